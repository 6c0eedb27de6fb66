"""Training stable-baselines3 agents on the inspection tasks (the library behind ``wt-inspect train``).

A run writes into its output directory::

    model.zip / model.json / model.vecnormalize.json  final agent (+ sidecar, + resume statistics)
    best_model.*                                      agent with the best periodic evaluation
    checkpoints/ckpt_<env steps>.*                    resumable checkpoints
    evaluations.json                                  periodic evaluations (shared metrics)
    episodes.csv                                      every training episode's return and metrics
    learning_curve.png                                coverage / SM / return against env steps
    summary.json                                      steps, wall time, throughput, final metrics
    recipe.json                                       the recipe used
    tb/                                               TensorBoard logs

Steps are counted in *simulator control steps* (100 Hz env steps), the unit of the issue's
"2 M steps" budget: with ``action_repeat = k`` the agent takes one decision per ``k`` of them, and
``--timesteps N`` trains for ``ceil(N / k)`` decisions (summed over the parallel envs).

Evaluation runs the deployed path, :class:`~agents.policy.SB3Policy` on a raw env (Dict
observation in, env action out), on the recipe's ``eval_env`` options (by default the full mission
with the paper's gust and no start noise), and reads coverage, safety SM and centering CM from the
env's ``info["metrics"]``. The best model is the one whose mean ``min(coverage, SM)`` is highest.
"""
from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import gymnasium as gym
import numpy as np

import wt_inspect_env
from wt_inspect_env.task.env_config import TASKS
from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.figure_io import check_figure_format
from wt_inspect_env.util.interrupts import interrupts_deferred
from wt_inspect_env.util.validation import check_choice, check_positive_int

from .policy import ALGOS, SB3Policy, algo_class, env_interface, load_sidecar, save_agent, sidecar_paths
from .recipe import Recipe, default_recipe_path, load_recipe
from .safe_load import (
    LEGACY_VECNORM_SUFFIX,
    load_legacy_vecnormalize,
    load_sb3_model,
    load_vecnormalize,
    sb3_algo_kwargs,
    sb3_policy_kwargs,
)
from .wrappers import AgentSpec, EpisodeVariants, InspectionAgentEnv, ShapingConfig

TASK_ENV_IDS: dict[str, str] = {task: env_id for env_id, task in wt_inspect_env.ENV_IDS.items()}
METRIC_KEYS: tuple[str, ...] = ("coverage", "safety_sm", "centering_cm", "rms_distance_error_m",
                                "collisions", "flight_time_s")
EVAL_SEED_BASE = 10_000


def make_raw_env(task: str, options: Mapping[str, Any]) -> gym.Env:
    """The registered inspection env of ``task`` with ``gym.make`` options."""
    check_choice("task", task, TASKS)
    return gym.make(TASK_ENV_IDS[task], **dict(options))


def make_agent_env(task: str, options: Mapping[str, Any], spec: AgentSpec,
                   shaping: ShapingConfig | None = None, variants: Sequence[Mapping[str, Any]] = (),
                   weights: Sequence[float] | None = None) -> gym.Env:
    """Raw env -> :class:`InspectionAgentEnv` -> stable-baselines3 ``Monitor`` (episode stats).
    With ``variants`` (option dicts merged over ``options``), one agent env per variant behind an
    :class:`~agents.wrappers.EpisodeVariants` that draws one per episode."""
    from stable_baselines3.common.monitor import Monitor
    if not variants:
        return Monitor(InspectionAgentEnv(make_raw_env(task, options), spec, shaping))
    envs = [InspectionAgentEnv(make_raw_env(task, {**dict(options), **dict(v)}), spec, shaping) for v in variants]
    return Monitor(EpisodeVariants(envs, None if weights is None else list(weights)))


def _env_factory(task: str, options: Mapping[str, Any], spec: AgentSpec, shaping: ShapingConfig | None,
                 variants: Sequence[Mapping[str, Any]], weights: Sequence[float] | None) -> Callable[[], gym.Env]:
    opts = dict(options)
    return lambda: make_agent_env(task, opts, spec, shaping, variants, weights)


