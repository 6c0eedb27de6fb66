"""Behaviour cloning of an expert's demonstrations into a stable-baselines3 policy.

The demonstrations are a Minari dataset of raw environment episodes (recorded by
``wt-inspect demos``: observations, the executed - noisy - env actions, and the expert's clean
action in ``infos["expert_action"]``). Cloning replays every episode through the agent's own
:class:`~agents.wrappers.FeatureEncoder` (so the features, the error integral and the
``last_action`` input are exactly what the deployed :class:`~agents.policy.SB3Policy` computes),
turns each expert action back into the agent's residual-hover action (the inverse of
:class:`~agents.wrappers.ResidualHoverAction` in ``rates`` mode), and fits the mean of the
recipe's SB3 policy to it by mean-squared error, each action component weighted by the
inverse of its variance (Adam with a cosine learning-rate decay, mini-batches, a held-out
validation share; the loss reported is that weighted MSE, 1 = no better than the mean action).
The result is saved like a trained model (``model.zip`` + sidecar + normalisation), so it
is evaluated with ``--controllers ppo:PATH`` and fine-tuned with ``wt-inspect train --resume``.

Why not the ``imitation`` library: its last release (1.0.1) pins ``gymnasium~=0.29`` and
``stable-baselines3~=2.2``, and this project needs Gymnasium 1.x (vector entry points,
autoreset modes); behaviour cloning itself is a few lines of supervised learning on the SB3
policy, written here against SB3's public policy API.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.validation import check_positive

from .wrappers import AgentSpec, FeatureEncoder


@dataclass(frozen=True)
class BCConfig:
    """Supervised-learning settings of behaviour cloning."""

    epochs: int = 30
    batch_size: int = 4096
    learning_rate: float = 3e-3
    validation_fraction: float = 0.05
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"bc {name} must be a positive integer, got {v!r}")
        check_positive("bc learning_rate", self.learning_rate)
        if not 0.0 <= float(self.validation_fraction) < 0.5:
            raise ValueError(f"bc validation_fraction must lie in [0, 0.5), got {self.validation_fraction!r}")


def load_demonstrations(path: str | Path):
    """The Minari dataset at ``path`` (a folder written by ``wt-inspect demos``:
    Minari's ``data/`` and the recorder's ``wt_inspect_demos.json`` metadata)."""
    import minari

    p = Path(path)
    if not (p / "data").is_dir() or not (p / "wt_inspect_demos.json").is_file():
        raise ValueError(f"dataset path {str(path)!r} is not a wt-inspect Minari dataset (no data/ or "
                         "wt_inspect_demos.json in it)")
    root, ns, name = p.parent.parent, p.parent.name, p.name
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        return minari.load_dataset(f"{ns}/{name}"), json.loads((p / "wt_inspect_demos.json").read_text())
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def invert_action(spec: AgentSpec, scaling, actions: np.ndarray, quaternions: np.ndarray) -> np.ndarray:
    """Agent actions ``u`` (N, 4) whose residual-hover decoding at ``quaternions`` gives the env
    ``actions`` (N, 4) - clipped to [-1, 1] where the expert went beyond the agent's range."""
    cfg = spec.action
    if cfg.mode != "rates":
        raise ValueError(f"behaviour cloning needs agent action mode 'rates', got {cfg.mode!r}")
    a = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
    lo, hi = scaling.lower, scaling.upper
    cmd = lo + (a + 1.0) * 0.5 * (hi - lo)
    u = np.empty_like(cmd)
    u[:, :3] = cmd[:, :3] / (cfg.rate_scale * scaling.max_rate)
    q = np.asarray(quaternions, dtype=np.float64)
    c = 1.0 - 2.0 * (q[:, 0] ** 2 + q[:, 1] ** 2)          # R[2, 2] = cos(tilt)
    factor = np.ones(len(c))
    if cfg.tilt_compensation:
        factor = np.where(c * cfg.max_tilt_factor <= 1.0, cfg.max_tilt_factor, 1.0 / np.where(c > 0, c, 1.0))
    u[:, 3] = (cmd[:, 3] / (scaling.hover_thrust * factor) - 1.0) / cfg.thrust_scale
    return np.clip(u, -1.0, 1.0)


