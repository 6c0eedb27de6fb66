"""Observation, reward and termination of one control step, for a batch of drones (one row per drone).

The default task's terms (:class:`~wt_inspect_env.task.hooks.TaskHooks` calls these): thin wrappers over
the compiled world core (:mod:`~wt_inspect_env.native.world_core`), which computes each drone's row with
the same scalar arithmetic whatever the batch, so the single environment (a batch of one) and the
vector environment agree by construction.
"""
from __future__ import annotations

import ctypes

import numpy as np

from ..native import world_core as wc
from .env_config import RewardConfig

REWARD_TERMS = ("coverage", "distance", "centering", "effort", "crash")


def observations(state: np.ndarray, rates: np.ndarray, point: np.ndarray, normal: np.ndarray,
                 point_velocity: np.ndarray, coverage: np.ndarray, progress: np.ndarray,
                 safe: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The Dict observation (see :mod:`~wt_inspect_env.task.spaces`), batched: ``(N, k)`` float32 arrays.

    Rows flagged in ``safe`` (non-finite states) have NaN/inf replaced by 0 so that the last
    observation of a diverged episode is still inside the observation space. The quaternion is
    normalised (level if it has no norm), ``normal`` clipped to [-1, 1], ``coverage`` to at most 1
    and ``progress`` to [0, 1].
    """
    if safe is None:
        safe = np.zeros(len(state), dtype=bool)
    return wc.observations(state, rates, point, normal, point_velocity, coverage, progress, safe)


def reward_terms(w: RewardConfig, dt: float, n_triangles: int, action: np.ndarray, hover: np.ndarray,
                 state: np.ndarray, ideal: np.ndarray, point: np.ndarray, n_new: np.ndarray,
                 crashed: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Reward and its terms per drone (see :class:`RewardConfig`); a non-finite state earns the
    crash penalty alone."""
    n = len(state)
    weights = wc.reward_weights(w, dt, n_triangles)
    reward, terms = np.empty(n), np.empty((n, len(REWARD_TERMS)))
    args = (wc.c_array(action, float), wc.c_array(hover, float), wc.c_array(state, float), wc.c_array(ideal, float),
            wc.c_array(point, float), wc.c_array(n_new, np.int64), wc.c_array(crashed, np.bool_))
    wc.library().wt_rewards(ctypes.addressof(weights), n, *(wc.addr(a) for a in args), wc.addr(reward),
                            wc.addr(terms))
    return reward, {k: terms[:, j] for j, k in enumerate(REWARD_TERMS)}


def clearance_reward(w: RewardConfig, dt: float, d_min: float, distance: np.ndarray) -> np.ndarray:
    """The ``clearance`` reward term per drone: ``-w.clearance * dt`` times the shortfall below
    ``d_min + w.clearance_margin`` as a share of ``d_min`` (0 for a drone without a finite distance)."""
    short = np.maximum(0.0, (d_min + w.clearance_margin) - distance) / d_min
    return np.where(np.isfinite(short), -w.clearance * dt * short, 0.0)


def too_close(code: np.ndarray, distance: np.ndarray, limit: float) -> np.ndarray:
    """The drones that ``clearance_limit`` ends: going on (code 0) and closer than ``limit`` to
    the structure."""
    return (code == 0) & (distance < limit)


def termination_codes(state: np.ndarray, collision: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                      ideal: np.ndarray, waiting: np.ndarray, pose_error_limit: float | None) -> np.ndarray:
    """Termination code per drone: 0 going on, 1 non-finite state, 2 collision, 3 outside the
    working volume ``[lo, hi]`` (per drone), 4 farther than ``pose_error_limit`` from the ideal
    stand-off pose (not while ``waiting`` for the rotor turn; None: no limit)."""
    n = len(state)
    code = np.empty(n, dtype=np.int64)
    args = (wc.c_array(state, float), wc.c_array(collision, np.bool_), wc.c_array(lo, float), wc.c_array(hi, float),
            wc.c_array(ideal, float), wc.c_array(waiting, np.bool_))
    limit = float("nan") if pose_error_limit is None else float(pose_error_limit)
    wc.library().wt_terminations(n, *(wc.addr(a) for a in args), limit, wc.addr(code))
    return code
