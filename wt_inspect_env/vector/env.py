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

What is shared (without ``turbines=``): the planned mission (one turbine, one task), the PyBullet client
(:class:`~wt_inspect_env.world.batched_sim.BatchedQuadrotorSim`) and the camera-ray batch. Per-drone wind
is supported (``winds=[spec_0, ..., spec_N-1]``); per-drone tasks or options are not and are
refused with a clear error; turbines vary per group of drones with ``turbines=`` (below).
Domain randomisation (``randomization=...``) is drawn per drone from drone ``i``'s stream exactly as
the single env draws it (its plant, noise and latency; the draw of an ended episode is in
``info["final_info"]["randomization"]``, the running ones in :attr:`randomization`).
``reset(options=...)`` takes the single env's options for that episode of every drone; image
observations are single-env only and refused (PyBullet renders one scene for all drones).

Many turbines (``turbines=``, a :class:`~wt_inspect_env.task.turbine_draws.TurbineDistribution` or a
dict of its fields, with ``n_turbines=G`` dividing N): the env holds G worlds of N/G drones each
(drones ``g*N/G ...`` fly world ``g``), each on a turbine and rotor azimuth drawn from the world's
own stream, so an agent trained on it does not see one turbine only. The stream of world ``g`` is
seeded from the seed of its first drone (``reset(seed=s)``: ``s + g*N/G``), so the same seed
gives the same turbines, and drone ``i`` is the single env made with ``turbine=`` its world's draw
and seeded like drone ``i``. A world redraws its turbine once its drones have ended
``redraw_every * N/G`` episodes since its last draw - or, with ``redraw_after_s=T``, once it has flown
T simulated seconds since its last draw (world ``g``'s first draw lasts ``(g + 1) T / G``, so that the
worlds are planned at different steps). Training wants the latter: early in learning episodes end
within a second or two, and a count of episodes would replan every world every few seconds of
flight. At a redraw the world's drones still flying are truncated at that
step (``truncated``, ``info["termination"] == "redraw"``, the final observation and info as for
any ended episode - a time-limit-like cut that a learner bootstraps from), the world is planned
anew on the next draw and all its drones reset. ``info["turbine"]`` (a dict of per-drone arrays:
kind, scale, sizes, rotor azimuth) and ``info["turbine_draw"]`` (the world's draw number) tell the
turbine of each returned observation's episode; ``info["final_info"]["turbine"]`` that of an
ended one. The worlds are planned at the first ``reset`` (and again at a seeded reset whose draws
differ); ``worlds`` holds them, and ``world``, ``sim``, ``mission``, ``n_triangles`` and ``time_limit``
(the single world's) raise an AttributeError that says so.

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
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..env import observation_space
from ..physics.wind import make_wind
from ..scene.camera import GimbalCamera
from ..task.env_config import EnvConfig
from ..task.hooks import TaskHooks
from ..task.spaces import ActionScaling
from ..task.turbine_draws import TurbineDistribution, TurbineDraw
from ..util.validation import check_actions, check_positive, check_positive_int
from ..world.world import InspectionWorld, StepResult
from .turbines import REDRAW, turbine_stream


def _concat(results: list[StepResult]) -> StepResult:
    """One step of several worlds as one of their drones in order (a single world's as it is)."""
    if len(results) == 1:
        return results[0]
    cat = np.concatenate
    return StepResult(observations={k: cat([r.observations[k] for r in results]) for k in results[0].observations},
                      reward=cat([r.reward for r in results]),
                      terms={k: cat([r.terms[k] for r in results]) for k in results[0].terms},
                      code=cat([r.code for r in results]), terminated=cat([r.terminated for r in results]),
                      truncated=cat([r.truncated for r in results]), complete=cat([r.complete for r in results]),
                      finite=cat([r.finite for r in results]))


class WindTurbineInspectionVectorEnv(VectorEnv):
    """N independent inspection drones stepped together (see the module docstring)."""

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, winds: Sequence[Any] | None = None,
                 wind_variants: Sequence[Any] | None = None, wind_variant_weights: Sequence[float] | None = None,
                 hooks: TaskHooks | None = None, turbines: TurbineDistribution | dict | None = None,
                 n_turbines: int = 1, redraw_every: int = 1, redraw_after_s: float | None = None,
                 **options: Any) -> None:
        n = self.num_envs = check_positive_int("num_envs", num_envs)
        self.turbines = None if turbines is None else TurbineDistribution.coerce(turbines)
        g = self.n_turbines = check_positive_int("n_turbines", n_turbines)
        self.redraw_every = check_positive_int("redraw_every", redraw_every)
        self.redraw_after_s = None if redraw_after_s is None else check_positive("redraw_after_s", redraw_after_s)
        if self.redraw_after_s is not None and self.redraw_every != 1:
            raise ValueError(f"give either redraw_every (episodes, got {redraw_every!r}) or redraw_after_s "
                             f"(simulated seconds, got {redraw_after_s!r}), not both")
        if self.redraw_after_s is not None and turbines is None:
            raise ValueError("redraw_after_s needs turbines= (a TurbineDistribution or a dict of its fields)")
        if n % g:
            raise ValueError(f"n_turbines must divide num_envs={n}, got {n_turbines!r}")
        if self.turbines is None and g != 1:
            raise ValueError(f"n_turbines={g} needs turbines= (a TurbineDistribution or a dict of its fields)")
        if self.turbines is not None and ("turbine" in options or "turbine_mesh" in options):
            raise ValueError("give either turbines (drawn per world) or turbine / turbine_mesh (one), not both")
        self.drones_per_world = n // g
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
        if hooks is not None and not isinstance(hooks, TaskHooks):
            raise ValueError(f"hooks must be a TaskHooks (or a subclass), got {type(hooks).__name__}")
        self._hooks = hooks if hooks is not None else TaskHooks()
        self._options = dict(options)
        self.worlds: list[InspectionWorld] = []
        self.draws: list[TurbineDraw | None] = [None] * g        # each world's turbine (many turbines)
        self.draw_count = np.zeros(g, dtype=np.int64)            # ... its draws since the seeded reset
        self._ended = np.zeros(g, dtype=np.int64)                # ... episodes ended since its draw
        self._flown = np.zeros(g, dtype=np.int64)                # ... control steps flown since its draw
        self._turbine_rngs: list[np.random.Generator | None] = [None] * g
        if self.turbines is None:
            world = InspectionWorld(cfg, n, winds=self.winds, hooks=hooks)
            self.worlds, self._hooks = [world], world.hooks
            self.winds = world.winds
            self.params, self.scaling = world.params, world.scaling
            self.dt, self.camera = world.dt, world.camera
        else:   # the worlds are planned at the first reset, on the reset seed's turbines
            self.params, self.scaling = cfg.drone, ActionScaling.from_params(cfg.drone)
            self.dt, self.camera = 1.0 / cfg.ctrl_hz, GimbalCamera(cfg.camera)
        # redraw_after_s in control steps (a world's flown time is counted in steps)
        self._redraw_steps = None if self.redraw_after_s is None else math.ceil(self.redraw_after_s / self.dt - 1e-9)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.single_observation_space = observation_space(structure=self.config.structure_observation)
        self.action_space = batch_space(self.single_action_space, n)
        self.observation_space = batch_space(self.single_observation_space, n)
        self._seeded = False
        self._started = False
        self.closed = False

    def _the_world(self, name: str) -> InspectionWorld:
        """The one world of a single-turbine env; an AttributeError naming ``name`` and what to use
        instead for a many-turbine one (each of its worlds has its own turbine, mission and size)."""
        if self.turbines is not None:
            raise AttributeError(f"{name!r}: a many-turbine vector env flies one world per turbine, each with its own "
                                 f"{name}; use .worlds[k].{name} (world k flies drones k * drones_per_world onwards)"
                                 if name != "world" else
                                 "'world': a many-turbine vector env flies one world per turbine; use .worlds[k]")
        return self.worlds[0]

    @property
    def world(self) -> InspectionWorld:
        """The world of a single-turbine env (a many-turbine one has :attr:`worlds`)."""
        return self._the_world("world")

    @property
    def sim(self) -> Any:
        """The batched simulator of a single-turbine env's world."""
        return self._the_world("sim").sim

    @property
    def mission(self) -> Any:
        """The mission of a single-turbine env's world."""
        return self._the_world("mission").mission

    @property
    def n_triangles(self) -> int:
        """Blade triangles of a single-turbine env's mission (the coverage denominator)."""
        return self._the_world("n_triangles").n_triangles

    @property
    def time_limit(self) -> float:
        """The truncation time [s] of a single-turbine env's missions."""
        return self._the_world("time_limit").time_limit

    @property
    def hooks(self) -> TaskHooks:
        """The task's observation, reward and termination rules (shared with the worlds)."""
        return self._hooks

    @property
    def randomization(self) -> list:
        """Each drone's domain-randomisation draw of its running episode (None without)."""
        return [r for w in self.worlds for r in w.randomization]

    @property
    def steps(self) -> np.ndarray:
        """Control steps of each drone's running episode."""
        return self._cat([w.steps for w in self.worlds])

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        """Reset every drone. ``options`` (the single env's ``reset`` options: wind, start_offset,
        start_noise, start_progress, randomization) hold for this episode of every drone; drones
        reset automatically afterwards start from the constructor's configuration again. With many
        turbines a seeded reset goes back to the first turbine of each world's seeded stream."""
        n, m = self.num_envs, self.drones_per_world
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
        if self.turbines is not None:
            self._draw_turbines(seeds)
        for i, s in enumerate(seeds):
            if s is not None:
                w, j = self._locate(i)
                w.rngs[j], _ = seeding.np_random(int(s))
                self._variant_rngs[i] = np.random.default_rng([int(s), 0x5A17])
        for g, w in enumerate(self.worlds):
            w_ep = ep if w.config is self.config else w.config.for_episode(options)
            for j in range(m):
                w.episode[j] = w_ep
                if options and "wind" in options:
                    w.set_wind(j, w.episode_wind(j, w_ep.wind))
                    self._sync_wind(g * m + j)
                else:
                    self._draw_wind(g * m + j)
            w.reset(np.arange(m))
        self._started = True
        obs = self._cat_obs([w.observations(np.zeros(m, dtype=bool)) for w in self.worlds])
        infos = self._infos(None)
        if self.turbines is not None:
            self._add_turbine_infos(infos)
        return obs, infos

    def step(self, actions):
        """Hold each drone's action for one control step; drones whose episode ended are reset
        (autoreset), and with many turbines a world due for a new turbine is rebuilt."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        n, m = self.num_envs, self.drones_per_world
        a = check_actions(actions, (n, 4), "actions")   # the single env's validation, batched
        r = _concat([w.step(a[g * m:(g + 1) * m]) for g, w in enumerate(self.worlds)])
        obs = r.observations
        ended_now = r.terminated | r.truncated
        redraw = self._due_for_redraw(ended_now)
        cut = np.zeros(n, dtype=bool)
        for g in redraw:
            cut[g * m:(g + 1) * m] = ~ended_now[g * m:(g + 1) * m]
        if cut.any():
            r.truncated[cut] = True
        infos = self._infos(r)
        if cut.any():
            infos["termination"][cut] = REDRAW
        ended = np.flatnonzero(r.terminated | r.truncated)
        if len(ended):
            names = self.hooks.termination_names
            for i in ended.tolist():
                w, j = self._locate(i)
                final_obs = {k: v[i].copy() for k, v in obs.items()}
                final_info = {"metrics": self.metrics(i), "termination": REDRAW if cut[i] else names[r.code[i]],
                              "mission_complete": bool(r.complete[i]), "coverage": float(w.coverage[j]),
                              "episode_steps": int(w.steps[j]), "variant": int(self.variant[i]),
                              "stalls": int(w.reference.stalls[j]), "skipped_m": float(w.reference.skipped[j])}
                if w.randomization[j] is not None:
                    final_info["randomization"] = w.randomization[j].to_info()
                if self.turbines is not None:
                    final_info["turbine"] = self.draws[i // m].to_info()
                infos = self._add_info(infos, {"final_obs": final_obs, "final_info": final_info}, i)
                w.episode[j] = w.config
                self._draw_wind(i)
            for g in redraw:
                self._set_world(g, self.turbines.draw(self._turbine_rngs[g]))
                self.draw_count[g] += 1
            for g, w in enumerate(self.worlds):
                rows = np.flatnonzero(r.terminated[g * m:(g + 1) * m] | r.truncated[g * m:(g + 1) * m])
                if not len(rows):
                    continue
                w.reset(rows)
                fresh = w.observations(np.zeros(m, dtype=bool), noisy=rows.tolist())
                for k in obs:
                    obs[k][g * m + rows] = fresh[k][rows]
        if self.turbines is not None:
            self._add_turbine_infos(infos)
        return obs, r.reward, r.terminated, r.truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        """Close the worlds' simulators."""
        for w in self.worlds:
            w.close()

    # ------------------------------------------------------------------ queries
    def metrics(self, i: int) -> dict[str, float]:
        """The :class:`~wt_inspect_env.task.metrics.InspectionMetrics` (as a dict) of drone ``i``'s episode so far."""
        w, j = self._locate(int(i))
        return w.metrics(j).to_dict()

    @property
    def state(self) -> np.ndarray:
        """Each drone's simulator state (position, velocity, quaternion, ... as
        :attr:`~wt_inspect_env.world.batched_sim.BatchedQuadrotorSim.state`), over all worlds - also
        with many turbines, where there is no single :attr:`sim` (a copy then)."""
        return self._cat([w.sim.state for w in self.worlds])

    @property
    def coverage(self) -> np.ndarray:
        """Each drone's coverage of its running episode."""
        return self._cat([w.coverage for w in self.worlds])

    # ------------------------------------------------------------------ internals
    def _locate(self, i: int) -> tuple[InspectionWorld, int]:
        """The world drone ``i`` flies in and its index there."""
        g, j = divmod(i, self.drones_per_world)
        return self.worlds[g], j

    @staticmethod
    def _cat(arrays: list[np.ndarray]) -> np.ndarray:
        """Per-world arrays as one over the drones (a single world's as it is)."""
        return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)

    def _cat_obs(self, parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        return parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def _draw_turbines(self, seeds: Sequence[int | None]) -> None:
        """At a reset: world ``g``'s turbine stream reseeded from its first drone's seed (if any),
        its first turbine drawn and the world planned on it unless it is already (an unseeded reset
        keeps the worlds and their counts; the very first one draws from fresh entropy)."""
        m = self.drones_per_world
        for g in range(self.n_turbines):
            s = seeds[g * m]
            if s is None and self.draws[g] is not None:
                continue
            self._turbine_rngs[g] = turbine_stream(s)
            draw = self.turbines.draw(self._turbine_rngs[g])
            if draw != self.draws[g]:
                self._set_world(g, draw)
            self.draw_count[g], self._ended[g] = 0, 0
            # staggered: world g's first turbine lasts (g + 1) / G of redraw_after_s
            self._flown[g] = 0 if self.redraw_after_s is None else round(
                (1.0 - (g + 1) / self.n_turbines) * self.redraw_after_s / self.dt)

    def _set_world(self, g: int, draw: TurbineDraw) -> None:
        """World ``g`` planned on ``draw``; its drones keep their random streams and wind fields
        (they are reset by the caller)."""
        m = self.drones_per_world
        cfg = EnvConfig.from_kwargs(**self._options, turbine=draw.turbine_option())
        old = self.worlds[g] if g < len(self.worlds) else None
        winds = list(old.winds) if old is not None else self.winds[g * m:(g + 1) * m]
        if old is not None:
            old.close()
        w = InspectionWorld(cfg, m, winds=winds, hooks=self._hooks)
        if old is not None:
            w.rngs = list(old.rngs)
            self.worlds[g] = w
        else:
            self.worlds.append(w)
        self.draws[g] = draw
        self._ended[g] = 0
        self._flown[g] = 0

    def _due_for_redraw(self, ended: np.ndarray) -> list[int]:
        """Count the episodes each world ended this step; the worlds due for a new turbine."""
        if self.turbines is None:
            return []
        m, due = self.drones_per_world, []
        for g in range(self.n_turbines):
            self._ended[g] += int(ended[g * m:(g + 1) * m].sum())
            self._flown[g] += 1
            if (self._flown[g] >= self._redraw_steps if self._redraw_steps is not None
                    else self._ended[g] >= self.redraw_every * m):
                due.append(g)
        return due

    def _add_turbine_infos(self, infos: dict[str, Any]) -> None:
        """Each drone's turbine (of the episode its returned observation belongs to)."""
        m = self.drones_per_world
        per = [d.to_info() for d in self.draws]
        infos["turbine"] = {k: np.repeat(np.array([p[k] for p in per], dtype=object if k == "kind" else float), m)
                            for k in per[0]}
        infos["_turbine"] = {k: np.ones(self.num_envs, dtype=bool) for k in per[0]}
        infos["turbine_draw"] = np.repeat(self.draw_count, m)
        infos["_turbine_draw"] = np.ones(self.num_envs, dtype=bool)

    def _sync_wind(self, i: int) -> None:
        """Keep :attr:`winds` (a list of its own with many worlds) on drone ``i``'s field."""
        w, j = self._locate(i)
        if self.winds is not w.winds:
            self.winds[i] = w.winds[j]

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
        w, j = self._locate(i)
        if w.winds[j] is not field:
            w.set_wind(j, field)
        self._sync_wind(i)

    def _infos(self, r) -> dict[str, Any]:
        ws, n = self.worlds, self.num_envs
        cat = self._cat
        ss = [w.reference.sample for w in ws]
        infos: dict[str, Any] = {
            "coverage": self.coverage, "phase": cat([s.phase for s in ss]).copy(),
            "time": cat([w.sim.time for w in ws]),
            "waiting_for_phase_change": cat([s.waiting_for_phase_change for s in ss]).copy(),
            "ideal_position": cat([s.ideal_position for s in ss]).copy(),
            "wind": cat([w.sim.last_wind for w in ws]).copy(),
            "approaching": cat([w.reference.approaching for w in ws]),
        }
        if r is not None:
            names = self.hooks.termination_names
            infos["termination"] = np.array([names[c] for c in r.code.tolist()], dtype=object)
            infos["mission_complete"] = r.complete.copy()
            infos["reward_terms"] = dict(r.terms)
        for k in list(infos):
            infos["_" + k] = np.ones(n, dtype=bool)
        return infos
