"""The behaviour digest of a training run: what its first update does, so that a training study is
judged current by behaviour (like the studies that fly, :mod:`wt_inspect.behaviour`), not by a hash of
the code.

A training study takes tens of minutes per seed; re-running it to check that the code still makes it
is out of the question, and a code hash makes it stale on every refactor. What a refactor must not
change, and what a change of the task, the agent interface or the learner does change, shows in the
run's first PPO iteration: the rollout (positions and body velocities of the first and the last drone
after each agent decision, and their cumulative training reward with the shaping, before
normalisation) and the policy after the first update (its deterministic action for the first and the
last drone's first observation). The recipe is data, read again from its file; the code that turns it
into behaviour is what the digest watches.

Between machines of one kind, floating point differs in the last digits; over one rollout (a few
simulated seconds) and one update that stays many orders below the rounding (4 decimals) and the
tolerance (2e-3) of :mod:`wt_inspect.behaviour`; a changed reward weight, feature, action decoding or
PPO setting moves at least one of these by more.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

#: decimals of the recorded samples (as the flown digests)
DECIMALS = 4
#: SB3's statistics of the first update that the digest records
UPDATE_STATISTICS = ("approx_kl", "clip_fraction", "value_loss", "policy_gradient_loss", "entropy_loss")


def _vector_env(venv):
    """The native vector env under SB3's wrappers (VecNormalize) and the agent interface."""
    inner = venv
    while not hasattr(inner, "worlds"):
        inner = inner.venv
    return inner


def first_update_digest(algo: str, task: str, n_envs: int, timesteps: int, *, recipe: str | Path | None = None,
                        resume: str | Path | None = None, seed: int = 0, trust_model: bool = False) -> dict[str, Any]:
    """Build the run ``wt-inspect train`` would start (same recipe, task, drones, seed and resumed
    model, vector backend), collect its first rollout, make its first update, and digest both (the
    module docstring); nothing is written. Needs the ``rl`` extra."""
    import torch

    from .training import build_run, new_stage, resolve_run

    if algo != "ppo":
        raise ValueError(f"a training digest needs algorithm 'ppo', got {algo!r}")
    rec, ckpt_doc, legacy = resolve_run(algo, recipe=recipe, resume=resume, trust_model=trust_model)
    threads = torch.get_num_threads()
    torch.set_num_threads(rec.torch_threads)
    try:
        model, vecnorm, venv = build_run(algo, task, n_envs, rec, backend="vector", seed=seed, resume=resume,
                                         ckpt_doc=ckpt_doc, recipe=recipe, trust_model=trust_model, legacy=legacy)
        try:
            vector = _vector_env(venv)
            rows = [0, n_envs - 1]
            samples: dict[str, list] = {"position": [], "velocity": [], "reward": []}
            first_obs: list[np.ndarray] = []
            total = np.zeros(len(rows) + 1)
            n_steps = int(model.n_steps)

            from stable_baselines3.common.callbacks import BaseCallback

            class Recorder(BaseCallback):
                """Records the first rollout; stops the second at its first step (after one update)."""

                def _on_rollout_start(self) -> None:
                    if not first_obs:
                        first_obs.append(np.array(self.model._last_obs, dtype=np.float32))

                def _on_step(self) -> bool:
                    if len(samples["position"]) >= n_steps:
                        return False
                    state = vector.state
                    raw = np.asarray(vecnorm.get_original_reward() if vecnorm is not None else self.locals["rewards"],
                                     dtype=float)
                    total[:] += np.append(raw[rows], raw.mean())
                    samples["position"].append(state[rows, 0:3].reshape(-1))
                    samples["velocity"].append(state[rows, 3:6].reshape(-1))
                    samples["reward"].append(total.copy())
                    return True

            # the run's whole length, so that a learning-rate schedule is where the run's first update has it
            agent_steps = max(int(np.ceil(timesteps / rec.spec.action_repeat)), 2 * n_steps * n_envs)
            model.learn(total_timesteps=agent_steps, callback=Recorder(),
                        reset_num_timesteps=new_stage(ckpt_doc, recipe), progress_bar=False)
            logged = model.logger.name_to_value
            update = [float(logged.get(f"train/{k}", np.nan)) for k in UPDATE_STATISTICS]
            action, _ = model.policy.predict(first_obs[0], deterministic=True)
        finally:
            venv.close()
    finally:
        torch.set_num_threads(threads)
    dt = rec.spec.action_repeat * float(vector.dt)
    out: dict[str, Any] = {"t": [round((k + 1) * dt, 6) for k in range(len(samples["position"]))]}
    for key, vals in samples.items():
        out[key] = np.round(np.asarray(vals, dtype=float), DECIMALS).tolist()
    action = np.asarray(action, dtype=float)
    summary = np.concatenate([action[[0, -1]].reshape(-1), action.mean(axis=0)])
    out["action"] = np.round(summary[None], DECIMALS).tolist()
    out["update"] = np.round(np.asarray(update)[None], DECIMALS).tolist()
    return out
