"""A native Gymnasium vector environment: N inspection drones in one process and one PyBullet world.

``gym.make_vec("WindTurbineInspection-v0", num_envs=N, vectorization_mode="vector_entry_point",
**options)`` builds :class:`WindTurbineInspectionVectorEnv` for any registered task. Drone ``i``
is the single :class:`~wt_inspect_env.env.WindTurbineInspectionEnv` made with the same options:
its own seed (``reset(seed=s)`` seeds drone ``i`` with ``s + i``), wind field, reference, coverage,
metrics and episode clock, and under the same actions the same observations, rewards, terminations,
coverage and metrics, bit for bit (tested for N = 1, 4, 16 across autoresets and the rotor turn).

What is shared: the planned mission (one turbine, one task), the PyBullet client
(:class:`~wt_inspect_env.vector.sim.BatchedQuadrotorSim`) and the camera-ray batch. Per-drone wind
is supported (``winds=[spec_0, ..., spec_N-1]``); per-drone turbines or tasks are not (one mission
is planned per vector env - make one vector env per turbine) and are refused with a clear error.
Domain randomisation (``randomization=...``) is drawn per drone from drone ``i``'s stream exactly as
the single env draws it (its plant, noise and latency; the draw of an ended episode is in
``info["final_info"]["randomization"]``, the running ones in :attr:`randomization`); image
observations and ``reset(options=...)`` are single-env only and refused.

Autoreset: ``AutoresetMode.SAME_STEP`` (in ``metadata["autoreset_mode"]``) - a drone whose
episode ends is reset inside the same ``step``; the returned observation is the first of its new
episode, and the last one is in ``info["final_obs"][i]`` with the ended episode's info (including
``"metrics"``) in ``info["final_info"]`` (masks ``info["_final_obs"]``, ``info["_final_info"]``),
the layout :class:`gymnasium.vector.SyncVectorEnv` gives in that mode. The per-step info holds cheap
per-drone arrays (coverage, phase, time, termination, reward terms, ...); the full metrics of a
running episode are :meth:`metrics` ``(i)``.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..camera import GimbalCamera
from ..coverage import TriangleVisibility
from ..env import grow_to_start, observation_space, start_state
from ..env_config import EnvConfig
from ..metrics import MetricsConfig
from ..mission import build_mission
from ..randomization import RandomizationDraw, noisy_state
from ..randomization import draw as draw_randomization
from ..reference import InspectionReference, ReferenceConfig
from ..sim import SimConfig
from ..spaces import ActionScaling
from ..step_terms import REWARD_TERMS, observations, reward_terms
from ..validation import check_actions
from ..wind import make_wind
from .metrics import BatchedMetrics
from .reference import BatchedReference
from .sim import BatchedQuadrotorSim, ray_mask

_TERMINATIONS = (None, "non_finite_state", "collision", "left_working_volume", "lost_pose")
_MAX_RAYS = 16383


def _check_num_envs(num_envs: Any) -> int:
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    return int(num_envs)


class WindTurbineInspectionVectorEnv(VectorEnv):
    """N independent inspection drones stepped together (see the module docstring)."""

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, winds: Sequence[Any] | None = None,
                 wind_variants: Sequence[Any] | None = None, wind_variant_weights: Sequence[float] | None = None,
                 **options: Any) -> None:
        n = self.num_envs = _check_num_envs(num_envs)
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported by the vector env (render a "
                             "single WindTurbineInspectionEnv instead)")
        self.render_mode = None
        for key, value in options.items():
            if isinstance(value, (list, tuple)) and key not in ("camera", "reward", "planner", "turbine",
                                                                "start_offset"):
                raise ValueError(f"per-drone {key} is not supported (got a {type(value).__name__} of "
                                 f"{len(value)}); only winds=[...] varies per drone - make one vector env "
                                 "per turbine, task or option set")
        if "wind" in options and winds is not None:
            raise ValueError("give either wind (all drones) or winds (one per drone), not both")
        self.config = cfg = EnvConfig.from_kwargs(**options)
        if cfg.obs_mode != "state":
            raise ValueError(f"obs_mode is not supported by the vector env (single WindTurbineInspectionEnv only: "
                             f"it renders no images); got obs_mode={cfg.obs_mode!r}")
        if winds is not None:
            if isinstance(winds, (str, bytes)) or not isinstance(winds, Sequence) or len(winds) != n:
                got = len(winds) if isinstance(winds, Sequence) and not isinstance(winds, (str, bytes)) else winds
                raise ValueError(f"winds must be a list of {n} wind specs (one per drone), got {got!r}")
            self.winds = []
            for i, spec in enumerate(winds):
                try:
                    self.winds.append(make_wind(spec))
                except ValueError as exc:
                    raise ValueError(f"winds[{i}]: {exc}") from None
        else:
            self.winds = [make_wind(cfg.wind) for _ in range(n)]
        # Per-episode wind variants (training: e.g. a mix of wind speeds): every drone holds its own
        # field of each variant and draws one at each reset from a generator of its own, so the
        # main per-drone stream (start pose, wind seed) stays the single env's.
        self._variants: list[list[Any]] | None = None
        if wind_variants is not None:
            if winds is not None:
                raise ValueError("give either winds (fixed per drone) or wind_variants (drawn per episode), not both")
            if isinstance(wind_variants, (str, bytes)) or not isinstance(wind_variants, Sequence) or not wind_variants:
                raise ValueError(f"wind_variants must be a non-empty list of wind specs, got {wind_variants!r}")
            w = np.ones(len(wind_variants)) if wind_variant_weights is None else np.asarray(wind_variant_weights, float)
            if w.shape != (len(wind_variants),) or not np.all(np.isfinite(w)) or np.any(w <= 0):
                raise ValueError(f"wind_variant_weights must be {len(wind_variants)} positive numbers, "
                                 f"got {wind_variant_weights!r}")
            self._variant_p = w / w.sum()
            self._variants = []
            for j, spec in enumerate(wind_variants):
                try:
                    self._variants.append([make_wind(spec) for _ in range(n)])
                except ValueError as exc:
                    raise ValueError(f"wind_variants[{j}]: {exc}") from None
            self.winds = [self._variants[0][i] for i in range(n)]
        self._variant_rngs: list[np.random.Generator | None] = [None] * n
        self.variant = np.zeros(n, dtype=np.int64)
        self.params = cfg.drone
        self.scaling = ActionScaling.from_params(self.params)
        self._lo, self._hi = self.scaling.lower, self.scaling.upper
        self.dt = 1.0 / cfg.ctrl_hz
        self._camera_every = max(1, int(round(cfg.ctrl_hz / cfg.camera_hz)))
        self.mission = mission = build_mission(cfg)
        self.sim = BatchedQuadrotorSim(self.params, SimConfig(ctrl_hz=cfg.ctrl_hz, physics_hz=cfg.physics_hz, integrator=cfg.integrator), n,
                                       geometries=[t.mesh for t in mission.turbines], winds=self.winds)
        self.camera = GimbalCamera(cfg.camera)
        ins = mission.inspected
        self.visibility = [TriangleVisibility(self.camera, t.blade_vertices[ins], t.blade_normals[ins])
                           for t in mission.turbines]
        self.n_triangles = len(ins)
        self.counts = np.zeros((n, self.n_triangles), dtype=np.int32)
        self.n_seen = np.zeros(n, dtype=np.int64)
        self.metrics_acc = BatchedMetrics(n, self.n_triangles, MetricsConfig(
            d_ref=cfg.standoff, safety_margin=cfg.safety_margin, pixel_ifov_rad=cfg.camera.ifov_rad))
        ref = InspectionReference(mission.points, mission.normals, mission.s, mission.phase,
                                  ReferenceConfig(speed=cfg.reference_speed, mode=cfg.reference_mode,
                                                  standoff=cfg.standoff, lag_threshold=cfg.reference_lag,
                                                  stop_threshold=cfg.reference_stop))
        self.reference = BatchedReference(ref, n)
        self.time_limit = cfg.time_limit_s or (1.5 * ref.nominal_duration + 30.0)
        lo, hi = mission.working_volume(cfg.working_margin)
        self._vol_base = (lo, hi)
        self._vol_lo, self._vol_hi = np.tile(lo, (n, 1)), np.tile(hi, (n, 1))   # per drone: its start

        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.single_observation_space = observation_space()
        self.action_space = batch_space(self.single_action_space, n)
        self.observation_space = batch_space(self.single_observation_space, n)
        self._hover = self.scaling.hover_action()
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._seeded = False
        self.steps = np.zeros(n, dtype=np.int64)
        self.phase_index = np.zeros(n, dtype=np.int64)
        self.done_time = np.full(n, math.nan)
        self._last_new = np.zeros(n, dtype=np.int64)
        self._last_visible = np.zeros(n, dtype=np.int64)
        self._reset_state = np.zeros((n, 10))   # commanded start states (the metrics' first sample)
        # Domain randomisation per drone, drawn as the single env draws it (see _reset_drone).
        self.randomization: list[RandomizationDraw | None] = [None] * n
        self._noise_rngs: list[np.random.Generator | None] = [None] * n
        self._commands: list[deque] = [deque() for _ in range(n)]
        self._started = False
        self.closed = False

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        if options:
            raise ValueError(f"reset options are not supported by the vector env (single WindTurbineInspectionEnv "
                             f"only), got {sorted(options)}")
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = ([self.config.seed + i for i in range(n)]
                                       if self.config.seed is not None and not self._seeded else [None] * n)
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(n)]
        elif isinstance(seed, Sequence) and len(seed) == n:
            seeds = list(seed)
        else:
            raise ValueError(f"seed must be an int, None or a list of {n} ints/None, got {seed!r}")
        self._seeded = True
        for i, s in enumerate(seeds):
            if s is not None:
                if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
                    raise ValueError(f"seed[{i}] must be a non-negative integer or None, got {s!r}")
                self._rngs[i], _ = seeding.np_random(int(s))
                self._variant_rngs[i] = np.random.default_rng([int(s), 0x5A17])
        idx = np.arange(n)
        for i in range(n):
            self._reset_drone(i)
        self._frames(idx)
        self._record_reset(idx)
        self._started = True
        return self._observations(np.zeros(n, dtype=bool)), self._infos(None, None, None)

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        n = self.num_envs
        a = check_actions(actions, (n, 4), "actions")   # the single env's validation, batched
        lo, hi = self._lo, self._hi
        commands = lo + (np.clip(a, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo)
        if self.config.randomization is not None:
            for i, r in enumerate(self.randomization):
                if r is not None and r.latency_steps:     # command latency, as the single env
                    self._commands[i].append(commands[i].copy())
                    commands[i] = self._commands[i].popleft()
        self.sim.step(commands)
        self.steps += 1
        state = self.sim.state
        finite = np.isfinite(state).all(axis=1)
        prev = self.reference.sample
        pos = np.where(finite[:, None], state[:, 0:3], prev.ideal_position)
        sample = self.reference.step(self.dt, pos)
        for i in np.flatnonzero(sample.hold_started).tolist():
            self._set_phase(i, int(self.phase_index[i]) + 1)
        self._last_visible[:] = 0
        new = np.zeros(n, dtype=np.int64)
        shoot = np.flatnonzero(finite & (self.steps % self._camera_every == 0))
        if len(shoot):
            new[shoot] = self._frames(shoot)
        collision = self.sim.in_collision.copy()
        t = self.sim.time
        fi = np.flatnonzero(finite)
        self.metrics_acc.add(fi, t[fi], state[fi, 0:3], state[fi, 6:10], sample.point[fi], sample.normal[fi],
                             collision[fi], new[fi], self._last_visible[fi], ~sample.waiting_for_phase_change[fi])
        p = np.where(finite[:, None], state[:, 0:3], 0.0)
        left = np.any(p < self._vol_lo, axis=1) | np.any(p > self._vol_hi, axis=1)
        code = np.where(~finite, 1, np.where(collision, 2, np.where(left, 3, 0)))
        limit = self.config.pose_error_limit
        if limit is not None:      # as the single env's _termination: not while waiting for a phase change
            lost = ~sample.waiting_for_phase_change & (np.linalg.norm(p - sample.ideal_position, axis=1) > limit)
            code = np.where((code == 0) & lost, 4, code)   # code 0 means finite, no collision, inside
        terminated = code > 0
        reward, terms = reward_terms(self.config.reward, self.dt, self.n_triangles, a, self._hover, state,
                                     sample.ideal_position, sample.point, new, terminated)
        newly_done = sample.done & np.isnan(self.done_time)
        self.done_time[newly_done] = t[newly_done]
        complete = ~np.isnan(self.done_time) & (t >= self.done_time + self.config.end_hold_s - 1e-9)
        truncated = ~terminated & (complete | (t >= self.time_limit - 1e-9))
        obs = self._observations(~finite)
        infos = self._infos(code, complete, terms)
        ended = np.flatnonzero(terminated | truncated)
        if len(ended):
            for i in ended.tolist():
                final_obs = {k: v[i].copy() for k, v in obs.items()}
                final_info = {"metrics": self.metrics(i), "termination": _TERMINATIONS[code[i]],
                              "mission_complete": bool(complete[i]), "coverage": float(self.n_seen[i] / self.n_triangles),
                              "episode_steps": int(self.steps[i]), "variant": int(self.variant[i])}
                if self.randomization[i] is not None:
                    final_info["randomization"] = self.randomization[i].to_info()
                infos = self._add_info(infos, {"final_obs": final_obs, "final_info": final_info}, i)
                self._reset_drone(i)
            self._frames(ended)
            self._record_reset(ended)
            fresh = self._observations(np.zeros(n, dtype=bool), noisy=ended.tolist())
            for k in obs:
                obs[k][ended] = fresh[k][ended]
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.sim.close()

    # ------------------------------------------------------------------ queries
    def metrics(self, i: int) -> dict[str, float]:
        """The :class:`~wt_inspect_env.metrics.InspectionMetrics` (as a dict) of drone ``i``'s episode so far."""
        return self.metrics_acc.result(int(i)).to_dict()

    @property
    def coverage(self) -> np.ndarray:
        return self.n_seen / self.n_triangles

    # ------------------------------------------------------------------ internals
    def _rng(self, i: int) -> np.random.Generator:
        if self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random()
        return self._rngs[i]

    def _reset_drone(self, i: int) -> None:
        """:meth:`WindTurbineInspectionEnv.reset` for drone ``i``, up to the first frame."""
        rng, cfg = self._rng(i), self.config
        if self._variants is not None:
            if self._variant_rngs[i] is None:
                self._variant_rngs[i] = np.random.default_rng()
            self.variant[i] = int(self._variant_rngs[i].choice(len(self._variants), p=self._variant_p))
            self.winds[i] = self._variants[self.variant[i]][i]
            self.sim.set_wind(i, self.winds[i])
        self.winds[i].reset(int(rng.integers(2**63 - 1)))
        self._set_phase(i, 0)
        frac = float(rng.uniform(0.0, cfg.start_progress)) if cfg.start_progress > 0 else 0.0
        self.reference.reset(i, frac)
        s = self.reference.sample
        state = start_state(s.ideal_position[i], s.point[i], cfg.start_offset, cfg.start_noise, rng)
        if cfg.randomization is not None:
            r = self.randomization[i] = draw_randomization(cfg.randomization, self.params, rng)
            self.sim.set_plant(i, r.plant, r.thrust_scale)
            self._noise_rngs[i] = np.random.default_rng(r.noise_seed)
            self._commands[i] = deque([self.scaling.to_command(self._hover)] * r.latency_steps)
        self._vol_lo[i], self._vol_hi[i] = grow_to_start(*self._vol_base, state[0:3], cfg.working_margin)
        self.sim.reset_drone(i, state)
        self._reset_state[i] = state
        self.counts[i] = 0
        self.n_seen[i] = 0
        self.metrics_acc.reset(i)
        self.steps[i] = 0
        self.done_time[i] = math.nan

    def _record_reset(self, idx: np.ndarray) -> None:
        s, st = self.reference.sample, self._reset_state
        self.metrics_acc.add(idx, np.zeros(len(idx)), st[idx, 0:3], st[idx, 6:10], s.point[idx], s.normal[idx],
                             np.zeros(len(idx), dtype=bool), self._last_new[idx], self._last_visible[idx],
                             np.ones(len(idx), dtype=bool))

    def _set_phase(self, i: int, index: int) -> None:
        index = min(index, len(self.mission.turbines) - 1)
        self.sim.set_geometry(i, index)
        self.phase_index[i] = index

    def _frames(self, idx: np.ndarray) -> np.ndarray:
        """One camera frame for each drone in ``idx``: culling for all at once, one batched ray test
        per turbine geometry. Returns the newly seen triangle counts (also in ``_last_new``)."""
        state = self.sim.state[idx]
        origins, Rs = self.camera.poses(state[:, 0:3], state[:, 6:10])
        geo = self.sim.geometry[idx]
        seen: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * len(idx)
        for g in np.unique(geo).tolist():
            sel = np.flatnonzero(geo == g)
            vis = self.visibility[g]
            cand = vis.in_view_batch(origins[sel], Rs[sel])
            if self.config.occlusion:
                cand = self._unoccluded(vis, g, origins[sel], cand)
            for j, c in zip(sel.tolist(), cand):
                seen[j] = c
        new = np.zeros(len(idx), dtype=np.int64)
        for j, (i, tri) in enumerate(zip(idx.tolist(), seen)):
            self._last_visible[i] = len(tri)
            if len(tri):
                row = self.counts[i]
                row[tri] += 1
                new[j] = int(np.count_nonzero(row[tri] == 1))
                self.n_seen[i] += new[j]
        self._last_new[idx] = new
        return new

    def _unoccluded(self, vis: TriangleVisibility, g: int, origins: np.ndarray,
                    cand: list[np.ndarray]) -> list[np.ndarray]:
        """Drop the occluded candidates: every drone's rays of geometry ``g`` in one ray batch."""
        import pybullet as p

        lengths = [len(c) for c in cand]
        if sum(lengths) == 0:
            return cand
        targets = vis.occlusion_targets(np.concatenate(cand))
        per = 1 if targets.ndim == 2 else 4
        targets = targets.reshape(-1, 3)
        froms = np.repeat(origins, np.array(lengths) * per, axis=0)
        hit = np.empty(len(targets), dtype=bool)
        for a in range(0, len(targets), _MAX_RAYS):
            b = min(len(targets), a + _MAX_RAYS)
            res = p.rayTestBatch(froms[a:b], targets[a:b], numThreads=1, collisionFilterMask=ray_mask(g),
                                 physicsClientId=self.sim.client)
            hit[a:b] = [r[0] != -1 for r in res]
        blocked = hit.reshape(-1, per).any(axis=1)
        out, k = [], 0
        for c, m in zip(cand, lengths):
            out.append(c[~blocked[k:k + m]])
            k += m
        return out

    def _observations(self, safe: np.ndarray, noisy: Any = None) -> dict[str, np.ndarray]:
        """All drones' observations; randomised observation noise is drawn for the drones in
        ``noisy`` (default all) that are not ``safe`` - once per drone and step, as the single env."""
        s = self.reference.sample
        obs = observations(self.sim.state, self.sim.body_rates, s.point, s.normal, s.velocity,
                           self.n_seen / self.n_triangles, s.progress, safe=safe)
        if self.config.randomization is not None:
            rows = range(self.num_envs) if noisy is None else noisy
            for i in rows:
                r = self.randomization[i]
                if r is not None and r.has_noise and not safe[i]:
                    row = {k: v[i] for k, v in obs.items()}
                    noisy_state(row, r, self._noise_rngs[i])
                    for k, v in row.items():
                        obs[k][i] = v
        return obs

    def _infos(self, code: np.ndarray | None, complete: np.ndarray | None,
               terms: dict[str, np.ndarray] | None) -> dict[str, Any]:
        s, n = self.reference.sample, self.num_envs
        infos: dict[str, Any] = {
            "coverage": self.n_seen / self.n_triangles, "phase": s.phase.copy(), "time": self.sim.time,
            "waiting_for_phase_change": s.waiting_for_phase_change.copy(),
            "ideal_position": s.ideal_position.copy(), "wind": self.sim.last_wind.copy(),
        }
        if code is not None:
            infos["termination"] = np.array([_TERMINATIONS[c] for c in code.tolist()], dtype=object)
            infos["mission_complete"] = complete.copy()
            infos["reward_terms"] = {k: terms[k] for k in REWARD_TERMS}
        for k in list(infos):
            infos["_" + k] = np.ones(n, dtype=bool)
        return infos
