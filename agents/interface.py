"""How an agent talks to the environment, for N drones: features in, env actions out.

One implementation serves every path: :class:`BatchedFeatures` turns the env's Dict observations
into the feature vector (stateful: error integral, last action, stand-off direction) and
:class:`BatchedDecoder` turns the policy's residual-hover action into the env's normalised action.
The training vector env (:mod:`agents.vec_env`) uses them for all its drones; the one-drone
classes of :mod:`agents.wrappers` (:class:`~agents.wrappers.FeatureEncoder`,
:class:`~agents.wrappers.ResidualHoverAction`, used by the single-env training backends and by
every deployed agent, :class:`~agents.policy.SB3Policy`) are validated fronts over a batch of one.
So an agent trained on the vector env is deployed with the same arithmetic it learned on.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.physics.dynamics import quat_to_rotmat_np
from wt_inspect_env.task.spaces import ActionScaling

#: feature groups that need an optional observation entry: group -> (entry, the boolean env option that adds it)
NEEDS_OPTION: dict[str, tuple[str, str]] = {"structure_body": ("structure", "structure_observation")}


def needed_env_options(groups: Any) -> dict[str, bool]:
    """The env options (``{option: True}``) that the feature ``groups`` need."""
    return {NEEDS_OPTION[g][1]: True for g in groups if g in NEEDS_OPTION}


def check_entries(groups: Any, keys: Any) -> None:
    """ValueError naming the group and the env option when one of the feature ``groups`` needs an
    observation entry that is not among ``keys``."""
    for g in groups:
        if g in NEEDS_OPTION and NEEDS_OPTION[g][0] not in keys:
            raise ValueError(f"feature group {g!r} needs the observation entry {NEEDS_OPTION[g][0]!r}: "
                             f"make the env with {NEEDS_OPTION[g][1]}=True")


def camera_headings(R: np.ndarray, position: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sin, cos)`` (each (n,)) of the horizontal angle from each camera axis (the horizontal
    projection of ``R e_x``, R (n, 3, 3); the gimbal levels the camera) to its inspection point
    (n, 3) seen from ``position`` (n, 3); ``(0, 1)`` when either is vertical."""
    fx, fy = R[:, 0, 0], R[:, 1, 0]
    ax, ay = point[:, 0] - position[:, 0], point[:, 1] - position[:, 1]
    nf, na = np.hypot(fx, fy), np.hypot(ax, ay)
    ok = (nf >= 1e-9) & (na >= 1e-9)
    d = np.where(ok, nf * na, 1.0)
    return np.where(ok, (fx * ay - fy * ax) / d, 0.0), np.where(ok, (fx * ax + fy * ay) / d, 1.0)


def camera_heading(R: np.ndarray, position: np.ndarray, point: np.ndarray) -> tuple[float, float]:
    """:func:`camera_headings` of one camera (R (3, 3), position and point (3,)), as floats."""
    s, c = camera_headings(np.asarray(R, dtype=float)[None], np.asarray(position, dtype=float)[None],
                           np.asarray(point, dtype=float)[None])
    return float(s[0]), float(c[0])


