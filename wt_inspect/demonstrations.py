"""Expert demonstrations (VT-NMPC+ by default) recorded as a Minari dataset.

Minari is the Farama Foundation's standard format for offline-RL datasets (episodes of
observations, actions, rewards, terminations, truncations and infos in one folder, loadable with
``minari.load_dataset``), so a dataset recorded here can be used by anyone's offline-RL or
imitation code, not only by :mod:`agents.imitation`.

Each episode is one flight of the expert - any registered controller, built through the
evaluation registry - on the raw environment: a segment starting at a random point of the path
(``start_progress``) with a random offset (``start_noise``), under one of several winds. The
*executed* action is the expert's plus Gaussian noise (``action_noise``, in normalised action
units, clipped to the action box): the dataset then holds the states a slightly imperfect
learner reaches and what the expert does there (DART, Laskey et al. 2017, "Learning robust
bounded-rank policies..." style noise injection), which is what keeps a cloned policy from
drifting off the expert's narrow distribution. Every step's info stores the expert's clean
action (``expert_action``), the coverage so far and the time; every episode's metadata its
final metrics and wind.

Writes are atomic: the dataset is created in a temporary folder beside the target and renamed
into place, so an interrupted recording leaves no half-written dataset.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import gymnasium as gym
import numpy as np

import wt_inspect_env
from wt_inspect_env.task.env_config import TASKS, check_start_noise
from wt_inspect_env.util.atomic_io import check_out_dir
from wt_inspect_env.util.validation import (
    check_choice,
    check_finite,
    check_positive,
    check_unknown_options,
    json_object_option,
)

DATASET_NAMESPACE = "wt-inspect"


def _default_winds() -> list[Any]:
    return ["none", {"type": "gust", "mean_speed": 4.0}, {"type": "gust", "mean_speed": 7.0},
            {"type": "dryden", "mean_speed": 4.0}]


@dataclass(frozen=True)
class DemoConfig:
    """What to record. ``episodes`` per wind; segments of ``time_limit_s`` [s] starting in the
    first ``start_progress`` of the path; ``full_missions``: additional whole missions from the
    start (one per wind, up to this many), which hold the phase change and phase 2."""

    expert: str = "vtnmpc-plus"
    task: str = "full"
    winds: list = field(default_factory=_default_winds)
    episodes: int = 4
    time_limit_s: float = 60.0
    start_progress: float = 0.999
    start_noise: float = 1.0
    action_noise: float = 0.05
    full_missions: int = 1
    seed: int = 0

    def __post_init__(self) -> None:
        check_choice("demo task", self.task, TASKS)
        if not isinstance(self.winds, (list, tuple)) or not self.winds:
            raise ValueError(f"demo winds must be a non-empty list of wind specs, got {self.winds!r}")
        for name in ("episodes", "full_missions", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"demo {name} must be a non-negative integer, got {v!r}")
        check_positive("demo time_limit_s", self.time_limit_s)
        check_start_noise(self.start_noise, "demo start_noise")
        check_positive("demo action_noise", self.action_noise, allow_zero=True)
        if not 0.0 <= check_finite("demo start_progress", self.start_progress) < 1.0:
            raise ValueError(f"demo start_progress must lie in [0, 1), got {self.start_progress!r}")

    @classmethod
    def from_json(cls, text: str | None, option: str = "--config") -> "DemoConfig":
        """The config from a JSON object of its fields, inline or in a ``.json`` file (None or empty:
        the defaults); a one-line ValueError naming ``option`` for anything else or an unknown field."""
        fields = json_object_option(option, text)
        check_unknown_options(f"{option} demo config", fields, cls.__dataclass_fields__)
        return cls(**fields)


# A dataset name: Minari's ``dataset_name-v<version>`` without a namespace of its own (the
# namespace is DATASET_NAMESPACE) - letters, digits, ``-`` and ``_``, so it is one folder inside
# ``--out`` (no ``/``, no ``..``) and Minari accepts the id after the recording, not only before.
_DATASET_NAME = re.compile(r"[A-Za-z0-9_][-\w]*-v\d+", re.ASCII)


def check_dataset_name(name: Any) -> str:
    """``name`` if it is a valid dataset name (see :data:`_DATASET_NAME`), checked also by Minari's
    own id parser when Minari is installed; otherwise a one-line ValueError naming ``--name``."""
    if not isinstance(name, str) or not _DATASET_NAME.fullmatch(name):
        raise ValueError(f"--name must be a dataset name of letters, digits, '-' and '_' ending in a version "
                         f"such as '-v0' (one folder inside --out: no '/' or '..'), got {name!r}")
    try:
        from minari.dataset.minari_dataset import parse_dataset_id
    except ImportError:   # checked again by record_demonstrations, which needs Minari
        return name
    try:
        namespace, _, _ = parse_dataset_id(f"{DATASET_NAMESPACE}/{name}")
    except (ValueError, TypeError) as exc:
        raise ValueError(f"--name {name!r} is not a valid Minari dataset name: {exc}") from None
    if namespace != DATASET_NAMESPACE:   # pragma: no cover - excluded by the pattern above
        raise ValueError(f"--name {name!r} must not contain a namespace")
    return name


def _episode_plan(cfg: DemoConfig) -> list[dict[str, Any]]:
    plan = []
    for w in cfg.winds:
        for _ in range(cfg.episodes):
            plan.append({"wind": w, "start_progress": cfg.start_progress, "start_noise": cfg.start_noise,
                         "time_limit_s": cfg.time_limit_s})
    for w in list(cfg.winds)[:cfg.full_missions]:
        plan.append({"wind": w, "start_progress": 0.0, "start_noise": cfg.start_noise, "time_limit_s": None})
    return plan


def record_demonstrations(cfg: DemoConfig, out: str | Path, name: str = "vtnmpc-plus-full-v0",
                          env_options: dict | None = None, progress: bool = True) -> dict[str, Any]:
    """Record the episodes of ``cfg`` into the Minari dataset ``out/<namespace>/<name>``; returns a
    summary (episodes, steps, mean metrics of the expert)."""
    import minari
    from minari.data_collector.episode_buffer import EpisodeBuffer
    from tqdm import tqdm

    from .evaluation.registry import resolve

    env_id = {task: eid for eid, task in wt_inspect_env.ENV_IDS.items()}[cfg.task]
    # Everything that can be refused is refused before the first episode flies.
    check_dataset_name(name)
    out = check_out_dir(out, "--out")
    dataset_id = f"{DATASET_NAMESPACE}/{name}"
    target = out / DATASET_NAMESPACE / name
    if target.exists():
        raise ValueError(f"dataset {str(target)!r} exists already; choose another --name or remove it")
    if (out / DATASET_NAMESPACE).exists() and not (out / DATASET_NAMESPACE).is_dir():
        raise ValueError(f"--out {str(out)!r}: {str(out / DATASET_NAMESPACE)!r} exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {str(out)!r} cannot be created: {exc.strerror or exc}") from None
    tmp_root = Path(tempfile.mkdtemp(prefix=".minari-", dir=out))
    old_path = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(tmp_root.resolve())   # Minari joins a relative one to itself
    rng = np.random.default_rng(cfg.seed)
    plan = _episode_plan(cfg)
    t_start = time.perf_counter()
    buffers, episode_meta, steps = [], [], 0
    env = None
    try:
        bar = tqdm(total=len(plan), desc="demonstrations", unit="episode", disable=not progress, file=sys.stderr)
        for k, opts in enumerate(plan):
            env = gym.make(env_id, **{**dict(env_options or {}), **opts})
            expert = resolve(cfg.expert)(env.unwrapped)
            seed = int(cfg.seed * 1000 + k)
            obs, info = env.reset(seed=seed)
            expert.reset(seed)
            observations = {key: [v] for key, v in obs.items()}
            infos = {"expert_action": [np.zeros(4, np.float32)], "coverage": [float(info["coverage"])],
                     "time": [float(info["time"])]}
            actions, rewards, terms, truncs = [], [], [], []
            while True:
                a = np.asarray(expert.act(obs), dtype=np.float32)
                noisy = np.clip(a + rng.normal(0.0, cfg.action_noise, 4), -1.0, 1.0).astype(np.float32)
                obs, reward, term, trunc, info = env.step(noisy)
                for key, v in obs.items():
                    observations[key].append(v)
                actions.append(noisy)
                rewards.append(float(reward))
                terms.append(bool(term))
                truncs.append(bool(trunc))
                infos["expert_action"].append(a)
                infos["coverage"].append(float(info["coverage"]))
                infos["time"].append(float(info["time"]))
                if term or trunc:
                    break
            steps += len(actions)
            buffers.append(EpisodeBuffer(
                id=k, seed=seed, observations={key: np.stack(v) for key, v in observations.items()},
                actions=np.stack(actions), rewards=rewards, terminations=terms, truncations=truncs,
                infos={key: np.asarray(v) for key, v in infos.items()}))
            m = info["metrics"]
            episode_meta.append({"episode": k, "seed": seed, "options": opts, "termination": info["termination"],
                                 "steps": len(actions),
                                 "metrics": {key: float(m[key]) for key in ("coverage", "safety_sm", "centering_cm",
                                                                           "rms_distance_error_m", "flight_time_s")}})
            if k < len(plan) - 1:
                env.close()
            bar.update(1)
        bar.close()
        dataset = minari.create_dataset_from_buffers(
            dataset_id=dataset_id, buffer=buffers, env=env,
            algorithm_name=f"{cfg.expert} + N(0, {cfg.action_noise}) action noise",
            eval_env=env, author="wt-inspect", author_email="https://github.com/wt-inspect",
            description=(f"{cfg.expert} flying the {cfg.task} task of {env_id}; executed actions "
                         "carry Gaussian noise, infos['expert_action'] is the clean label"))
        meta = {"config": {**cfg.__dict__, "winds": list(cfg.winds)}, "env_id": env_id,
                "env_options": dict(env_options or {}), "episodes": episode_meta, "steps": steps,
                "total_episodes": dataset.total_episodes,
                # part of a route's wall time from nothing (the imitation study's seeds report adds it)
                "wall_time_s": round(time.perf_counter() - t_start, 1),
                "drone": {"mass": env.unwrapped.params.mass, "standoff": env.unwrapped.config.standoff,
                          "ctrl_hz": env.unwrapped.config.ctrl_hz}}
        src = tmp_root / DATASET_NAMESPACE / name
        (src / "wt_inspect_demos.json").write_text(json.dumps(meta, indent=1))
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, target)
    finally:
        if env is not None:
            env.close()
        if old_path is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old_path
        shutil.rmtree(tmp_root, ignore_errors=True)
    return {"dataset": str(target), "dataset_id": dataset_id, **meta}


def main(argv: Sequence[str], prog: str = "wt-inspect demos") -> int:
    """``wt-inspect demos``: record the dataset given by ``argv``; returns the exit code."""
    import argparse

    ap = argparse.ArgumentParser(prog=prog, description="Record expert demonstrations as a Minari dataset.")
    ap.add_argument("--out", required=True, help="root folder of the datasets (dataset in OUT/wt-inspect/NAME)")
    ap.add_argument("--name", default="vtnmpc-plus-full-v0", help="dataset name (default vtnmpc-plus-full-v0)")
    ap.add_argument("--config", default=None, help="JSON object of DemoConfig fields")
    ap.add_argument("--env", default=None, help="JSON object of further environment options")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(list(argv))
    try:
        cfg = DemoConfig.from_json(args.config, "--config")
        env = json_object_option("--env", args.env)
        from .evaluation.registry import check_controller
        check_dataset_name(args.name)   # before anything is imported, built or recorded
        check_out_dir(args.out, "--out")
        check_controller(cfg.expert)
        summary = record_demonstrations(cfg, args.out, args.name, env, progress=not args.no_progress)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:   # the disk filled or went read-only while recording
        print(f"{prog}: error: cannot write the dataset into {args.out!r}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    mean = {k: float(np.mean([e["metrics"][k] for e in summary["episodes"]])) for k in ("coverage", "safety_sm")}
    print(f"recorded {summary['total_episodes']} episodes, {summary['steps']} steps into {summary['dataset']} "
          f"(expert coverage {mean['coverage']:.3f}, SM {mean['safety_sm']:.3f})")
    return 0
