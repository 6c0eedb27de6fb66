"""The inspection world: N drones, one turbine mission, one PyBullet scene - every concept once.

:class:`InspectionWorld` holds everything an inspection episode is made of, in arrays over its
drones: the flight (:class:`~wt_inspect_env.world.batched_sim.BatchedQuadrotorSim`: the compiled flight
core and PyBullet for contacts, rays and images), each drone's wind field, moving inspection
reference, camera coverage, metrics, working volume, domain randomisation and episode clock. The
task's hooks (:class:`~wt_inspect_env.task.hooks.TaskHooks`) turn it into observations, rewards and
terminations. Both environments are adapters over it: the single
:class:`~wt_inspect_env.env.WindTurbineInspectionEnv` is a world of one drone, the native vector
environment a world of N. So drone ``i`` of a world of N and the only drone of a world of one, given
the same seed, options and actions, fly the same episode bit for bit (tested), with no second
implementation to keep equal.

The per-step arithmetic - reference, metrics, observation, reward, termination - is compiled
(:mod:`~wt_inspect_env.native.world_core`), per drone and in a fixed order, and one camera's culling does not
depend on how many are culled together: a drone's numbers do not depend on the batch it is in.
"""
from __future__ import annotations

import ctypes
import json
import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from gymnasium.utils import seeding

from ..native.world_core import observation_dict
from ..physics.dynamics import yaw_to_quat
from ..physics.sim_config import SimConfig
from ..physics.wind import WindField, make_wind
from ..planner.clearance import DistanceField
from ..scene.camera import GimbalCamera
from ..task.coverage import TriangleVisibility
from ..task.env_config import EnvConfig
from ..task.hooks import TaskHooks
from ..task.metrics import BatchedMetrics, InspectionMetrics, MetricsConfig
from ..task.mission import Mission, build_mission
from ..task.randomization import RandomizationDraw, noisy_state
from ..task.randomization import draw as draw_randomization
from ..task.reference import BatchedReference, InspectionReference, ReferenceConfig
from ..task.spaces import ActionScaling
from ..task.step_terms import REWARD_TERMS, clearance_reward, too_close
from .batched_sim import BatchedQuadrotorSim, ray_mask

_MAX_RAYS = 16383          # PyBullet's rayTestBatch limit per call
_MAX_EPISODE_WINDS = 8     # per drone: distinct reset(options={"wind": ...}) fields kept
START_CLEARANCE_MARGIN = 0.1   # [m] a noisy start keeps this much more than clearance_limit
START_REDRAWS = 16             # noisy starts drawn before the noise-free one is taken
NEAR_START_SAMPLES = 4096      # points of the start range searched for poses near the structure
NEAR_START_FALLBACK_M = 0.5    # no pose within start_near_distance: the poses this close to the closest
FAR_START_REDRAWS = 100        # far starts drawn before the path's start itself is taken


