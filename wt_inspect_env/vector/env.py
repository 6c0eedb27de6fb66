"""A native Gymnasium vector environment: N inspection drones in one process and one PyBullet world.

``gym.make_vec("WindTurbineInspection-v0", num_envs=N, vectorization_mode="vector_entry_point",
**options)`` builds :class:`WindTurbineInspectionVectorEnv` for any registered task. Drone ``i``
is the single :class:`~wt_inspect_env.env.WindTurbineInspectionEnv` made with the same options:
both are adapters over one :class:`~wt_inspect_env.world.world.InspectionWorld` (the single env is its
N = 1 case), so drone ``i`` has its own seed (``reset(seed=s)`` seeds drone ``i`` with ``s + i``),
wind field, reference, coverage, metrics and episode clock, and under the same actions the same
observations, rewards, terminations, coverage and metrics, bit for bit (tested for N = 1, 4, 16
across autoresets and the rotor turn). ``hooks=`` (a :class:`~wt_inspect_env.task.hooks.TaskHooks`)
changes the task for both.

What is shared: the planned mission (one turbine, one task), the PyBullet client
(:class:`~wt_inspect_env.world.batched_sim.BatchedQuadrotorSim`) and the camera-ray batch. Per-drone wind
is supported (``winds=[spec_0, ..., spec_N-1]``); per-drone turbines or tasks are not (one mission
is planned per vector env - make one vector env per turbine) and are refused with a clear error.
Domain randomisation (``randomization=...``) is drawn per drone from drone ``i``'s stream exactly as
the single env draws it (its plant, noise and latency; the draw of an ended episode is in
``info["final_info"]["randomization"]``, the running ones in :attr:`randomization`).
``reset(options=...)`` takes the single env's options for that episode of every drone; image
observations are single-env only and refused (PyBullet renders one scene for all drones).

Autoreset: ``AutoresetMode.SAME_STEP`` (in ``metadata["autoreset_mode"]``) - a drone whose
episode ends is reset inside the same ``step``; the returned observation is the first of its new
episode, and the last one is in ``info["final_obs"][i]`` with the ended episode's info (including
``"metrics"``) in ``info["final_info"]`` (masks ``info["_final_obs"]``, ``info["_final_info"]``),
the layout :class:`gymnasium.vector.SyncVectorEnv` gives in that mode. The per-step info holds cheap
per-drone arrays (coverage, phase, time, termination, reward terms, ...); the full metrics of a
running episode are :meth:`metrics` ``(i)``.
"""
from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..env import observation_space
from ..physics.wind import make_wind
from ..task.env_config import EnvConfig
from ..task.hooks import TaskHooks
from ..util.validation import check_actions
from ..world.world import InspectionWorld


def _check_num_envs(num_envs: Any) -> int:
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    return int(num_envs)