class BatchedFeatures:
    """The feature vectors of ``n`` drones (``config``: a :class:`~agents.wrappers.FeatureConfig`).

    Call :meth:`reset` at an episode start, :meth:`update` on *every* observation (each control
    step, also while an action is held) and :meth:`note_action` with each new policy action.
    """

    def __init__(self, config: Any, n: int, *, standoff: float, dt: float, max_rate: float) -> None:
        self.config, self.n, self.standoff, self.dt, self.max_rate = config, n, standoff, dt, max_rate
        self._decay = math.exp(-dt / config.integral_time_s)
        self._gain = config.integral_time_s * (1.0 - self._decay)
        self._ilimit = config.clip * config.integral_time_s * config.position_scale
        self.integral = np.zeros((n, 3))
        self.last_action = np.zeros((n, 4))
        self.hdir = np.tile([1.0, 0.0, 0.0], (n, 1))
        self.err = np.zeros((n, 3))
        # the ideal pose's velocity beyond the point's: d_ref times the horizontal normal's turn
        # per second, by finite differences between updates (0 on an episode's first update)
        self.pose_turn = np.zeros((n, 3))
        self._fresh = np.ones(n, dtype=bool)
        self._obs: dict[str, np.ndarray] = {}
        self._R = np.tile(np.eye(3), (n, 1, 1))

    def reset(self, idx: Any) -> None:
        """Clear the integral, last action and heading memory of drones ``idx`` (a new episode)."""
        self.integral[idx] = 0.0
        self.last_action[idx] = 0.0
        self.hdir[idx] = [1.0, 0.0, 0.0]
        self.pose_turn[idx] = 0.0
        self._fresh[idx] = True

    def note_action(self, u: np.ndarray, idx: Any = slice(None)) -> None:
        """Remember the policy actions now being applied (the ``last_action`` feature)."""
        self.last_action[idx] = np.asarray(u, dtype=np.float64)

    def ideal_positions(self, idx: Any, normal: np.ndarray, point: np.ndarray) -> np.ndarray:
        """The stand-off poses ``point + d_ref n_xy / |n_xy|`` of drones ``idx`` (their remembered
        horizontal direction where the normal is (nearly) vertical - the env does the same along
        its path), updating the remembered direction."""
        nx, ny = normal[:, 0], normal[:, 1]
        norm = np.hypot(nx, ny)
        ok = norm > 1e-6
        safe = np.where(ok, norm, 1.0)
        new_h = np.stack([nx / safe, ny / safe, np.zeros(len(nx))], axis=1)
        self.hdir[idx] = np.where(ok[:, None], new_h, self.hdir[idx])
        return point + self.standoff * self.hdir[idx]

    def update(self, idx: Any, obs: Mapping[str, np.ndarray]) -> None:
        """Consume one observation for drones ``idx`` (``obs`` rows belong to them)."""
        o = {k: np.asarray(v, dtype=np.float64) for k, v in obs.items()}
        if len(o["position"]) == 0:
            return
        h_before = self.hdir[idx].copy()
        err = self.ideal_positions(idx, o["normal"], o["point"]) - o["position"]
        turn = self.standoff * (self.hdir[idx] - h_before) / self.dt
        self.pose_turn[idx] = np.where(self._fresh[idx][:, None], 0.0, turn)
        self._fresh[idx] = False
        # exact (zero-order-hold) discretisation of dI/dt = e - I / T: I -> T e for a constant e
        integ = self.integral[idx] * self._decay + self._gain * err
        n = np.linalg.norm(integ, axis=1)
        over = n > self._ilimit
        integ[over] *= (self._ilimit / n[over])[:, None]
        self.integral[idx] = integ
        self.err[idx] = err
        for k, v in o.items():
            if k not in self._obs:
                self._obs[k] = np.zeros((self.n,) + v.shape[1:])
            self._obs[k][idx] = v
        self._R[idx] = quat_to_rotmat_np(o["quaternion"])

    def heading_cos(self, i: int) -> float:
        """Cosine of drone ``i``'s camera heading error at its last update."""
        return float(self.heading_cos_of(np.array([i]))[0])

    def heading_cos_of(self, idx: np.ndarray) -> np.ndarray:
        """Cosines (len(idx),) of drones ``idx``'s camera heading errors at their last update."""
        return camera_headings(self._R[idx], self._obs["position"][idx], self._obs["point"][idx])[1]

    def features(self) -> np.ndarray:
        """(n, F) float32 features of every drone's last update (and last noted action)."""
        cfg, o, R = self.config, self._obs, self._R
        Rt = np.transpose(R, (0, 2, 1))
        x, point = o["position"], o["point"]

        def body(v: np.ndarray) -> np.ndarray:
            return np.einsum("nij,nj->ni", Rt, v)

        parts: list[np.ndarray] = []
        for g in cfg.groups:
            if g == "ideal_body":
                parts.append(body(self.err) / cfg.position_scale)
            elif g == "point_body":
                parts.append(body(point - x) / self.standoff)
            elif g == "velocity_body":
                parts.append((o["velocity_body"] - body(o["point_velocity"])) / cfg.velocity_scale)
            elif g == "pose_velocity_body":
                parts.append((o["velocity_body"] - body(o["point_velocity"] + self.pose_turn)) / cfg.velocity_scale)
            elif g == "gravity_body":
                parts.append(-R[:, 2, :])
            elif g == "heading":
                parts.append(np.stack(camera_headings(R, x, point), axis=1))
            elif g == "body_rates":
                parts.append(o["body_rates"] / self.max_rate)
            elif g == "normal_body":
                parts.append(body(o["normal"]))
            elif g == "integral":
                parts.append(body(self.integral) / (cfg.integral_time_s * cfg.position_scale))
            elif g == "last_action":
                parts.append(self.last_action)
            elif g in ("progress", "coverage"):
                parts.append(o[g].reshape(-1, 1))
            elif g == "structure_body":
                check_entries((g,), o)
                st = o["structure"]
                parts.append(np.concatenate([body(st[:, 0:3]), st[:, 3:4]], axis=1) / self.standoff)
        return np.clip(np.concatenate(parts, axis=1), -cfg.clip, cfg.clip).astype(np.float32)