def dataset_arrays(dataset, spec: AgentSpec, scaling, *, standoff: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(features, labels) of every step of every episode (see the module docstring)."""
    feats, labels = [], []
    for ep in dataset.iterate_episodes():
        obs = ep.observations
        T = len(ep.actions)
        expert = np.asarray(ep.infos["expert_action"])[1:T + 1]     # infos[0] is the reset's
        quat = np.asarray(obs["quaternion"], dtype=np.float64)
        label = invert_action(spec, scaling, expert, quat[:T])
        executed = invert_action(spec, scaling, np.asarray(ep.actions), quat[:T])
        enc = FeatureEncoder(spec.features, standoff=standoff, dt=dt, max_rate=scaling.max_rate)
        enc.reset()
        row = {k: np.asarray(v) for k, v in obs.items()}
        out = np.empty((T, spec.features.size), dtype=np.float32)
        enc.update({k: v[0] for k, v in row.items()})
        for t in range(T):
            out[t] = enc.features()
            enc.note_action(executed[t])
            enc.update({k: v[t + 1] for k, v in row.items()})
        feats.append(out)
        labels.append(label.astype(np.float32))
    return np.concatenate(feats), np.concatenate(labels)


def check_dataset_matches(meta: Mapping[str, Any], env) -> None:
    """A dataset recorded for another drone, stand-off or control rate cannot teach this env."""
    u = env.unwrapped
    drone = meta.get("drone", {})
    for name, have in (("mass", u.params.mass), ("standoff", u.config.standoff), ("ctrl_hz", u.config.ctrl_hz)):
        got = drone.get(name)
        if got is None or not math.isclose(float(got), float(have), rel_tol=1e-9):
            raise ValueError(f"dataset was recorded with {name} {got!r}, the recipe's environment has {have!r}")


def new_clone_model(recipe, task: str, X: np.ndarray, seed: int):
    """``(model, vecnormalize, venv)``: a fresh PPO model of the recipe's network (seeded) on a
    one-drone vector env, its observation normalisation set to the statistics of the features
    ``X`` (so a saved clone deploys with them). Close ``venv`` when done."""
    import torch

    from .policy import algo_class
    from .training import _policy_kwargs, recipe_vec_env, recipe_vecnormalize

    torch.manual_seed(seed)
    torch.set_num_threads(max(1, recipe.torch_threads))
    venv = recipe_vec_env(recipe, task, 1, backend="vector", seed=seed)
    vecnorm = recipe_vecnormalize(venv, recipe)
    vecnorm.obs_rms.mean = X.mean(axis=0).astype(np.float64)
    vecnorm.obs_rms.var = X.var(axis=0).astype(np.float64) + 1e-8
    vecnorm.obs_rms.count = float(len(X))
    kw = {k: v for k, v in recipe.algo_kwargs.items() if k != "learning_rate_final"}
    model = algo_class("ppo")("MlpPolicy", vecnorm, seed=seed, device="cpu",
                              policy_kwargs=_policy_kwargs(recipe), **kw)
    return model, vecnorm, venv


def normalize_features(vecnorm, X: np.ndarray) -> np.ndarray:
    """Raw features as the network sees them (VecNormalize's observation statistics and clip)."""
    return np.clip((X - vecnorm.obs_rms.mean) / np.sqrt(vecnorm.obs_rms.var + vecnorm.epsilon),
                   -vecnorm.clip_obs, vecnorm.clip_obs).astype(np.float32)


def actor_parameters(policy) -> list:
    """The parameters that shape the policy's mean action (not the critic's, not ``log_std``)."""
    return [p for n_, p in policy.named_parameters() if not n_.startswith(("value_net", "mlp_extractor.value_net"))
            and n_ != "log_std"]


def policy_mean_action(policy, x):
    """The deterministic action of an SB3 actor-critic policy for normalised features ``x``
    (a torch tensor), differentiable."""
    latent_pi, _ = policy.mlp_extractor(policy.extract_features(x, policy.pi_features_extractor))
    return policy.action_net(latent_pi)


def label_weights(Y: np.ndarray):
    """Per-component loss weights, the inverse variance of the labels ``Y`` (see behaviour_clone)."""
    import torch
    return torch.as_tensor(1.0 / np.maximum(Y.var(axis=0), 1e-8), dtype=torch.float32)


def behaviour_clone(dataset_path: str | Path, out: str | Path, *, recipe, task: str = "full",
                    config: BCConfig | None = None, progress: bool = True, evaluate: bool = True) -> dict[str, Any]:
    """Clone the dataset's expert into the recipe's policy; writes ``out/model.*`` and
    ``out/bc_summary.json`` (and, with ``evaluate``, ``out/evaluations.json``: the clone flown on
    the recipe's evaluation mission, as training runs record theirs) and returns the summary."""
    import torch
    from tqdm import tqdm

    from .policy import env_interface, save_agent
    from .training import make_raw_env

    cfg = config if config is not None else BCConfig()
    if recipe.algo != "ppo":
        raise ValueError(f"behaviour cloning initialises a PPO policy; recipe algo is {recipe.algo!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {str(out)!r} exists and is not a directory")
    dataset, meta = load_demonstrations(dataset_path)
    evals = [make_raw_env(task, options) for options in recipe.eval_options_list()]
    raw = evals[0]
    try:
        for env in evals:
            check_dataset_matches(meta, env)
        u = raw.unwrapped
        t0 = time.perf_counter()
        X, Y = dataset_arrays(dataset, recipe.spec, u.scaling, standoff=u.config.standoff, dt=u.dt)
        prep_s = time.perf_counter() - t0
        model, vecnorm, venv = new_clone_model(recipe, task, X, cfg.seed)
        Xn = normalize_features(vecnorm, X)
        rng = np.random.default_rng(cfg.seed)
        perm = rng.permutation(len(Xn))
        n_val = int(cfg.validation_fraction * len(Xn))
        val, tr = perm[:n_val], perm[n_val:]
        Xt, Yt = torch.as_tensor(Xn), torch.as_tensor(Y)
        policy = model.policy
        opt = torch.optim.Adam(actor_parameters(policy), lr=cfg.learning_rate)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.epochs)
        # Each action component is weighted by the inverse of its variance in the data: the expert's
        # roll-rate commands vary ~5x less than its thrust, and a plain MSE fits them poorly (measured:
        # validation RMSE 0.74 of the roll-rate spread against 0.22 with the weighting).
        w = label_weights(Y)

        def mean_action(x: "torch.Tensor") -> "torch.Tensor":
            return policy_mean_action(policy, x)

        history = []
        t1 = time.perf_counter()
        bar = tqdm(range(cfg.epochs), desc="behaviour cloning", unit="epoch", disable=not progress, file=sys.stderr)
        for epoch in bar:
            order = rng.permutation(tr)
            losses = []
            for a in range(0, len(order), cfg.batch_size):
                b = torch.as_tensor(order[a:a + cfg.batch_size])
                loss = torch.mean(w * (mean_action(Xt[b]) - Yt[b]) ** 2)
                opt.zero_grad()
                loss.backward()
                opt.step()
                losses.append(loss.item())
            sched.step()
            with torch.no_grad():
                vb = torch.as_tensor(val)
                vl = float(torch.mean(w * (mean_action(Xt[vb]) - Yt[vb]) ** 2)) if n_val else math.nan
            history.append({"epoch": epoch + 1, "train_mse": float(np.mean(losses)), "val_mse": vl})
            bar.set_postfix(train=f"{history[-1]['train_mse']:.4f}", val=f"{vl:.4f}")
        fit_s = time.perf_counter() - t1
        summary = {"dataset": str(dataset_path), "samples": int(len(X)), "episodes": int(dataset.total_episodes),
                   "feature_prep_s": round(prep_s, 1), "fit_s": round(fit_s, 1), "config": cfg.__dict__,
                   "history": history, "task": task}
        extra = {"training": {"algo": "ppo", "task": task, "env_steps": 0, "wall_time_s": round(prep_s + fit_s, 1),
                              "method": "behaviour cloning", "dataset": str(dataset_path), "seed": cfg.seed},
                 "recipe": recipe.to_dict()}
        path = save_agent(model, out / "model", algo="ppo", spec=recipe.spec, vecnormalize=vecnorm,
                          interface=env_interface(raw), extra=extra)
        summary["model"] = str(path)
        if evaluate:
            from .policy import load_sb3_policy
            from .training import EVAL_SEED_BASE, evaluate_on_envs
            t2 = time.perf_counter()
            seeds = [EVAL_SEED_BASE + i for i in range(recipe.eval_episodes)]
            result = evaluate_on_envs(lambda env: load_sb3_policy("ppo", path, env), evals, seeds)
            entry = {"env_steps": 0, "wall_time_s": round(prep_s + fit_s, 1),
                     "eval_time_s": round(time.perf_counter() - t2, 1), **result}
            write_text_atomic(out / "evaluations.json", json.dumps([entry], indent=1))
            summary["evaluation"] = {"mean": result["mean"], "score": result["score"]}
        write_text_atomic(out / "bc_summary.json", json.dumps(summary, indent=1))
        venv.close()
    finally:
        for env in evals:
            env.close()
    return summary