BACKENDS: tuple[str, ...] = ("vector", "subprocess", "dummy")


def make_vec_env(task: str, options: Mapping[str, Any], spec: AgentSpec, n_envs: int,
                 backend: str = "vector", shaping: ShapingConfig | None = None,
                 variants: Sequence[Mapping[str, Any]] = (), weights: Sequence[float] | None = None,
                 seed: int = 0, turbines: Mapping[str, Any] | None = None):
    """``n_envs`` agent envs as one stable-baselines3 VecEnv.

    ``backend``: ``vector`` (default) - all drones in this process, in the native batched vector
    env (:mod:`agents.vec_env`), with episode statistics from SB3's ``VecMonitor``;
    ``subprocess`` - one single env per subprocess (SB3's ``SubprocVecEnv``); ``dummy`` - single
    envs stepped in turn in this process (SB3's ``DummyVecEnv``). ``turbines``: many-turbine
    options of the vector backend (:func:`~wt_inspect_env.vector.turbines.many_turbine_kwargs`; the
    drones fly on turbines drawn per world instead of the one of ``options``).
    """
    check_choice("backend", backend, BACKENDS)
    if turbines is not None and backend != "vector":
        raise ValueError(f"turbines (many turbines per run) needs backend='vector', got backend={backend!r}")
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor
    if backend == "vector":
        from .vec_env import make_inspection_vec_env
        return VecMonitor(make_inspection_vec_env(task, options, spec, n_envs, shaping, variants, weights, seed,
                                                  turbines=turbines))
    fns = [_env_factory(task, options, spec, shaping, variants, weights) for _ in range(n_envs)]
    return SubprocVecEnv(fns, start_method="forkserver") if backend == "subprocess" else DummyVecEnv(fns)


def recipe_vec_env(rec: Recipe, task: str, n_envs: int, *, backend: str = "vector", seed: int = 0):
    """:func:`make_vec_env` with a recipe's env options, agent spec, shaping, env variants and
    many-turbine options."""
    return make_vec_env(task, rec.env, rec.spec, n_envs, backend=backend, shaping=rec.shaping,
                        variants=rec.env_variants, weights=rec.env_variant_weights, seed=seed,
                        turbines=rec.turbines)


def recipe_vecnormalize(venv, rec: Recipe):
    """A new VecNormalize around ``venv`` with the recipe's ``normalize`` switches and clips and
    its discount (the reward statistics follow the return the algorithm discounts)."""
    from stable_baselines3.common.vec_env import VecNormalize

    norm = dict(rec.normalize)
    return VecNormalize(venv, norm_obs=bool(norm.get("obs", True)), norm_reward=bool(norm.get("reward", True)),
                        clip_obs=float(norm.get("clip_obs", 10.0)), clip_reward=float(norm.get("clip_reward", 10.0)),
                        gamma=float(rec.algo_kwargs.get("gamma", 0.99)))


def run_episode(policy, env: gym.Env, seed: int) -> dict[str, Any]:
    """One episode of a ``reset/act`` policy on a raw env; the env's final metrics and the return,
    and - when the env observes the structure (``structure_observation``) - the least distance to
    it over the episode (``clearance_min_m``: what an agent that keeps d_min by itself is judged on)."""
    obs, info = env.reset(seed=seed)
    policy.reset(seed)
    total, steps = 0.0, 0
    least = float(obs["structure"][3]) if "structure" in obs else None
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        total += reward
        steps += 1
        if least is not None:
            least = min(least, float(obs["structure"][3]))
        if terminated or truncated:
            break
    m = info["metrics"]
    out = {k: float(m[k]) for k in METRIC_KEYS}
    out.update(seed=seed, steps=steps, episode_return=total, termination=info["termination"],
               mission_complete=bool(info["mission_complete"]))
    if least is not None:
        out["clearance_min_m"] = least
        out["d_min_m"] = float(env.unwrapped.config.d_min)
    return out


