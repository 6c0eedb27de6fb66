"""Observation and reward of one control step, for a batch of drones (one row per drone).

Both :class:`~wt_inspect_env.env.WindTurbineInspectionEnv` (a batch of one) and the vector
environment call these, so the two agree by construction. The arithmetic is element-wise, with
``math.exp``/``math.hypot`` per row (NumPy's versions need not match them to the last bit), so a
drone's numbers do not depend on the batch it is computed in.
"""
from __future__ import annotations

import math

import numpy as np

from .env_config import RewardConfig

REWARD_TERMS = ("coverage", "distance", "centering", "effort", "crash")


def observations(state: np.ndarray, rates: np.ndarray, point: np.ndarray, normal: np.ndarray,
                 point_velocity: np.ndarray, coverage: np.ndarray, progress: np.ndarray,
                 safe: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The Dict observation (see :mod:`~wt_inspect_env.spaces`), batched: ``(N, k)`` float32 arrays.

    Rows flagged in ``safe`` (non-finite states) have NaN/inf replaced by 0 so that the last
    observation of a diverged episode is still inside the observation space.
    """
    if safe is not None and safe.any():
        state = np.where(safe[:, None], np.nan_to_num(state, nan=0.0, posinf=0.0, neginf=0.0), state)
        rates = np.where(safe[:, None], np.nan_to_num(rates), rates)
    q = state[:, 6:10]
    nq = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])
    good = nq > 1e-9
    q = np.where(good[:, None], q / np.where(good, nq, 1.0)[:, None], np.array([0.0, 0.0, 0.0, 1.0]))
    f32 = np.float32
    return {
        "position": state[:, 0:3].astype(f32), "velocity_body": state[:, 3:6].astype(f32),
        "quaternion": np.clip(q, -1.0, 1.0).astype(f32), "body_rates": rates.astype(f32),
        "point": point.astype(f32), "normal": np.clip(normal, -1.0, 1.0).astype(f32),
        "point_velocity": point_velocity.astype(f32),
        "coverage": np.minimum(1.0, coverage).astype(f32)[:, None],
        "progress": np.minimum(1.0, np.maximum(0.0, progress)).astype(f32)[:, None],
    }


def reward_terms(w: RewardConfig, dt: float, n_triangles: int, action: np.ndarray, hover: np.ndarray,
                 state: np.ndarray, ideal: np.ndarray, point: np.ndarray, n_new: np.ndarray,
                 crashed: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Reward and its terms per drone (see :class:`RewardConfig`); a non-finite state earns the
    crash penalty alone."""
    n = len(state)
    finite = np.isfinite(state).all(axis=1)
    st = np.where(finite[:, None], state, 0.0)
    d0, d1, d2 = st[:, 0] - ideal[:, 0], st[:, 1] - ideal[:, 1], st[:, 2] - ideal[:, 2]
    e = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    a0, a1 = point[:, 0] - st[:, 0], point[:, 1] - st[:, 1]
    axy = np.array([math.hypot(x, y) for x, y in zip(a0.tolist(), a1.tolist())])
    qx, qy, qz, qw = st[:, 6], st[:, 7], st[:, 8], st[:, 9]
    fwd0 = 1 - 2 * (qy * qy + qz * qz)
    fwd1 = 2 * (qx * qy + qw * qz)
    ok = axy > 1e-9
    h = np.where(ok, (fwd0 * a0 + fwd1 * a1) / np.where(ok, axy, 1.0), 0.0)
    r = e / w.distance_scale
    gauss = np.array([math.exp(x) for x in (-0.5 * (r * r)).tolist()])
    u = action - hover
    effort = ((u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1]) + u[:, 2] * u[:, 2]) + u[:, 3] * u[:, 3]
    zero = np.zeros(n)
    terms = {
        "coverage": np.where(finite, w.coverage * n_new / n_triangles, zero),
        "distance": np.where(finite, w.distance * dt * gauss, zero),
        "centering": np.where(finite, w.centering * dt * h, zero),
        "effort": np.where(finite, -w.effort * dt * effort, zero),
        "crash": np.where(crashed | ~finite, -w.crash, zero),
    }
    reward = terms["coverage"] + terms["distance"] + terms["centering"] + terms["effort"] + terms["crash"]
    return reward, terms
