"""The agent interface over the native vector environment, as one stable-baselines3 ``VecEnv``.

:class:`BatchedAgentInterface` is :class:`~agents.wrappers.FeatureEncoder` and
:class:`~agents.wrappers.ResidualHoverAction` for N drones at once (both are fronts over a batch
of one of the same code, :mod:`agents.interface`). :class:`InspectionVecEnv` drives
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

from typing import Any, Mapping, Sequence

import numpy as np
from gymnasium import spaces

from wt_inspect_env.task.spaces import ActionScaling

from .interface import BatchedDecoder, BatchedFeatures
from .wrappers import AgentSpec, ShapingConfig


class BatchedAgentInterface:
    """Features in, env actions out, for ``n`` drones: :class:`~agents.interface.BatchedFeatures`
    and :class:`~agents.interface.BatchedDecoder` of one agent spec."""

    def __init__(self, spec: AgentSpec, n: int, *, standoff: float, dt: float, scaling: ActionScaling) -> None:
        self.spec, self.n, self.standoff, self.dt, self.scaling = spec, n, standoff, dt, scaling
        self.encoder = BatchedFeatures(spec.features, n, standoff=standoff, dt=dt, max_rate=scaling.max_rate)
        self.decoder = BatchedDecoder(spec.action, scaling)

    @property
    def err(self) -> np.ndarray:
        """Each drone's position error to its ideal pose [m], (n, 3), as of its last update."""
        return self.encoder.err

    def reset(self, idx: np.ndarray) -> None:
        """Forget the previous episode of drones ``idx``."""
        self.encoder.reset(idx)

    def note_action(self, u: np.ndarray) -> None:
        """Remember the policy actions now being applied (the ``last_action`` feature)."""
        self.encoder.note_action(u)

    def update(self, idx: np.ndarray, obs: Mapping[str, np.ndarray]) -> None:
        """Consume one observation for drones ``idx`` (``obs`` rows belong to them)."""
        if len(idx):
            self.encoder.update(idx, obs)

    def heading_cos(self, i: int) -> float:
        """Cosine of drone ``i``'s camera heading error at its last update."""
        return self.encoder.heading_cos(i)

    def heading_cos_of(self, idx: np.ndarray) -> np.ndarray:
        """Cosines of drones ``idx``'s camera heading errors at their last update."""
        return self.encoder.heading_cos_of(idx)

    def features(self) -> np.ndarray:
        """The agent's features of every drone, (n, size)."""
        return self.encoder.features()

    def decode(self, u: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
        """(n, 4) env actions for policy actions ``u`` at attitudes ``quaternion`` (residual hover)."""
        return self.decoder.decode(u, quaternion)


def _vec_env_base():
    """SB3's VecEnv, imported lazily (the ``rl`` extra)."""
    from stable_baselines3.common.vec_env import VecEnv
    return VecEnv


def make_inspection_vec_env(task: str, options: Mapping[str, Any], spec: AgentSpec, n_envs: int,
                            shaping: ShapingConfig | None = None, variants: Sequence[Mapping[str, Any]] = (),
                            weights: Sequence[float] | None = None, seed: int = 0,
                            turbines: Mapping[str, Any] | None = None):
    """An :class:`InspectionVecEnv` (class built on first use so that SB3 stays optional).
    ``turbines``: many-turbine options (:func:`~wt_inspect_env.vector.turbines.many_turbine_kwargs`)."""
    VecEnv = _vec_env_base()

    class InspectionVecEnv(VecEnv):
        """stable-baselines3 VecEnv of agent decisions over the native vector env (module docstring)."""

        def __init__(self) -> None:
            from wt_inspect_env.task.env_config import TASKS
            from wt_inspect_env.util.validation import check_choice
            from wt_inspect_env.vector import WindTurbineInspectionVectorEnv
            from wt_inspect_env.vector.turbines import many_turbine_kwargs

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
            if turbines is not None:
                extra.update(many_turbine_kwargs(turbines))
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
                    kept = fin[~term[fin]]
                    if self.shaping.centering_fine_weight > 0.0 and len(kept):
                        total[kept] += self.shaping.centering_fine_batch(self.venv.dt, self.iface.heading_cos_of(kept))
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
                        if "turbine" in info["final_info"]:
                            infos[i]["turbine"] = {k: v[i] for k, v in info["final_info"]["turbine"].items()}
                    self.iface.reset(fin)
                    self.iface.update(fin, {k: v[fin] for k, v in obs.items()})
                if len(cont):
                    self.iface.update(cont, {k: v[cont] for k, v in obs.items()})
                    lc = cont[live[cont]]
                    if self._coarse_w > 0.0:
                        e2 = np.einsum("ij,ij->i", self.iface.err[lc], self.iface.err[lc])
                        total[lc] += self._coarse_w / (1.0 + self._coarse_k * e2)
                    if self.shaping.centering_fine_weight > 0.0 and len(lc):
                        total[lc] += self.shaping.centering_fine_batch(self.venv.dt, self.iface.heading_cos_of(lc))
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