def evaluate_policy(policy, task: str, options: Mapping[str, Any], seeds: Sequence[int]) -> dict[str, Any]:
    """Episodes of ``policy`` on ``task`` (one seed each) and their means."""
    env = make_raw_env(task, options)
    try:
        episodes = [run_episode(policy, env, int(s)) for s in seeds]
    finally:
        env.close()
    return summarize_episodes(episodes)


def summarize_episodes(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean metrics and score (mean of :func:`episode_score`) of evaluation episodes, kept beside them."""
    mean = {k: float(np.mean([e[k] for e in episodes])) for k in (*METRIC_KEYS, "episode_return", "steps")}
    if episodes and all("clearance_min_m" in e for e in episodes):   # the least over the episodes
        mean["clearance_min_m"] = float(min(e["clearance_min_m"] for e in episodes))
    score = float(np.mean([episode_score(e) for e in episodes]))
    return {"mean": mean, "score": score, "episodes": episodes}


def evaluate_on_envs(make_policy: Callable[[gym.Env], Any], envs: Sequence[gym.Env],
                     seeds: Sequence[int]) -> dict[str, Any]:
    """Episodes on every env of ``envs`` (one per seed each; the policy ``make_policy(env)``) summarised.

    With one env this is :func:`summarize_episodes` of its episodes. With several (a recipe's
    ``eval_variants``), ``mean`` is over all their episodes (each marked with its ``eval_variant``),
    ``variants`` holds each env's own summary, and ``score`` is the *worst* env's score: a model is
    kept for doing the task in every condition, not for the average of one good and one bad.
    """
    parts = []
    for env in envs:
        policy = make_policy(env)
        parts.append(summarize_episodes([run_episode(policy, env, int(s)) for s in seeds]))
    if len(parts) == 1:
        return parts[0]
    result = summarize_episodes([{**e, "eval_variant": i} for i, p in enumerate(parts) for e in p["episodes"]])
    result["score"] = min(p["score"] for p in parts)
    result["variants"] = [{"mean": p["mean"], "score": p["score"]} for p in parts]
    return result


def episode_score(episode: Mapping[str, Any]) -> float:
    """What the best model is chosen by: ``min(coverage, SM)``, and when the episode recorded its
    least clearance (the env observes the structure), also that clearance as a share of d_min - a
    pass below d_min costs its shortfall, so the best model of a recipe that must keep its distance
    by itself is not one that covers the blade by passing too close."""
    score = min(episode["coverage"], episode["safety_sm"])
    if "clearance_min_m" in episode and "d_min_m" in episode:
        score = min(score, episode["clearance_min_m"] / episode["d_min_m"])
    return float(score)


def _policy_from_model(model, spec: AgentSpec, vecnormalize, env_like) -> SB3Policy:
    norm = None
    if vecnormalize is not None and vecnormalize.norm_obs:
        norm = {"mean": vecnormalize.obs_rms.mean.copy(), "var": vecnormalize.obs_rms.var.copy(),
                "clip_obs": vecnormalize.clip_obs, "epsilon": vecnormalize.epsilon}
    iface = env_interface(env_like)
    return SB3Policy(model, spec, env_like.unwrapped.scaling, standoff=iface["standoff"], dt=iface["dt"],
                     obs_normalization=norm)


def _callback_class():
    """Defined lazily so that importing this module does not import torch."""
    from stable_baselines3.common.callbacks import BaseCallback

    class InspectionCallback(BaseCallback):
        """Env-step accounting, training-episode metrics, periodic evaluation, checkpoints, best
        model, a wall-clock limit and a tqdm progress bar, all in env (control) steps."""

        def __init__(self, run: "TrainingRun") -> None:
            super().__init__(verbose=0)
            self.run = run
            self.stopped_by_clock = False
            self._bar = None

        def _on_training_start(self) -> None:
            r = self.run
            if r.progress_bar:
                from tqdm import tqdm
                self._bar = tqdm(total=r.target_env_steps, initial=r.env_steps, unit="step",
                                 unit_scale=True, mininterval=2.0, dynamic_ncols=True, file=sys.stderr,
                                 desc=f"{r.algo} {r.task}")

        def _on_step(self) -> bool:
            r = self.run
            infos = self.locals["infos"]
            dones = self.locals["dones"]
            n = int(sum(info.get("env_steps", r.spec.action_repeat) for info in infos))
            r.env_steps += n
            if self._bar is not None:
                self._bar.update(n)
            for done, info in zip(dones, infos):
                if done and "metrics" in info:
                    r.record_episode(info, self.logger)
            if r.env_steps >= r.next_eval:
                r.next_eval += r.recipe.eval_every_env_steps
                r.evaluate(self.model, self.logger)
            if r.env_steps >= r.next_checkpoint:
                r.next_checkpoint += r.recipe.checkpoint_every_env_steps
                r.checkpoint(self.model)
            if r.max_seconds is not None and r.elapsed() >= r.max_seconds:
                self.stopped_by_clock = True
                return False
            return True

        def _on_training_end(self) -> None:
            if self._bar is not None:
                self._bar.close()

    return InspectionCallback


class TrainingRun:
    """State of one ``train`` call (kept out of globals; see :func:`train`)."""

    def __init__(self, *, algo: str, task: str, recipe: Recipe, out: Path, n_envs: int, seed: int,
                 target_env_steps: int, env_steps: int, wall_before: float, max_seconds: float | None,
                 progress_bar: bool, vecnormalize, backend: str = "vector") -> None:
        self.algo, self.task, self.recipe, self.out = algo, task, recipe, out
        self.backend = backend
        self.spec = recipe.spec
        self.n_envs, self.seed = n_envs, seed
        self.env_steps = env_steps
        self.start_env_steps = env_steps
        self.target_env_steps = target_env_steps
        self.wall_before = wall_before
        self.t0 = time.perf_counter()
        self.max_seconds = max_seconds
        self.progress_bar = progress_bar
        self.vecnormalize = vecnormalize
        every = recipe.eval_every_env_steps
        self.next_eval = (env_steps // every + 1) * every
        cevery = recipe.checkpoint_every_env_steps
        self.next_checkpoint = (env_steps // cevery + 1) * cevery
        self.evaluations: list[dict[str, Any]] = _read_json_list(out / "evaluations.json")
        self.best_score = max((e["score"] for e in self.evaluations), default=-math.inf)
        self.eval_time = 0.0
        self._eval_envs: list[gym.Env] = []
        self._episodes_path = out / "episodes.csv"

    def elapsed(self) -> float:
        """Seconds of wall time since this run started (this invocation only)."""
        return time.perf_counter() - self.t0

    def wall_time(self) -> float:
        """Seconds of wall time of the whole training, earlier runs it resumes included."""
        return self.wall_before + self.elapsed()

    def eval_envs(self) -> list[gym.Env]:
        """The raw envs the periodic evaluation flies, one per evaluation variant of the recipe
        (made on first use, then kept)."""
        if not self._eval_envs:
            for options in self.recipe.eval_options_list():
                self._eval_envs.append(make_raw_env(self.task, options))
        return self._eval_envs

    def interface_env(self) -> gym.Env:
        """The raw env whose interface (scaling, stand-off, step) a saved model records: the first
        evaluation env (the variants differ in conditions such as the wind, not in the interface)."""
        return self.eval_envs()[0]

    def record_episode(self, info: Mapping[str, Any], logger) -> None:
        """Log one finished training episode's return and metrics (to ``logger`` and the run's record)."""
        m = info["metrics"]
        row = {"env_steps": self.env_steps, "wall_time_s": round(self.wall_time(), 2),
               "return": float(info["episode"]["r"]) if "episode" in info else float("nan"),
               "time_s": float(info.get("time", float("nan"))),
               **{k: float(m[k]) for k in ("coverage", "safety_sm", "centering_cm", "rms_distance_error_m")},
               "termination": info.get("termination") or ("complete" if info.get("mission_complete") else "time"),
               "variant": info.get("variant", "")}
        new = not self._episodes_path.exists()
        with open(self._episodes_path, "a", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(row))
            if new:
                w.writeheader()
            w.writerow(row)
        for k in ("coverage", "safety_sm", "centering_cm"):
            logger.record_mean(f"episode/{k}", row[k])
        logger.record_mean("episode/crashed", float(info.get("termination") is not None))
        logger.record("time/env_steps", self.env_steps)

    def evaluate(self, model, logger=None) -> dict[str, Any]:
        """Evaluate ``model`` deterministically on the evaluation seeds; returns the summary (logged if ``logger``)."""
        t = time.perf_counter()
        seeds = [EVAL_SEED_BASE + i for i in range(self.recipe.eval_episodes)]
        result = evaluate_on_envs(lambda env: _policy_from_model(model, self.spec, self.vecnormalize, env),
                                  self.eval_envs(), seeds)
        dt = time.perf_counter() - t
        self.eval_time += dt
        entry = {"env_steps": self.env_steps, "wall_time_s": round(self.wall_time(), 2),
                 "eval_time_s": round(dt, 2), **result}
        self.evaluations.append(entry)
        write_text_atomic(self.out / "evaluations.json", json.dumps(self.evaluations, indent=1))
        if logger is not None:
            for k, v in result["mean"].items():
                logger.record(f"eval/{k}", v)
            logger.record("eval/score", result["score"])
        mean = result["mean"]
        print(f"[eval] env_steps={self.env_steps} wall={self.wall_time():.0f}s coverage={mean['coverage']:.3f} "
              f"SM={mean['safety_sm']:.3f} CM={mean['centering_cm']:.3f} return={mean['episode_return']:.1f} "
              f"steps={mean['steps']:.0f}"
              + (f" clearance_min={mean['clearance_min_m']:.2f}m" if "clearance_min_m" in mean else ""),
              file=sys.stderr, flush=True)
        if result["score"] > self.best_score:
            self.best_score = result["score"]
            self.save(model, self.out / "best_model", evaluation=entry)
        return entry

    def training_info(self) -> dict[str, Any]:
        """What a saved model records about the training that made it (algorithm, task, steps, wall time)."""
        return {"algo": self.algo, "task": self.task, "env_steps": self.env_steps,
                "wall_time_s": round(self.wall_time(), 1), "n_envs": self.n_envs, "seed": self.seed,
                "backend": self.backend}

    def save(self, model, path: Path, evaluation: Mapping[str, Any] | None = None) -> Path:
        """Save ``model`` with its sidecar (spec, normalisation, interface, training info) at ``path``."""
        extra = {"training": self.training_info(), "recipe": self.recipe.to_dict()}
        if evaluation is not None:
            extra["evaluation"] = evaluation
        return save_agent(model, path, algo=self.algo, spec=self.spec, vecnormalize=self.vecnormalize,
                          interface=env_interface(self.interface_env()), extra=extra)

    def checkpoint(self, model) -> Path:
        """Save a checkpoint named by the current number of env steps under ``OUT/checkpoints``."""
        return self.save(model, self.out / "checkpoints" / f"ckpt_{self.env_steps}")

    def close(self) -> None:
        """Close the evaluation envs, if any were made."""
        for env in self._eval_envs:
            env.close()
        self._eval_envs = []


def _read_json_list(path: Path) -> list:
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            return data if isinstance(data, list) else []
        except json.JSONDecodeError:
            return []
    return []


def _algo_kwargs(recipe: Recipe) -> dict[str, Any]:
    return sb3_algo_kwargs(recipe.algo_kwargs)


# PPO settings a fine-tune's recipe may change on a resumed model (SB3's ``load(**kwargs)`` sets
# them before the rollout buffer and the schedules are built): the rollout length per drone must
# follow the number of drones, or a 16-drone fine-tune of a 2-env model would collect 8x longer
# rollouts per update; and a fine-tune's learning rate and clip range are its own (they were once
# left at the base model's, and the saved model then disagreed with its own sidecar's recipe).
PPO_RESUME_KEYS = ("n_steps", "batch_size", "n_epochs", "gae_lambda", "ent_coef", "vf_coef", "max_grad_norm",
                   "target_kl", "learning_rate", "clip_range")


def resume_overrides(algo: str, recipe: Recipe) -> dict[str, Any]:
    """The settings of an explicitly given recipe applied to a resumed PPO model."""
    if algo != "ppo":
        return {}
    kw = _algo_kwargs(recipe)
    return {k: kw[k] for k in PPO_RESUME_KEYS if k in kw}


def _policy_kwargs(recipe: Recipe) -> dict[str, Any]:
    return sb3_policy_kwargs(recipe.policy_kwargs)


class TrainingInterrupted(KeyboardInterrupt):
    """``train`` was interrupted (SIGINT / SIGTERM): ``checkpoint`` is the resumable checkpoint
    saved at ``env_steps`` (None: nothing could be saved), ``signal`` the original interrupt."""

    def __init__(self, interrupt: BaseException, checkpoint: Path | None, env_steps: int) -> None:
        super().__init__(str(interrupt))
        self.signum = getattr(interrupt, "signum", 2)
        self.checkpoint = checkpoint
        self.env_steps = env_steps


def build_run(algo: str, task: str, n_envs: int, rec: Recipe, *, backend: str, seed: int, resume, ckpt_doc, recipe,
              trust_model: bool, legacy: Path | None, verbose: int = 0, tb: str | None = None):
    """The agent envs of ``rec`` and the model on them (new, or loaded from ``resume``) with its
    VecNormalize (the checkpoint's statistics, or new ones when the recipe normalises); returns
    ``(model, vecnorm or None, the outermost VecEnv)``; closes the envs if building the model
    fails. Writes nothing."""
    venv = recipe_vec_env(rec, task, n_envs, backend=backend, seed=seed)
    try:
        vecnorm = None
        norm = dict(rec.normalize)
        if ckpt_doc is not None and sidecar_paths(resume)[2].is_file():
            vecnorm = venv = load_vecnormalize(sidecar_paths(resume)[2], venv)
        elif ckpt_doc is not None and trust_model and legacy is not None and legacy.is_file():
            vecnorm = venv = load_legacy_vecnormalize(legacy, venv)   # the user trusts this pickle (checked above)
        elif norm.get("obs", True) or norm.get("reward", True):
            vecnorm = venv = recipe_vecnormalize(venv, rec)
        cls = algo_class(algo)
        if ckpt_doc is not None:
            changes = resume_overrides(algo, rec) if recipe is not None else {}
            model = load_sb3_model(cls, sidecar_paths(resume)[0], ckpt_doc, trust_model=trust_model, env=venv,
                                   device="cpu", tensorboard_log=tb, **changes)
            # SB3's load does not reseed: without this, the seeds of a fine-tune would share torch's
            # unseeded stream and no fine-tune would be reproducible.
            model.set_random_seed(seed)
        else:
            model = cls("MlpPolicy", venv, tensorboard_log=tb, seed=seed, device="cpu", verbose=verbose,
                        policy_kwargs=_policy_kwargs(rec), **_algo_kwargs(rec))
    except BaseException:
        venv.close()
        raise
    return model, vecnorm, venv


def new_stage(ckpt_doc: Mapping[str, Any] | None, recipe: Any) -> bool:
    """Whether a run starts a stage of its own - a new model, or a resumed one with an explicit
    recipe (a fine-tune) - rather than continuing a stopped run. SB3 then counts its decisions
    from 0, so the recipe's schedules (a decaying learning rate) run over this stage, not over
    the tail of the base model's run."""
    return ckpt_doc is None or recipe is not None


def resolve_run(algo: str, *, recipe: str | Path | Recipe | None, resume: str | Path | None,
                trust_model: bool, eval_every: int | None = None) -> tuple[Recipe, dict | None, Path | None]:
    """The recipe a run trains with, the resumed checkpoint's sidecar (None: a new model) and the
    path of its legacy pickled statistics (None: a new model); checks the checkpoint before
    anything is built (a missing file, another algorithm, statistics that need unpickling without
    ``trust_model``, an agent spec the recipe changes) - see :func:`train`."""
    ckpt_doc = None
    if resume is not None:
        zip_path, _, norm_path = sidecar_paths(resume)
        if not zip_path.is_file():
            raise ValueError(f"resume checkpoint {str(zip_path)!r} not found")
        ckpt_doc = load_sidecar(zip_path)
        if ckpt_doc.get("algo") != algo:
            raise ValueError(f"resume checkpoint {str(zip_path)!r} was trained with {ckpt_doc.get('algo')!r}, "
                             f"not {algo!r}")
        legacy = Path(str(zip_path.with_suffix("")) + LEGACY_VECNORM_SUFFIX)
        if not norm_path.is_file() and legacy.is_file() and not trust_model:
            raise ValueError(f"resume: the normalisation statistics {str(legacy)!r} are a pickle (loading runs code "
                             f"from it); pass --trust-model to load it once (the run then saves "
                             f"{norm_path.name!r}) only if you trust the file")
        if not norm_path.is_file() and not legacy.is_file() and ckpt_doc.get("obs_normalization") is not None:
            raise ValueError(f"resume needs the normalisation statistics {str(norm_path)!r}")
        if not trust_model:   # refuse an unsafe checkpoint before anything is written
            from .safe_load import check_safe
            check_safe(algo_class(algo), zip_path, ckpt_doc)
    if isinstance(recipe, Recipe):
        rec = recipe
    elif recipe is not None:
        rec = load_recipe(recipe)
    elif ckpt_doc is not None:
        rec = Recipe.from_dict(ckpt_doc["recipe"])
    else:
        rec = load_recipe(default_recipe_path(algo))
    if rec.algo != algo:
        raise ValueError(f"recipe is for algorithm {rec.algo!r}, not {algo!r}")
    if eval_every is not None:
        rec = dataclasses.replace(rec, eval_every_env_steps=check_positive_int("eval_every", eval_every))
    if ckpt_doc is not None and AgentSpec.from_dict(ckpt_doc["spec"]) != rec.spec:
        raise ValueError("the recipe's agent spec differs from the checkpoint's (features/action/repeat "
                         "must stay the same to resume)")
    return rec, ckpt_doc, (legacy if ckpt_doc is not None else None)


def train(algo: str, task: str, timesteps: int, n_envs: int, out: str | Path, *,
          recipe: str | Path | Recipe | None = None, resume: str | Path | None = None, seed: int = 0,
          max_minutes: float | None = None, progress_bar: bool = True, verbose: int = 0,
          backend: str = "vector", trust_model: bool = False, figure_format: str = "png",
          eval_every: int | None = None) -> dict[str, Any]:
    """Train (or resume) an agent; returns the run summary (also written to ``out/summary.json``).

    ``timesteps``: simulator control steps to train *in this call*. ``recipe``: a path, a
    :class:`Recipe`, or None for ``agents/recipes/<algo>_surface.json`` (or, when resuming, the
    checkpoint's recipe). ``resume``: a checkpoint/model ``.zip`` saved by a run (its sidecar and
    VecNormalize statistics are read from beside it). ``max_minutes``: stop early (and save) once
    this much wall time has passed in this call. ``trust_model``: resume from a checkpoint even if
    loading it runs code from it (a zip that needs unpickling, or an old ``.vecnormalize.pkl``);
    without it such a checkpoint is a ValueError before anything is written. ``figure_format``: of
    the learning curve (png, pdf, svg). ``eval_every``: simulator steps between the periodic
    evaluations, overriding the recipe's ``eval_every_env_steps`` (a study over seeds wants a denser
    learning curve than a production run; the policy's training does not depend on it) - the run's
    ``recipe.json`` records the value used.
    """
    check_choice("algorithm", algo, ALGOS)
    check_figure_format(figure_format)
    check_choice("task", task, TASKS)
    check_choice("backend", backend, BACKENDS)
    timesteps = check_positive_int("timesteps", timesteps)
    n_envs = check_positive_int("n_envs", n_envs)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if max_minutes is not None and not (isinstance(max_minutes, (int, float)) and max_minutes > 0):
        raise ValueError(f"max_minutes must be positive, got {max_minutes!r}")
    rec, ckpt_doc, legacy = resolve_run(algo, recipe=recipe, resume=resume, trust_model=trust_model,
                                        eval_every=eval_every)
    import torch

    torch.set_num_threads(rec.torch_threads)
    out = Path(out)
    # Nothing is written into ``out`` until the model is built or loaded: a checkpoint refused while
    # loading (malformed statistics or model data) leaves no recipe.json behind.
    model, vecnorm, venv = build_run(algo, task, n_envs, rec, backend=backend, seed=seed, resume=resume,
                                     ckpt_doc=ckpt_doc, recipe=recipe, trust_model=trust_model, legacy=legacy,
                                     verbose=verbose, tb=str(out / "tb"))
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "recipe.json", json.dumps(rec.to_dict(), indent=1))
    if ckpt_doc is not None:
        env_steps0 = int(ckpt_doc.get("training", {}).get("env_steps", 0))
        wall0 = float(ckpt_doc.get("training", {}).get("wall_time_s", 0.0))
    else:
        env_steps0, wall0 = 0, 0.0
    run = TrainingRun(algo=algo, task=task, recipe=rec, out=out, n_envs=n_envs, seed=seed,
                      target_env_steps=env_steps0 + timesteps, env_steps=env_steps0, wall_before=wall0,
                      max_seconds=None if max_minutes is None else 60.0 * max_minutes,
                      progress_bar=progress_bar, vecnormalize=vecnorm, backend=backend)
    callback = _callback_class()(run)
    agent_steps = math.ceil(timesteps / rec.spec.action_repeat)
    try:
        model.learn(total_timesteps=agent_steps, callback=callback, reset_num_timesteps=new_stage(ckpt_doc, recipe),
                    tb_log_name=algo, progress_bar=False)
        train_seconds = run.elapsed()
        eval_seconds = run.eval_time
        last = run.evaluations[-1] if run.evaluations else None
        # a periodic evaluation of these very weights (a clock stop right after one) is not repeated
        final_eval = last if last is not None and last["env_steps"] == run.env_steps else run.evaluate(model)
        final_path = run.save(model, out / "model", evaluation=final_eval)
    except KeyboardInterrupt as exc:   # Ctrl-C / SIGTERM: keep what was learnt as a resumable checkpoint
        callback._on_training_end()    # close the progress bar
        saved = None
        with interrupts_deferred(raise_noted=False):
            try:
                saved = run.checkpoint(model)
            except (OSError, ValueError):   # a full disk: say that nothing was saved
                saved = None
        raise TrainingInterrupted(exc, saved, run.env_steps) from None
    finally:
        venv.close()
        run.close()
    best_eval = max(run.evaluations, key=lambda e: e["score"]) if run.evaluations else None
    steps_this_call = run.env_steps - run.start_env_steps
    summary = {
        **run.training_info(),
        "env_steps_this_call": steps_this_call,
        "target_env_steps": run.target_env_steps,
        "agent_decisions": int(model.num_timesteps),
        "action_repeat": rec.spec.action_repeat,
        "train_wall_time_this_call_s": round(train_seconds, 1),
        "eval_time_this_call_s": round(run.eval_time, 1),
        "env_steps_per_s": round(steps_this_call / max(train_seconds - eval_seconds, 1e-9), 1),
        "stopped_by_wall_clock": callback.stopped_by_clock,
        "resumed_from": None if resume is None else str(resume),
        "final_model": str(final_path),
        "final_evaluation": {"mean": final_eval["mean"], "score": final_eval["score"]},
        "best_evaluation": None if best_eval is None else {"env_steps": best_eval["env_steps"],
                                                           "mean": best_eval["mean"], "score": best_eval["score"]},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "torch": torch.__version__, "torch_threads": rec.torch_threads},
    }
    from .curves import write_run_summary
    write_run_summary(out, summary, figure_format)
    return summary