class BatchedDecoder:
    """Policy actions ``u in [-1, 1]^4`` of ``n`` drones -> the env's normalised actions
    (``config``: an :class:`~agents.wrappers.ActionConfig`; see :mod:`agents.wrappers`)."""

    def __init__(self, config: Any, scaling: ActionScaling) -> None:
        self.config, self.scaling = config, scaling
        self.hover_thrust = scaling.hover_thrust
        self._lo, self._hi = scaling.lower, scaling.upper

    def command(self, u: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
        """(n, 4) physical commands ``[p, q, r, T]`` (before saturation at the airframe's bounds)."""
        cfg = self.config
        u = np.asarray(u, dtype=np.float64)
        R = quat_to_rotmat_np(np.asarray(quaternion, dtype=np.float64))
        if cfg.mode == "rates":
            rates = cfg.rate_scale * self.scaling.max_rate * u[:, :3]
        else:   # attitude: u[0], u[1] = desired roll, pitch in the heading frame; P loop to rates
            tilt = math.radians(cfg.max_tilt_deg)
            roll, pitch = tilt * u[:, 0], tilt * u[:, 1]
            z_h = np.stack([np.cos(roll) * np.sin(pitch), -np.sin(roll), np.cos(roll) * np.cos(pitch)], axis=1)
            fx, fy = R[:, 0, 0], R[:, 1, 0]
            nf = np.hypot(fx, fy)
            ok = nf > 1e-9
            c = np.where(ok, fx / np.where(ok, nf, 1.0), 1.0)
            s_ = np.where(ok, fy / np.where(ok, nf, 1.0), 0.0)
            z_w = np.stack([c * z_h[:, 0] - s_ * z_h[:, 1], s_ * z_h[:, 0] + c * z_h[:, 1], z_h[:, 2]], axis=1)
            z_b = np.einsum("nji,nj->ni", R, z_w)      # desired thrust axis in the body frame
            rates = np.stack([-cfg.attitude_gain * z_b[:, 1], cfg.attitude_gain * z_b[:, 0],
                              cfg.rate_scale * self.scaling.max_rate * u[:, 2]], axis=1)
        thrust = self.hover_thrust * (1.0 + cfg.thrust_scale * u[:, 3])
        if cfg.tilt_compensation:
            cz = R[:, 2, 2]    # cos(tilt): body z . world z
            thrust = thrust * np.where(cz * cfg.max_tilt_factor <= 1.0, cfg.max_tilt_factor,
                                       1.0 / np.where(cz * cfg.max_tilt_factor <= 1.0, 1.0, cz))
        return np.concatenate([rates, thrust[:, None]], axis=1)

    def decode(self, u: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
        """(n, 4) float32 env actions (the commands normalised, saturated at the bounds)."""
        cmd = self.command(u, quaternion)
        lo, hi = self._lo, self._hi
        return np.clip(2.0 * (cmd - lo) / (hi - lo) - 1.0, -1.0, 1.0).astype(np.float32)