class WindTurbineInspectionVectorEnv(VectorEnv):
    """N independent inspection drones stepped together (see the module docstring)."""

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, winds: Sequence[Any] | None = None,
                 wind_variants: Sequence[Any] | None = None, wind_variant_weights: Sequence[float] | None = None,
                 hooks: TaskHooks | None = None, **options: Any) -> None:
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
                             f"PyBullet renders one scene, in which each drone would see the others and the other "
                             f"phases' turbines); got obs_mode={cfg.obs_mode!r}")
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
        self._fixed_winds = list(self.winds)
        self.world = world = InspectionWorld(cfg, n, winds=self.winds, hooks=hooks)
        self.winds = world.winds
        self.sim, self.mission, self.params, self.scaling = world.sim, world.mission, world.params, world.scaling
        self.dt, self.camera = world.dt, world.camera
        self.n_triangles, self.time_limit = world.n_triangles, world.time_limit
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.single_observation_space = observation_space(structure=self.config.structure_observation)
        self.action_space = batch_space(self.single_action_space, n)
        self.observation_space = batch_space(self.single_observation_space, n)
        self._seeded = False
        self._started = False
        self.closed = False

    @property
    def hooks(self) -> TaskHooks:
        """The task's observation, reward and termination rules (shared with the world)."""
        return self.world.hooks

    @property
    def randomization(self) -> list:
        """Each drone's domain-randomisation draw of its running episode (None without)."""
        return self.world.randomization

    @property
    def steps(self) -> np.ndarray:
        """Control steps of each drone's running episode."""
        return self.world.steps

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        """Reset every drone. ``options`` (the single env's ``reset`` options: wind, start_offset,
        start_noise, start_progress, randomization) hold for this episode of every drone; drones
        reset automatically afterwards start from the constructor's configuration again."""
        w, n = self.world, self.num_envs
        ep = self.config.for_episode(options)
        if seed is None:
            seeds: list[int | None] = ([self.config.seed + i for i in range(n)]
                                       if self.config.seed is not None and not self._seeded else [None] * n)
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(n)]
        elif isinstance(seed, Sequence) and len(seed) == n:
            seeds = list(seed)
        else:
            raise ValueError(f"seed must be an int, None or a list of {n} ints/None, got {seed!r}")
        for i, s in enumerate(seeds):
            if s is not None and (isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0):
                raise ValueError(f"seed[{i}] must be a non-negative integer or None, got {s!r}")
        self._seeded = True
        for i, s in enumerate(seeds):
            if s is not None:
                w.rngs[i], _ = seeding.np_random(int(s))
                self._variant_rngs[i] = np.random.default_rng([int(s), 0x5A17])
        for i in range(n):
            w.episode[i] = ep
            if options and "wind" in options:
                w.set_wind(i, w.episode_wind(i, ep.wind))
            else:
                self._draw_wind(i)
        w.reset(np.arange(n))
        self._started = True
        return w.observations(np.zeros(n, dtype=bool)), self._infos(None)

    def step(self, actions):
        """Hold each drone's action for one control step; drones whose episode ended are reset (autoreset)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        w, n = self.world, self.num_envs
        a = check_actions(actions, (n, 4), "actions")   # the single env's validation, batched
        r = w.step(a)
        obs = r.observations
        infos = self._infos(r)
        ended = np.flatnonzero(r.terminated | r.truncated)
        if len(ended):
            names = w.hooks.termination_names
            for i in ended.tolist():
                final_obs = {k: v[i].copy() for k, v in obs.items()}
                final_info = {"metrics": self.metrics(i), "termination": names[r.code[i]],
                              "mission_complete": bool(r.complete[i]), "coverage": float(w.coverage[i]),
                              "episode_steps": int(w.steps[i]), "variant": int(self.variant[i]),
                              "stalls": int(w.reference.stalls[i]), "skipped_m": float(w.reference.skipped[i])}
                if w.randomization[i] is not None:
                    final_info["randomization"] = w.randomization[i].to_info()
                infos = self._add_info(infos, {"final_obs": final_obs, "final_info": final_info}, i)
                w.episode[i] = self.config
                self._draw_wind(i)
            w.reset(ended)
            fresh = w.observations(np.zeros(n, dtype=bool), noisy=ended.tolist())
            for k in obs:
                obs[k][ended] = fresh[k][ended]
        return obs, r.reward, r.terminated, r.truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        """Close the world's simulator."""
        self.world.close()

    # ------------------------------------------------------------------ queries
    def metrics(self, i: int) -> dict[str, float]:
        """The :class:`~wt_inspect_env.task.metrics.InspectionMetrics` (as a dict) of drone ``i``'s episode so far."""
        return self.world.metrics(int(i)).to_dict()

    @property
    def coverage(self) -> np.ndarray:
        """Each drone's coverage of its running episode."""
        return self.world.coverage

    # ------------------------------------------------------------------ internals
    def _draw_wind(self, i: int) -> None:
        """Drone ``i``'s field for its next episode: its own of the constructor's wind, or one of the
        wind variants drawn from its variant stream."""
        if self._variants is not None:
            if self._variant_rngs[i] is None:
                self._variant_rngs[i] = np.random.default_rng()
            self.variant[i] = int(self._variant_rngs[i].choice(len(self._variants), p=self._variant_p))
            field = self._variants[self.variant[i]][i]
        else:
            field = self._fixed_winds[i]
        if self.world.winds[i] is not field:
            self.world.set_wind(i, field)

    def _infos(self, r) -> dict[str, Any]:
        w, n = self.world, self.num_envs
        s = w.reference.sample
        infos: dict[str, Any] = {
            "coverage": w.coverage, "phase": s.phase.copy(), "time": w.sim.time,
            "waiting_for_phase_change": s.waiting_for_phase_change.copy(),
            "ideal_position": s.ideal_position.copy(), "wind": w.sim.last_wind.copy(),
            "approaching": w.reference.approaching,
        }
        if r is not None:
            names = w.hooks.termination_names
            infos["termination"] = np.array([names[c] for c in r.code.tolist()], dtype=object)
            infos["mission_complete"] = r.complete.copy()
            infos["reward_terms"] = dict(r.terms)
        for k in list(infos):
            infos["_" + k] = np.ones(n, dtype=bool)
        return infos
