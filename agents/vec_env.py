"""The agent interface over the native vector environment, as one stable-baselines3 ``VecEnv``.

:class:`BatchedAgentInterface` is :class:`~agents.wrappers.FeatureEncoder` and
:class:`~agents.wrappers.ResidualHoverAction` for N drones at once (NumPy over the drones; the
scalar classes stay the deployed path, used by :class:`~agents.policy.SB3Policy`, and a test checks
the two agree to float32 rounding). :class:`InspectionVecEnv` drives
:class:`~wt_inspect_env.vector.WindTurbineInspectionVectorEnv` with it: one SB3 step is one agent
decision per drone, held for ``action_repeat`` control steps with the policy action decoded at
the current attitude every step, rewards summed, the training-only shaping added - what
:class:`~agents.wrappers.InspectionAgentEnv` does for one env, so every recipe runs unchanged.

All drones step together, so a drone whose episode ends in the middle of a decision is already
in its next episode (the vector env resets it in the same step) for the rest of that decision; it
hovers there (the hover action) and its next observation is taken after those few control steps.
Recipe ``env_variants`` may vary the wind only (the vector env draws one per drone and episode);
other variants need the subprocess path (``backend="subprocess"``).
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
from gymnasium import spaces

from wt_inspect_env.dynamics import quat_to_rotmat_np
from wt_inspect_env.spaces import ActionScaling

from .wrappers import AgentSpec, ShapingConfig, camera_heading


class BatchedAgentInterface:
    """Features in, env actions out, for ``n`` drones (see the module docstring)."""

    def __init__(self, spec: AgentSpec, n: int, *, standoff: float, dt: float, scaling: ActionScaling) -> None:
        self.spec, self.n, self.standoff, self.dt, self.scaling = spec, n, standoff, dt, scaling
        cfg = spec.features
        self._decay = math.exp(-dt / cfg.integral_time_s)
        self._gain = cfg.integral_time_s * (1.0 - self._decay)
        self._ilimit = cfg.clip * cfg.integral_time_s * cfg.position_scale
        self._hover_thrust = scaling.hover_thrust
        self._lo, self._hi = scaling.lower, scaling.upper
        self.integral = np.zeros((n, 3))
        self.last_action = np.zeros((n, 4))
        self.hdir = np.tile([1.0, 0.0, 0.0], (n, 1))
        self.has_hdir = np.zeros(n, dtype=bool)
        self.err = np.zeros((n, 3))
        self._obs: dict[str, np.ndarray] = {}
        self._R = np.tile(np.eye(3), (n, 1, 1))

    def reset(self, idx: np.ndarray) -> None:
        self.integral[idx] = 0.0
        self.last_action[idx] = 0.0
        self.hdir[idx] = [1.0, 0.0, 0.0]
        self.has_hdir[idx] = False

    def note_action(self, u: np.ndarray) -> None:
        self.last_action = np.asarray(u, dtype=np.float64).copy()

    def update(self, idx: np.ndarray, obs: Mapping[str, np.ndarray]) -> None:
        """Consume one observation for drones ``idx`` (``obs`` rows belong to them)."""
        if len(idx) == 0:
            return
        o = {k: np.asarray(v, dtype=np.float64) for k, v in obs.items()}
        nx, ny = o["normal"][:, 0], o["normal"][:, 1]
        norm = np.hypot(nx, ny)
        ok = norm > 1e-6
        safe = np.where(ok, norm, 1.0)
        new_h = np.stack([nx / safe, ny / safe, np.zeros(len(idx))], axis=1)
        self.hdir[idx] = np.where(ok[:, None], new_h, self.hdir[idx])
        self.has_hdir[idx] |= ok
        ideal = o["point"] + self.standoff * self.hdir[idx]
        err = ideal - o["position"]
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
        """Cosine of drone ``i``'s camera heading error at its last update (the scalar formula)."""
        return camera_heading(self._R[i], self._obs["position"][i], self._obs["point"][i])[1]

    def features(self) -> np.ndarray:
        """(n, F) float32 features of every drone's last update (and last noted action)."""
        cfg, o, R = self.spec.features, self._obs, self._R
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
            elif g == "gravity_body":
                parts.append(-R[:, 2, :])
            elif g == "heading":
                fx, fy = R[:, 0, 0], R[:, 1, 0]
                ax, ay = point[:, 0] - x[:, 0], point[:, 1] - x[:, 1]
                nf, na = np.hypot(fx, fy), np.hypot(ax, ay)
                ok = (nf >= 1e-9) & (na >= 1e-9)
                d = np.where(ok, nf * na, 1.0)
                parts.append(np.stack([np.where(ok, (fx * ay - fy * ax) / d, 0.0),
                                       np.where(ok, (fx * ax + fy * ay) / d, 1.0)], axis=1))
            elif g == "body_rates":
                parts.append(o["body_rates"] / self.scaling.max_rate)
            elif g == "normal_body":
                parts.append(body(o["normal"]))
            elif g == "integral":
                parts.append(body(self.integral) / (cfg.integral_time_s * cfg.position_scale))
            elif g == "last_action":
                parts.append(self.last_action)
            elif g in ("progress", "coverage"):
                parts.append(o[g].reshape(-1, 1))
        return np.clip(np.concatenate(parts, axis=1), -cfg.clip, cfg.clip).astype(np.float32)

    def decode(self, u: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
        """(n, 4) env actions for policy actions ``u`` at attitudes ``quaternion`` (residual hover)."""
        cfg = self.spec.action
        R = quat_to_rotmat_np(np.asarray(quaternion, dtype=np.float64))
        if cfg.mode == "rates":
            rates = cfg.rate_scale * self.scaling.max_rate * u[:, :3]
        else:
            tilt = math.radians(cfg.max_tilt_deg)
            roll, pitch = tilt * u[:, 0], tilt * u[:, 1]
            z_h = np.stack([np.cos(roll) * np.sin(pitch), -np.sin(roll), np.cos(roll) * np.cos(pitch)], axis=1)
            fx, fy = R[:, 0, 0], R[:, 1, 0]
            nf = np.hypot(fx, fy)
            ok = nf > 1e-9
            c = np.where(ok, fx / np.where(ok, nf, 1.0), 1.0)
            s_ = np.where(ok, fy / np.where(ok, nf, 1.0), 0.0)
            z_w = np.stack([c * z_h[:, 0] - s_ * z_h[:, 1], s_ * z_h[:, 0] + c * z_h[:, 1], z_h[:, 2]], axis=1)
            z_b = np.einsum("nji,nj->ni", R, z_w)
            rates = np.stack([-cfg.attitude_gain * z_b[:, 1], cfg.attitude_gain * z_b[:, 0],
                              cfg.rate_scale * self.scaling.max_rate * u[:, 2]], axis=1)
        thrust = self._hover_thrust * (1.0 + cfg.thrust_scale * u[:, 3])
        if cfg.tilt_compensation:
            cz = R[:, 2, 2]
            thrust = thrust * np.where(cz * cfg.max_tilt_factor <= 1.0, cfg.max_tilt_factor,
                                       1.0 / np.where(cz * cfg.max_tilt_factor <= 1.0, 1.0, cz))
        cmd = np.concatenate([rates, thrust[:, None]], axis=1)
        lo, hi = self._lo, self._hi
        return np.clip(2.0 * (cmd - lo) / (hi - lo) - 1.0, -1.0, 1.0).astype(np.float32)


def _vec_env_base():
    """SB3's VecEnv, imported lazily (the ``rl`` extra)."""
    from stable_baselines3.common.vec_env import VecEnv
    return VecEnv


def make_inspection_vec_env(task: str, options: Mapping[str, Any], spec: AgentSpec, n_envs: int,
                            shaping: ShapingConfig | None = None, variants: Sequence[Mapping[str, Any]] = (),
                            weights: Sequence[float] | None = None, seed: int = 0):
    """An :class:`InspectionVecEnv` (class built on first use so that SB3 stays optional)."""
    VecEnv = _vec_env_base()

    class InspectionVecEnv(VecEnv):
        """stable-baselines3 VecEnv of agent decisions over the native vector env (module docstring)."""

        def __init__(self) -> None:
            from wt_inspect_env.env_config import TASKS
            from wt_inspect_env.validation import check_choice
            from wt_inspect_env.vector import WindTurbineInspectionVectorEnv

            check_choice("task", task, TASKS)
            opts = dict(options)
            extra: dict[str, Any] = {}
            if variants:
                for j, v in enumerate(variants):
                    other = sorted(set(v) - {"wind"})
                    if other:
                        raise ValueError(f"env_variants[{j}] varies {other}; the vector env varies only the wind "
                                         "per episode - train with backend='subprocess' for other variants")
                extra = {"wind_variants": [v.get("wind", opts.get("wind", "gust")) for v in variants],
                         "wind_variant_weights": None if weights is None else list(weights)}
                opts.pop("wind", None)
            self.venv = WindTurbineInspectionVectorEnv(num_envs=n_envs, task=task, **opts, **extra)
            u = self.venv
            self.iface = BatchedAgentInterface(spec, n_envs, standoff=u.config.standoff, dt=u.dt, scaling=u.scaling)
            self.shaping = shaping if shaping is not None else ShapingConfig()
            self._coarse_w = self.shaping.distance_coarse_weight * u.dt
            self._coarse_k = 1.0 / self.shaping.distance_coarse_scale ** 2
            c = spec.features.clip
            obs_space = spaces.Box(-c, c, shape=(spec.features.size,), dtype=np.float32)
            act_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
            super().__init__(n_envs, obs_space, act_space)
            self._seed = seed
            self._actions: np.ndarray | None = None
            self._raw: dict[str, np.ndarray] | None = None
            self._hover = np.tile(u.scaling.hover_action(), (n_envs, 1))

        def reset(self):
            obs, _ = self.venv.reset(seed=self._seed)
            self._seed = None   # later resets continue each drone's generator
            idx = np.arange(self.num_envs)
            self.iface.reset(idx)
            self.iface.update(idx, obs)
            self._raw = obs
            return self.iface.features()

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)

        def step_wait(self):
            n, u = self.num_envs, self._actions
            self.iface.note_action(u)
            total = np.zeros(n)
            taken = np.zeros(n, dtype=np.int64)
            done = np.zeros(n, dtype=bool)
            infos: list[dict[str, Any]] = [{} for _ in range(n)]
            raw = self._raw
            for _ in range(spec.action_repeat):
                act = self.iface.decode(u, raw["quaternion"])
                act[done] = self._hover[done]
                obs, reward, term, trunc, info = self.venv.step(act)
                live = ~done
                total[live] += reward[live]
                taken[live] += 1
                ended = term | trunc
                fin = np.flatnonzero(ended & live)
                cont = np.flatnonzero(~(ended & live))
                # drones whose episode ended now: features of the final observation first
                if len(fin):
                    final = {k: np.stack([info["final_obs"][i][k] for i in fin]) for k in obs}
                    self.iface.update(fin, final)
                    if self._coarse_w > 0.0:
                        e2 = np.einsum("ij,ij->i", self.iface.err[fin], self.iface.err[fin])
                        total[fin] += np.where(term[fin], 0.0, self._coarse_w / (1.0 + self._coarse_k * e2))
                    if self.shaping.centering_fine_weight > 0.0:
                        for i in fin[~term[fin]].tolist():
                            total[i] += self.shaping.centering_fine(self.venv.dt, self.iface.heading_cos(i))
                    feats = self.iface.features()
                    fm = info["final_info"]["metrics"]
                    for i in fin.tolist():
                        infos[i] = {"terminal_observation": feats[i].copy(),
                                    "TimeLimit.truncated": bool(trunc[i] and not term[i]),
                                    "metrics": {k: float(v[i]) for k, v in fm.items()},
                                    "termination": info["final_info"]["termination"][i],
                                    "mission_complete": bool(info["final_info"]["mission_complete"][i]),
                                    "time": float(info["final_info"]["episode_steps"][i] * self.venv.dt),
                                    "variant": int(info["final_info"]["variant"][i])}
                    self.iface.reset(fin)
                    self.iface.update(fin, {k: v[fin] for k, v in obs.items()})
                if len(cont):
                    self.iface.update(cont, {k: v[cont] for k, v in obs.items()})
                    lc = cont[live[cont]]
                    if self._coarse_w > 0.0:
                        e2 = np.einsum("ij,ij->i", self.iface.err[lc], self.iface.err[lc])
                        total[lc] += self._coarse_w / (1.0 + self._coarse_k * e2)
                    if self.shaping.centering_fine_weight > 0.0:
                        for i in lc.tolist():
                            total[i] += self.shaping.centering_fine(self.venv.dt, self.iface.heading_cos(i))
                done |= ended
                raw = obs
            self._raw = raw
            for i in range(n):
                infos[i]["env_steps"] = int(taken[i])
            feats = self.iface.features()
            return feats, total.astype(np.float32), done.copy(), infos

        def close(self) -> None:
            self.venv.close()

        def get_attr(self, attr_name, indices=None):
            return [getattr(self, attr_name, None) for _ in self._idx(indices)]

        def set_attr(self, attr_name, value, indices=None) -> None:
            setattr(self, attr_name, value)

        def env_method(self, method_name, *args, indices=None, **kwargs):
            raise AttributeError(f"InspectionVecEnv has no per-env method {method_name!r}")

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False for _ in self._idx(indices)]

        def seed(self, seed=None):
            self._seed = seed
            return [seed] * self.num_envs

        def _idx(self, indices):
            if indices is None:
                return range(self.num_envs)
            return [indices] if isinstance(indices, int) else indices

    return InspectionVecEnv()