def grow_to_start(lo: np.ndarray, hi: np.ndarray, start: np.ndarray, margin: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The episode's working volume: the mission's box grown to hold the start position with
    ``margin`` round it, so that a start far off the path (``start_offset``) is not already a
    departure from the working volume (the mission's box is thin across the rotor plane)."""
    start = np.asarray(start, dtype=float)
    lo = np.minimum(lo, start - margin)
    return lo, np.maximum(hi, start + margin)


def start_state(ideal_position: np.ndarray, point: np.ndarray, start_offset: Any, start_noise: float,
                rng: np.random.Generator) -> np.ndarray:
    """The model state an episode starts from: the ideal stand-off pose plus the fixed
    ``start_offset`` plus ``N(0, start_noise)`` noise (drawn from ``rng`` only when positive, so
    the seeded stream is unchanged without it), at rest, level, facing the inspection point."""
    start = ideal_position + np.asarray(start_offset, dtype=float)
    if start_noise > 0:
        start = start + rng.normal(0.0, start_noise, 3)
    a = point - start
    state = np.zeros(10)
    state[0:3] = start
    state[6:10] = yaw_to_quat(math.atan2(a[1], a[0]))
    return state


@dataclass
class StepResult:
    """One control step of every drone, before any reset (arrays over drones)."""

    observations: dict[str, np.ndarray]
    reward: np.ndarray
    terms: dict[str, np.ndarray]
    code: np.ndarray              # termination code per drone (0: going on)
    terminated: np.ndarray
    truncated: np.ndarray
    complete: np.ndarray          # mission complete (after its end hold)
    finite: np.ndarray


#: the closed-loop reference's points reach the path's end this long [s] before the time limit less
#: the end hold at the latest (see BatchedReference.set_deadline)
DEADLINE_MARGIN_S = 1.0


class InspectionWorld:
    """N inspection drones on one planned mission (see the module docstring).

    ``winds``: one :class:`WindField` per drone (default: each its own field of ``config.wind``).
    ``hooks``: the task's hooks (default :class:`TaskHooks`). ``texture``: given the planned mission,
    the turbine's look in rendered images (a world of one drone renders; see :mod:`.render`).
    """

    def __init__(self, config: EnvConfig, n: int, *, winds: Sequence[WindField] | None = None,
                 hooks: TaskHooks | None = None, texture: Callable[[Mission], Any] | None = None) -> None:
        if hooks is not None and not isinstance(hooks, TaskHooks):
            raise ValueError(f"hooks must be a TaskHooks (or a subclass), got {type(hooks).__name__}")
        self.config = cfg = config
        self.n = n
        self.hooks = hooks if hooks is not None else TaskHooks()
        self.params = cfg.drone
        self.scaling = ActionScaling.from_params(self.params)
        self._lo, self._hi = self.scaling.lower, self.scaling.upper
        self.hover_action = self.scaling.hover_action()
        self.dt = 1.0 / cfg.ctrl_hz
        # control steps between coverage frames; 0: no frames (camera_hz = 0)
        self.camera_every = max(1, int(round(cfg.ctrl_hz / cfg.camera_hz))) if cfg.camera_hz > 0 else 0
        self.mission: Mission = build_mission(cfg)
        mission = self.mission
        self.winds: list[WindField] = list(winds) if winds is not None else [make_wind(cfg.wind) for _ in range(n)]
        self.sim = BatchedQuadrotorSim(self.params, SimConfig(ctrl_hz=cfg.ctrl_hz, physics_hz=cfg.physics_hz,
                                                              integrator=cfg.integrator), n,
                                       geometries=[t.mesh for t in mission.turbines], winds=self.winds,
                                       obstacle_texture=None if texture is None else texture(mission))
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
                                                  stop_threshold=cfg.reference_stop,
                                                  stall_time=cfg.reference_stall_time,
                                                  on_stall=cfg.reference_on_stall,
                                                  approach_speed=cfg.reference_approach_speed),
                                  reach=mission.clearance_shortfall(cfg.standoff, cfg.d_min))
        self.reference = BatchedReference(ref, n)
        self._router = None
        self.time_limit = cfg.time_limit_s or (1.5 * ref.nominal_duration + 30.0)
        # a mission that fits its time limit ends by it: a point that falls too far behind keeps
        # the nominal speed to the end (BatchedReference.set_deadline); a time limit shorter than
        # the mission (RL training episodes) is a truncation, not a deadline
        deadline = self.time_limit - cfg.end_hold_s - DEADLINE_MARGIN_S
        if cfg.reference_on_stall == "skip" and deadline >= ref.nominal_duration:
            self.reference.set_deadline(deadline)
        lo, hi = mission.working_volume(cfg.working_margin)
        self._vol_base = (lo, hi)
        self.volume_lo, self.volume_hi = np.tile(lo, (n, 1)), np.tile(hi, (n, 1))   # per drone: its start
        self.rngs: list[np.random.Generator | None] = [None] * n
        self.episode: list[EnvConfig] = [cfg] * n          # each drone's episode (reset options applied)
        self.steps = np.zeros(n, dtype=np.int64)
        self.phase_index = np.zeros(n, dtype=np.int64)
        self.done_time = np.full(n, math.nan)
        self.last_new = np.zeros(n, dtype=np.int64)
        self.last_visible = np.zeros(n, dtype=np.int64)
        self._reset_state = np.zeros((n, 10))   # commanded start states (the metrics' first sample)
        self.randomization: list[RandomizationDraw | None] = [None] * n
        self._noise_rngs: list[np.random.Generator | None] = [None] * n
        self._commands: list[deque] = [deque() for _ in range(n)]
        self._episode_winds: list[dict[str, WindField]] = [{} for _ in range(n)]
        self._noise_drones: list[int] = []        # drones whose episode draws observation noise
        self._latency_drones: list[int] = []      # ... and command latency
        self._fused_step: Any = None
        # exact nearest points of each rotor position's collision mesh, for the structure
        # observation and the optional clearance terms of the task
        self._clearance_terms = cfg.clearance_limit is not None or cfg.reward.clearance > 0.0
        self._structure = ([DistanceField(t.mesh.triangles) for t in mission.turbines]
                           if cfg.structure_observation or self._clearance_terms else None)
        self._structure_cache: tuple[np.ndarray, ...] | None = None     # (state, phases, vectors, distances)
        self._near_starts: dict[tuple[float, float], np.ndarray] = {}   # (progress, distance) -> fractions
        self._start_distances: DistanceField | None = None   # without _structure: for drawing starts

    # ------------------------------------------------------------------ queries
    @property
    def coverage(self) -> np.ndarray:
        """(N,) share of the mission's inspected triangles each drone has seen this episode."""
        return self.n_seen / self.n_triangles

    def metrics(self, i: int) -> InspectionMetrics:
        """Drone ``i``'s :class:`~wt_inspect_env.task.metrics.InspectionMetrics` of its episode so far."""
        return self.metrics_acc.result(int(i))

    def rng(self, i: int) -> np.random.Generator:
        """Drone ``i``'s random stream (start pose, wind seed, randomisation), seeded by the env."""
        if self.rngs[i] is None:
            self.rngs[i], _ = seeding.np_random()
        return self.rngs[i]

    # ------------------------------------------------------------------ episodes
    def episode_wind(self, i: int, spec: Any) -> WindField:
        """Drone ``i``'s field for a ``reset(options={"wind": spec})``: built once per distinct spec
        (a Dryden field's shaping filters take far longer to build than a reset) and reseeded at
        every reset, so reusing it changes nothing; a few specs are kept per drone."""
        try:
            key = json.dumps(spec, sort_keys=True)
        except (TypeError, ValueError):     # a callable or WindField: used as given
            return make_wind(spec)
        kept = self._episode_winds[i]
        field = kept.pop(key, None) or make_wind(spec)
        kept[key] = field                   # most recently used last
        while len(kept) > _MAX_EPISODE_WINDS:
            kept.pop(next(iter(kept)))
        return field

    def set_wind(self, i: int, wind: WindField) -> None:
        """Fly drone ``i`` in ``wind`` from its next reset on."""
        self.winds[i] = wind
        self.sim.set_wind(i, wind)

    def reset(self, idx: Sequence[int]) -> None:
        """Start a new episode for the drones ``idx`` (their :attr:`episode` configuration, wind and
        random stream as set), up to and including the first camera frame and metrics sample."""
        idx = np.asarray(idx, dtype=np.int64)
        for i in idx.tolist():
            self._reset_drone(i)
        if self.camera_every:
            self._frames(idx)
        else:
            self.last_new[idx], self.last_visible[idx] = 0, 0
        s, st = self.reference.sample, self._reset_state
        self.metrics_acc.add(idx, np.zeros(len(idx)), st[idx, 0:3], st[idx, 6:10], s.point[idx], s.normal[idx],
                             np.zeros(len(idx), dtype=bool), self.last_new[idx], self.last_visible[idx],
                             np.ones(len(idx), dtype=bool))

    def _approach_router(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """The approach route from a far start (built on the first one: most episodes start on the
        path): d_min clear of the first rotor position's whole mesh and the ground."""
        if self._router is None:
            from ..planner.approach import ApproachRouter
            turbine = self.mission.turbines[0]
            self._router = ApproachRouter(turbine.all_triangles, turbine.rotor_axis, self.config.d_min,
                                          self.config.standoff)
        return self._router(start, goal)

    def _reset_drone(self, i: int) -> None:
        rng, ep = self.rng(i), self.episode[i]
        self.winds[i].reset(int(rng.integers(2**63 - 1)))
        self.set_phase(i, 0)
        far = ep.start_far > 0 and rng.uniform() < ep.start_far
        frac = 0.0 if far else self._start_fraction(i, ep, rng)
        self.reference.reset(i, frac)
        s = self.reference.sample
        if far:
            state = self._far_start(i, s, ep, rng)
        else:
            state = start_state(s.ideal_position[i], s.point[i], ep.start_offset, ep.start_noise, rng)
            state = self._clear_start(i, state, s, ep, rng)
        # Drawn after the start (so without randomisation the seeded stream is unchanged).
        r = self.randomization[i] = (None if ep.randomization is None
                                     else draw_randomization(ep.randomization, self.params, rng))
        if r is not None:
            self.sim.set_plant(i, r.plant, r.thrust_scale)
            self._noise_rngs[i] = np.random.default_rng(r.noise_seed)
            self._commands[i] = deque([self.scaling.to_command(self.hover_action)] * r.latency_steps)
        else:
            if self.sim.plants[i] is not self.params:
                self.sim.set_plant(i)
            self._commands[i] = deque()
        self._noise_drones = [j for j, d in enumerate(self.randomization) if d is not None and d.has_noise]
        self._latency_drones = [j for j, d in enumerate(self.randomization) if d is not None and d.latency_steps]
        if self.reference.approach(i, state[0:3], self._approach_router):   # a far start: face the point it carries
            a = self.reference.sample.point[i] - state[0:3]
            state[6:10] = yaw_to_quat(math.atan2(a[1], a[0]))
        self.volume_lo[i], self.volume_hi[i] = grow_to_start(*self._vol_base, state[0:3], self.config.working_margin)
        self.sim.reset_drone(i, state)
        self._reset_state[i] = state
        self.counts[i] = 0
        self.n_seen[i] = 0
        self.metrics_acc.reset(i)
        self.steps[i] = 0
        self.done_time[i] = math.nan

    def _start_fraction(self, i: int, ep: EnvConfig, rng: np.random.Generator) -> float:
        """Where along the first phase's path drone ``i`` starts: uniformly in the first
        ``start_progress``, or - a ``start_near_structure`` share of the time - at one of the
        points of that range whose ideal pose lies within ``start_near_distance`` of the
        structure (drawn uniformly among them, jittered within their sample spacing)."""
        if ep.start_progress <= 0:
            return 0.0
        if ep.start_near_structure <= 0 or rng.uniform() >= ep.start_near_structure:
            return float(rng.uniform(0.0, ep.start_progress))
        near = self._near_fractions(i, ep)
        step = ep.start_progress / NEAR_START_SAMPLES
        return float(min(near[rng.integers(len(near))] + rng.uniform(0.0, step), np.nextafter(ep.start_progress, 0)))

    def _near_fractions(self, i: int, ep: EnvConfig) -> np.ndarray:
        """The sample fractions of the first ``start_progress`` of the path whose ideal pose lies
        within ``start_near_distance`` of the first rotor position's mesh - or, where none does,
        within :data:`NEAR_START_FALLBACK_M` of the closest pose's distance - found once per range
        on drone ``i``'s reference row, which its reset overwrites next. (The many-turbine vector
        env draws turbines whose paths may all keep farther off than the recipe's distance.)"""
        key = (float(ep.start_progress), float(ep.start_near_distance))
        if key not in self._near_starts:
            fracs = np.arange(NEAR_START_SAMPLES) * (ep.start_progress / NEAR_START_SAMPLES)
            poses = np.empty((len(fracs), 3))
            for k, f in enumerate(fracs):
                self.reference.reset(i, float(f))
                poses[k] = self.reference.sample.ideal_position[i]
            dist = self._start_field().closest(poses)[1]
            # a path that never comes within the distance (a drawn turbine whose poses all keep
            # farther off) starts at its closest passes instead
            closest = float(dist.min())
            within = ep.start_near_distance if closest < ep.start_near_distance else closest + NEAR_START_FALLBACK_M
            self._near_starts[key] = fracs[dist < within]
        return self._near_starts[key]

    def _far_start(self, i: int, s: Any, ep: EnvConfig, rng: np.random.Generator) -> np.ndarray:
        """A ``start_far`` start of drone ``i`` (at the path's start): ``start_offset`` plus an offset
        of uniform length in [0, ``start_far_distance``] and uniform direction with no downward
        part - the randomised campaign's starts - plus ``start_noise``, drawn again (up to
        :data:`FAR_START_REDRAWS` times, then the path's start itself) while closer than d_min to
        the first rotor position's structure or below the ground."""
        field = self._start_field()
        need = float(self.config.d_min)
        for _ in range(FAR_START_REDRAWS):
            v = rng.normal(size=3)
            v[2] = abs(v[2])
            offset = np.asarray(ep.start_offset, dtype=float) + rng.uniform(0.0, ep.start_far_distance) * (
                v / max(float(np.linalg.norm(v)), 1e-12))
            state = start_state(s.ideal_position[i], s.point[i], offset, ep.start_noise, rng)
            if state[2] >= need and float(field.closest(state[None, 0:3])[1][0]) >= need:
                return state
        return start_state(s.ideal_position[i], s.point[i], ep.start_offset, 0.0, rng)

    def _start_field(self) -> DistanceField:
        """Distances to the first rotor position's mesh (the clearance structure when it exists)."""
        if self._structure is not None:
            return self._structure[0]
        if self._start_distances is None:
            self._start_distances = DistanceField(self.mission.turbines[0].mesh.triangles)
        return self._start_distances

    def _clear_start(self, i: int, state: np.ndarray, s: Any, ep: Any, rng: np.random.Generator) -> np.ndarray:
        """With ``clearance_limit`` and ``start_noise``, a start whose noise put it closer than the
        limit plus :data:`START_CLEARANCE_MARGIN` to the structure is drawn again (up to
        :data:`START_REDRAWS` times, then the start without noise): an episode must not begin
        with its own end (round the hub and the blade roots the ideal poses lie little more than
        d_min from the mesh, and noise of a few decimetres crosses the limit). Without the limit
        nothing more is drawn, so other configurations keep their seeded streams."""
        if self.config.clearance_limit is None or ep.start_noise <= 0:
            return state
        need = self.config.clearance_limit + START_CLEARANCE_MARGIN
        field = self._structure[self.phase_index[i]]

        def clear(st: np.ndarray) -> bool:
            return float(field.closest(st[None, 0:3])[1][0]) >= need

        for _ in range(START_REDRAWS):
            if clear(state):
                return state
            state = start_state(s.ideal_position[i], s.point[i], ep.start_offset, ep.start_noise, rng)
        return state if clear(state) else start_state(s.ideal_position[i], s.point[i], ep.start_offset, 0.0, rng)

    def set_phase(self, i: int, index: int) -> None:
        """Drone ``i`` flies in the turbine geometry of mission phase ``index`` (the rotor turned)."""
        index = min(index, len(self.mission.turbines) - 1)
        self.sim.set_geometry(i, index)
        self.phase_index[i] = index

    # ------------------------------------------------------------------ stepping
    def commands(self, actions: np.ndarray) -> np.ndarray:
        """The rate-loop commands ``[p, q, r, T]`` (N, 4) of validated normalised actions, with each
        randomised drone's command latency applied."""
        lo, hi = self._lo, self._hi
        commands = lo + (np.clip(actions, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo)
        for i in self._latency_drones:            # the command from latency_steps ago
            self._commands[i].append(commands[i].copy())
            commands[i] = self._commands[i].popleft()
        return commands

    def step(self, actions: np.ndarray) -> StepResult:
        """One control step of every drone under validated normalised ``actions`` (N, 4).

        With the default hooks and the world's own simulator the whole step after the flight is
        two compiled calls (:meth:`_step_fused`), plus the optional clearance terms
        (``clearance_limit``, ``reward.clearance``) on their result; hooks of a subclass (or a
        stand-in simulator such as a vehicle link) take the general path, which calls them. Both
        give the same numbers."""
        self.sim.step(self.commands(actions))
        self.steps += 1
        if self._fused_ok():
            return self._step_fused(actions)
        return self._step_general(actions)

    def _fused_ok(self) -> bool:
        h = type(self.hooks)
        return (type(self.sim) is BatchedQuadrotorSim and h.observations is TaskHooks.observations
                and h.rewards is TaskHooks.rewards and h.terminations is TaskHooks.terminations)

    def _fused(self) -> Any:
        """The compiled step's view of the world's arrays (built once; they are updated in place)."""
        if self._fused_step is None:
            from ..native import world_core as wc
            n, cfg, sim = self.n, self.config, self.sim
            state, rates = sim.body_frame()
            buf = self._fused_buf = {
                "finite": np.zeros(n, dtype=bool), "n_new": np.zeros(n, dtype=np.int64),
                "actions": np.zeros((n, 4)), "hover": np.ascontiguousarray(self.hover_action, dtype=float),
                "code": np.zeros(n, dtype=np.int64), "reward": np.zeros(n), "terms": np.zeros((n, 5)),
                "terminated": np.zeros(n, dtype=bool), "truncated": np.zeros(n, dtype=bool),
                "complete": np.zeros(n, dtype=bool), "obs": np.zeros((n, wc.OBS_WIDTH), dtype=np.float32)}
            self._fused_weights = wc.reward_weights(cfg.reward, self.dt, self.n_triangles)
            w = wc.WorldStep()
            w.n, w.dt, w.end_hold, w.time_limit, w.d_ref = n, self.dt, cfg.end_hold_s, self.time_limit, cfg.standoff
            w.pose_limit = math.nan if cfg.pose_error_limit is None else float(cfg.pose_error_limit)
            w.path, w.ref = self.reference._pp, self.reference._sp
            w.metrics, w.weights = self.metrics_acc._mp, ctypes.addressof(self._fused_weights)
            arrays = {"state": state, "rates": rates, "steps": self.steps, "collision": sim.in_collision,
                      "n_vis": self.last_visible, "lo": self.volume_lo, "hi": self.volume_hi,
                      "done_time": self.done_time, "n_seen": self.n_seen, **buf}
            for name, arr in arrays.items():
                setattr(w, name, wc.addr(arr))
            self._fused_step = (wc.library(), ctypes.addressof(w), w)
        return self._fused_step

    def _step_fused(self, actions: np.ndarray) -> StepResult:
        lib, wp, _ = self._fused()
        buf = self._fused_buf
        self.sim.body_frame()                       # the state after the flight step (cached, in place)
        lib.wt_world_advance(wp)
        sample = self.reference.sample
        if sample.hold_started.any():
            for i in np.flatnonzero(sample.hold_started).tolist():
                self.set_phase(i, int(self.phase_index[i]) + 1)
        self.last_visible[:] = 0
        new = buf["n_new"]
        new[:] = 0
        finite = buf["finite"]
        self._frames_due(finite, new)
        buf["actions"][:] = actions
        lib.wt_world_finish(wp)
        obs = observation_dict(buf["obs"].copy())
        self._add_structure(obs, ~finite)
        self._add_noise(obs, ~finite, None)
        terms = buf["terms"].copy()
        named = {k: terms[:, j] for j, k in enumerate(REWARD_TERMS)}
        reward, code = buf["reward"].copy(), buf["code"].copy()
        terminated, truncated = buf["terminated"].copy(), buf["truncated"].copy()
        if self._clearance_terms:
            reward = self._clearance_after(reward, named, code, terminated, truncated)
        return StepResult(obs, reward, named, code, terminated, truncated, buf["complete"].copy(), finite.copy())

    def _clearance_after(self, reward: np.ndarray, terms: dict[str, np.ndarray], code: np.ndarray,
                         terminated: np.ndarray, truncated: np.ndarray) -> np.ndarray:
        """The optional clearance terms on the compiled step's result (in place; returns the
        reward): the same functions as the hooks' general path, in the same order of operations -
        a ``too_close`` end adds the crash penalty as the compiled sum's last term would have (it
        was 0 there), then the ``clearance`` term is added - so both paths give the same numbers."""
        cfg = self.config
        dist = self.structure()[1]
        if cfg.clearance_limit is not None:
            close = too_close(code, dist, cfg.clearance_limit)
            if close.any():
                code[close] = self.hooks.code_for("too_close")
                terminated[close], truncated[close] = True, False
                terms["crash"][close] = -cfg.reward.crash
                reward[close] = reward[close] + -cfg.reward.crash
        if cfg.reward.clearance > 0.0:
            terms["clearance"] = clearance_reward(cfg.reward, self.dt, cfg.d_min, dist)
            reward = reward + terms["clearance"]
        return reward

    def _step_general(self, actions: np.ndarray) -> StepResult:
        n, cfg = self.n, self.config
        state = self.sim.state
        finite = np.isfinite(state).all(axis=1)
        prev = self.reference.sample
        pos = np.where(finite[:, None], state[:, 0:3], prev.ideal_position)
        sample = self.reference.step(self.dt, pos)
        for i in np.flatnonzero(sample.hold_started).tolist():
            self.set_phase(i, int(self.phase_index[i]) + 1)
        self.last_visible[:] = 0
        new = np.zeros(n, dtype=np.int64)
        self._frames_due(finite, new)
        collision = self.sim.in_collision.copy()
        t = self.sim.time
        fi = np.flatnonzero(finite)
        self.metrics_acc.add(fi, t[fi], state[fi, 0:3], state[fi, 6:10], sample.point[fi], sample.normal[fi],
                             collision[fi], new[fi], self.last_visible[fi], ~sample.waiting_for_phase_change[fi])
        code = np.asarray(self.hooks.terminations(self, state, finite, collision))
        terminated = code > 0
        reward, terms = self.hooks.rewards(self, actions, new, terminated)
        newly_done = sample.done & np.isnan(self.done_time)
        self.done_time[newly_done] = t[newly_done]
        complete = ~np.isnan(self.done_time) & (t >= self.done_time + cfg.end_hold_s - 1e-9)
        stalled = (self.reference.stalls > 0) & (cfg.reference_on_stall == "end")
        truncated = ~terminated & (complete | (t >= self.time_limit - 1e-9) | stalled)
        obs = self.observations(~finite)
        return StepResult(obs, reward, terms, code, terminated, truncated, complete, finite)

    def observations(self, safe: np.ndarray, noisy: Any = None) -> dict[str, np.ndarray]:
        """All drones' observations (the hooks') with randomised observation noise drawn for the
        drones in ``noisy`` (default all) that are not ``safe`` - once per drone and step."""
        obs = self.hooks.observations(self, safe)
        self._add_structure(obs, safe)
        self._add_noise(obs, safe, noisy)
        return obs

    def structure(self) -> tuple[np.ndarray, np.ndarray]:
        """Each drone's vector to the nearest point of its rotor position's collision mesh (N, 3)
        (world frame [m]) and that distance (N,) from its true position; 0 and inf for a drone
        whose state is not finite. Needs ``structure_observation``, ``clearance_limit`` or a
        ``reward.clearance`` weight (the meshes' search trees are built only then)."""
        if self._structure is None:
            raise RuntimeError("the world keeps no structure distances: set structure_observation=True, "
                               "clearance_limit or reward.clearance")
        state = self.sim.state
        cached = self._structure_cache
        # one query per state: the terminations, the reward and the observation of a step all ask
        if (cached is not None and np.array_equal(cached[0], state, equal_nan=True)
                and np.array_equal(cached[1], self.phase_index)):
            return cached[2], cached[3]
        vec, dist = np.zeros((self.n, 3)), np.full(self.n, np.inf)
        pos = state[:, 0:3]
        ok = np.isfinite(state).all(axis=1)
        for k, field in enumerate(self._structure):
            rows = np.flatnonzero(ok & (self.phase_index == k))
            if len(rows):
                c, d = field.closest(pos[rows])
                vec[rows], dist[rows] = c - pos[rows], d
        self._structure_cache = (state.copy(), self.phase_index.copy(), vec, dist)
        return vec, dist

    def _add_structure(self, obs: dict[str, np.ndarray], safe: np.ndarray) -> None:
        """The ``structure`` entry (``EnvConfig.structure_observation``): :meth:`structure`, 0 for
        the ``safe`` rows (non-finite states). From the true position: randomised observation
        noise is not applied to it (a real drone would sense the structure with its own sensor)."""
        if not self.config.structure_observation:
            return
        vec, dist = self.structure()
        out = np.zeros((self.n, 4), dtype=np.float32)
        ok = ~np.asarray(safe, dtype=bool) & np.isfinite(dist)
        out[ok, 0:3], out[ok, 3] = vec[ok], dist[ok]
        obs["structure"] = out

    def _add_noise(self, obs: dict[str, np.ndarray], safe: np.ndarray, noisy: Any) -> None:
        """Randomised observation noise for the drones in ``noisy`` (default all) that draw it and
        are not ``safe``, in place."""
        if not self._noise_drones:
            return
        rows = self._noise_drones if noisy is None else [i for i in noisy if i in self._noise_drones]
        for i in rows:
            if not safe[i]:
                row = {k: v[i] for k, v in obs.items()}
                noisy_state(row, self.randomization[i], self._noise_rngs[i])
                for k, v in row.items():
                    obs[k][i] = v

    # ------------------------------------------------------------------ camera
    def _frames_due(self, finite: np.ndarray, new: np.ndarray) -> None:
        """The camera frames of this step (both step paths): every ``camera_every``-th step for the
        drones with a finite state (none with ``camera_hz`` 0); their newly seen counts into ``new``."""
        if not self.camera_every:
            return
        shoot = np.flatnonzero(finite & (self.steps % self.camera_every == 0))
        if len(shoot):
            new[shoot] = self._frames(shoot)

    def _frames(self, idx: np.ndarray) -> np.ndarray:
        """One camera frame for each drone in ``idx``: culling for all at once, one batched ray test
        per turbine geometry. Returns the newly seen triangle counts (also in ``last_new``)."""
        state = self.sim.state[idx]
        origins, Rs = self.camera.poses(state[:, 0:3], state[:, 6:10])
        seen = self.visible(self.sim.geometry[idx], origins, Rs)
        lengths = np.array([len(tri) for tri in seen], dtype=np.int64)
        self.last_visible[idx] = lengths
        new = np.zeros(len(idx), dtype=np.int64)
        if lengths.any():
            # every (drone, triangle) pair once per frame: counted with one fancy-indexed update
            j = np.repeat(np.arange(len(idx)), lengths)
            rows, tri = idx[j], np.concatenate(seen)
            self.counts[rows, tri] += 1
            new = np.bincount(j[self.counts[rows, tri] == 1], minlength=len(idx)).astype(np.int64)
            self.n_seen[idx] += new
        self.last_new[idx] = new
        return new

    def visible(self, geometry: np.ndarray, origins: np.ndarray, Rs: np.ndarray) -> list[np.ndarray]:
        """The triangles seen by cameras at ``origins`` / ``Rs`` (K of them), camera ``j`` in turbine
        geometry ``geometry[j]`` (the coverage rule, occlusion by the scene's rays included)."""
        seen: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * len(origins)
        for g in np.unique(geometry).tolist():
            sel = np.flatnonzero(geometry == g)
            vis = self.visibility[g]
            cand = vis.in_view_batch(origins[sel], Rs[sel])
            if self.config.occlusion:
                cand = self._unoccluded(vis, g, origins[sel], cand)
            for j, c in zip(sel.tolist(), cand):
                seen[j] = c
        return seen

    def _unoccluded(self, vis: TriangleVisibility, g: int, origins: np.ndarray,
                    cand: list[np.ndarray]) -> list[np.ndarray]:
        """Drop the occluded candidates: every camera's rays of geometry ``g`` in one ray batch."""
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

    def close(self) -> None:
        """Close the simulator."""
        self.sim.close()
