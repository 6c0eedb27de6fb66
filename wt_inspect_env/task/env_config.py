"""Configuration of the inspection environments (keyword options of ``gym.make``).

Everything a user can set is a field of :class:`EnvConfig`; ``gym.make(id, **options)`` accepts the
same names, nested options as dataclasses or plain dicts (``turbine={"blade_length": 40}``,
``wind={"type": "gust", "mean_speed": 7}``, ``camera={"focal_length_mm": 20}``). Unknown names are
a ``ValueError`` listing the valid ones.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..physics.quadrotor import QuadrotorParams, get_preset
from ..physics.sim_config import INTEGRATORS
from ..planner.config import CLEARANCE_BRAKE, D_MIN_RATIO, PAPER_ROTOR_TURN_DEG
from ..scene.camera import CameraConfig
from ..turbine.spec import TurbineSpec
from ..util.validation import (
    check_array,
    check_choice,
    check_field_types,
    check_finite,
    check_positive,
    check_unknown_options,
    coerce_config,
)
from .randomization import coerce_randomization
from .reference import MODES as REFERENCE_MODES
from .reference import ON_STALL as REFERENCE_ON_STALL

TASKS = ("full", "blade", "surface")

OBS_MODES = ("state", "rgb", "depth", "rgbd")
# The options ``reset(options=...)`` accepts for one episode (validated as EnvConfig fields).
RESET_OPTIONS = ("wind", "start_offset", "start_noise", "start_progress", "randomization")
_REFUSED_RESET_OPTIONS = {
    "turbine": "a turbine variant needs its own planned mission (about a second of planning per "
               "turbine) and resizes the coverage and metrics; make one environment per turbine",
}
_REFUSED_RESET_OPTIONS["turbine_mesh"] = _REFUSED_RESET_OPTIONS["turbine"]


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the reward terms (each term is also reported in ``info["reward_terms"]``).

    * ``coverage``: per unit of blade coverage newly gained (100 -> 1 per percent).
    * ``distance``: per second, times ``exp(-e^2 / (2 sigma^2))`` with ``e`` the 3-D distance of the
      drone from its ideal stand-off pose and ``sigma = distance_scale``; bounded and positive so
      that staying alive near the pose pays, and a crash never looks attractive.
    * ``centering``: per second, times the heading function ``h`` in [-1, 1] (the paper's CM).
    * ``effort``: per second, times the squared distance of the normalised action from hover.
    * ``crash``: one-off penalty on collision, leaving the working volume or a non-finite state.
    * ``clearance``: per second, times the shortfall below d_min as a share of it,
      ``max(0, d_min - d) / d_min`` with ``d`` the distance to the structure (the turbine mesh of the
      flown rotor position; reported as the term ``clearance``). 0 (default): off. On, every step
      queries the structure distances (the compiled step adds the term to its result).
    * ``clearance_margin``: the clearance cost starts this far [m] above d_min, ``max(0, d_min +
      margin - d) / d_min``: an agent whose tracking error is decimetres, where the stand-off pose
      itself passes little more than d_min from the hub, learns to keep that error outward.
    """

    coverage: float = 100.0
    distance: float = 1.0
    distance_scale: float = 1.0
    centering: float = 0.5
    effort: float = 0.05
    crash: float = 100.0
    clearance: float = 0.0
    clearance_margin: float = 0.0

    def __post_init__(self) -> None:
        check_field_types(self, "reward ")
        for f in dataclasses.fields(self):
            check_positive(f"reward {f.name}", getattr(self, f.name), allow_zero=f.name != "distance_scale")


# Physical bounds of the start options [m]. A start more than 1 km off its stand-off pose is not
# the start of an inspection flight (the largest turbine a TurbineSpec allows is 500 m tall), and
# without a bound a finite 1e308 overflows to infinite positions and an episode that never ends.
# A start-noise standard deviation of 100 m already scatters starts over ~400 m.
MAX_START_OFFSET = 1000.0
MAX_START_NOISE = 100.0
# Far plane of the rendered images [m]: the depth buffer is float32, so beyond ~1 km (10^4 x the
# 0.1 m near plane) the depth of distant surfaces is rounding noise (NaN and negative values from
# about 1e6 m); the camera inspects from a few metres.
MAX_DEPTH_FAR = 1000.0


def check_start_offset(value: Any, name: str = "start_offset") -> tuple[float, float, float]:
    """A start offset [m] as three finite floats at most :data:`MAX_START_OFFSET` long; a one-line
    ValueError naming ``name`` and the value otherwise.

    The one validation of the option, shared by :class:`EnvConfig`, the vector env and per-reset
    options, so every path refuses the same input with the same message."""
    if isinstance(value, (str, bytes)) or value is None:
        raise ValueError(f"{name} must be 3 finite numbers [m], got {value!r}")
    arr = check_array(name, value, (3,))
    big = float(np.max(np.abs(arr)))
    length = big if big > MAX_START_OFFSET else float(np.linalg.norm(arr))   # no overflow in the norm
    if not length <= MAX_START_OFFSET:
        raise ValueError(f"{name} must be at most {MAX_START_OFFSET:g} m long (a start farther from the path is not "
                         f"an inspection flight), got {value!r} ({length:.4g} m)")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def check_start_noise(value: Any, name: str = "start_noise") -> float:
    """A start-noise standard deviation [m] in [0, :data:`MAX_START_NOISE`] (shared by every entry
    point, like :func:`check_start_offset`)."""
    v = check_positive(name, value, allow_zero=True)
    if v > MAX_START_NOISE:
        raise ValueError(f"{name} must be at most {MAX_START_NOISE:g} m (a standard deviation; starts then scatter "
                         f"over hundreds of metres already), got {value!r}")
    return v


@dataclass(frozen=True)
class EnvConfig:
    """All options of :class:`~wt_inspect_env.env.WindTurbineInspectionEnv`.

    task: ``full`` (the paper's two-phase mission over all blades), ``blade`` (the four surfaces of
        one blade, phase 1), ``surface`` (one surface); ``blade_index`` / ``surface_index`` pick
        which, counted in tour order among the phase-1 ones (0 = the first the tour visits).
    turbine: a :class:`TurbineSpec` or dict of its fields (``{"preset": "nrel-5mw"}`` for a named
        turbine); ``turbine_mesh``: a mesh file to load instead, or a dict of
        :class:`~wt_inspect_env.turbine.loading.MeshLoadOptions` (``path``, ``unit``, ``up_axis``, ...).
    rotor_turn_deg: the rotor turn between phase 1 and 2 [deg]; ``None``: the planner chooses the
        rotor positions (none, one or two turns) with the least flight, which any rotor azimuth
        needs (``mission.turbines`` then holds one turbine per position); ``"auto"`` (default): the
        paper's 120 deg on the paper's turbine (the default ``TurbineSpec``), the planner's choice on
        every other turbine or mesh - a fixed 120 deg turn leaves surfaces of other turbines
        uninspectable (the NREL 5-MW's blade roots beside its hub, a rotor stopped at another azimuth).
    wind: a wind spec for :func:`~wt_inspect_env.physics.wind.make_wind` (default: the paper's gust, 4 m/s
        along y, period 10 s, std 0.5 m/s); ``"none"`` for still air.
    drone: preset name or :class:`QuadrotorParams`.
    reference_speed / reference_mode / standoff: the inspection point's nominal speed [m/s], its
        timing (``closed_loop`` waits for a lagging drone, ``open_loop`` is the paper's), d_ref [m].
    reference_lag / reference_stop: in ``closed_loop`` timing the point slows once the drone is
        this far [m] from its stand-off pose and stops at the second distance; default standoff / 7
        and 2 standoff / 7 (1 m and 2 m at the paper's 7 m; 7 cm and 14 cm for the 0.5 m lab
        stand-off, where fixed metres would let the point run away from a drone that is already
        blown out of its 0.1 m band).
    d_min: the flight's minimum distance to the structure [m]; default :data:`D_MIN_RATIO` x standoff
        (3 m at 7 m): what the MPCs' clearance constraint keeps, what the harness counts the time
        below, and what the closed-loop reference allows for where an ideal pose lies closer.
    reference_stall_time / reference_on_stall: seconds without progress after which the closed-loop
        reference stalls (``None``: never), and what then: ``"skip"`` (default) on without the drone
        until it is back on its pose, the path skipped in ``info["skipped_m"]`` (see :mod:`.reference`),
        or ``"end"`` the episode (truncated; the harness records ``reference_stall``). With
        ``"skip"``, a mission whose nominal time fits in its time limit also ends by it: a point
        that falls too far behind keeps the nominal speed to the end (one more stall).
    reference_approach_speed: from a start farther than ``reference_stop`` from the first stand-off
        pose, the reference first approaches from the start at this speed [m/s] (see
        :mod:`.reference`); ``"auto"`` (default): the braking bound sqrt(2 a (standoff - d_min)),
        a = :data:`~wt_inspect_env.planner.config.CLEARANCE_BRAKE` (4.9 m/s at the paper's 7 m / 3 m);
        ``None``: no approach (the first pose is the target from the start).
    safety_margin: SM band [m]. camera_hz: coverage frames per second (a real inspection camera
        shoots a few frames per second; 10 Hz keeps the env fast); 0: no frames at all - coverage and
        its reward stay 0, redundancy is undefined (NaN) - for training on a reward that ignores coverage,
        where the frames are a fifth of a step's time. ctrl_hz / physics_hz: command and
        physics rates. integrator: ``"compiled"`` (free flight in the compiled flight core, PyBullet
        near contacts) or ``"bullet"`` (PyBullet integrates every sub-step; the reference).
        time_limit_s: truncation time (default: 1.5 x the nominal mission time + 30 s).
    start_noise: standard deviation [m] of a random offset of the start position from the ideal
        stand-off pose (0 for reproducible MPC evaluation; RL training uses > 0).
    start_offset: a fixed 3-vector [m] (world frame) added to the ideal stand-off pose of every
        start, before ``start_noise`` (deterministic: for tests and studies of starts away from
        the path, e.g. ``(0, 0, 30)`` starts 30 m above it; the drone still faces the point).
    start_progress: each episode starts at a uniformly random point of the first ``start_progress``
        of the first phase's path (0: at its start; RL training on the blade task uses 0.9 so
        that short training episodes also see the transitions round the blade edges). Coverage
        and metrics count from the start point.
    start_near_structure: the share (in [0, 1]) of episodes that start, instead of uniformly, at
        a point of the first ``start_progress`` of the path whose ideal stand-off pose lies within
        ``start_near_distance`` [m] of the structure - round the hub and the blade roots, where
        the path passes closest. Uniform starts put a few per cent of the episodes there, and an
        agent that keeps d_min by itself has to learn those passes; 0 (default): uniform starts
        only (and no extra random draw, so the seeded stream is unchanged). Needs
        ``start_progress`` > 0. On a path whose poses all keep farther off (a turbine drawn by
        the many-turbine vector env), the starts are drawn among its closest passes: the poses
        within 0.5 m of the closest one's distance.
    start_near_distance: see ``start_near_structure`` [m].
    start_far: the share (in [0, 1]) of episodes that start far from the path, as whole missions
        do: at the path's start, moved by ``start_offset`` plus a random offset of uniform length
        in [0, ``start_far_distance``] and uniform direction without a downward part (the
        randomised campaign's starts), drawn again while it lies closer than d_min to the
        structure; the reference then approaches from there (``reference_approach_speed``).
        Training on such episodes teaches the approach an agent otherwise only meets in
        evaluation. 0 (default): no far starts (and no extra random draw, so the seeded stream is
        unchanged).
    start_far_distance: see ``start_far`` [m].
    working_margin: the working volume is the bounding box of the turbine, the path and the
        episode's start position, grown by this [m].
    pose_error_limit: end the episode (``terminated``, ``info["termination"] == "lost_pose"``, the
        crash penalty) once the drone is farther than this [m] from its ideal stand-off pose;
        ``None`` (default): no such limit. For RL training: without it a policy can collect the
        survival and heavy-tailed distance rewards hovering metres away from the pose, a local
        optimum PPO seeds sit in for a long time (early termination, as in motion imitation).
        Not checked while the drone waits for a phase change (the rotor turn), where the pose
        moves to the next phase's start.
    clearance_limit: end the episode (``terminated``, ``info["termination"] == "too_close"``, the
        crash penalty) once the drone is closer than this [m] to the structure (the turbine mesh of
        the flown rotor position); ``None`` (default): no such limit. For training agents that keep
        d_min by themselves (set it a little below ``d_min``); like ``reward.clearance`` it makes
        every step query the structure distances.
    occlusion: ray-cast occlusion in the coverage test (the paper's code skipped it).
    planner: further :class:`~wt_inspect_env.planner.PlannerConfig` options (dict), e.g.
        ``{"clearance": 0.2}`` for a scaled lab turbine; ``standoff``, ``spacing`` and
        ``rotor_turn_deg`` come from the fields above.
    seed: default seed of the first ``reset()`` called without one (so ``gym.make(..., seed=3)``
        alone makes the run reproducible); later seedless resets continue the generator.
    end_hold_s: after the inspection point reaches the end of the path, the episode goes on for
        this long (the drone catches up and the last frames are taken) before it is truncated.
    randomization: domain randomisation, off (``None``) by default; ``True`` for the default
        ranges, or a :class:`~wt_inspect_env.task.randomization.RandomizationConfig` / dict of ranges
        (airframe, observation noise, command latency; drawn at every reset).
    obs_mode: ``state`` (the Dict of drone and reference state), or that Dict plus an image from
        the gimbal camera: ``rgb`` (key ``rgb``, uint8 (h, w, 3)), ``depth`` (key ``depth``,
        float32 (h, w, 1) in metres, ``depth_far`` where nothing is hit) or ``rgbd`` (both).
    camera_resolution: ``(width, height)`` of those images [px] (small: they are rendered in
        software every control step).
    depth_far: far clipping distance of the rendered images [m] (depth saturates there).
    structure_observation: add the key ``structure`` (float32 (4,)): the vector from the drone to
        the nearest point of the turbine's collision mesh of the rotor position it flies in (world
        frame [m]) and that distance [m] - what an agent needs to keep d_min by itself (the MPCs
        get the same nearest points through their clearance constraint). Exact (libigl's AABB
        tree), computed for every drone each step; off, nothing is computed.
    """

    task: str = "full"
    turbine: Any = None
    turbine_mesh: str | None = None
    wind: Any = "gust"
    drone: Any = "matrice100"
    camera: Any = None
    reward: Any = None
    reference_speed: float = 0.7
    reference_mode: str = "closed_loop"
    standoff: float = 7.0
    reference_lag: float | None = None
    reference_stop: float | None = None
    reference_stall_time: float | None = 20.0
    reference_on_stall: str = "skip"
    reference_approach_speed: float | str | None = "auto"
    d_min: float | None = None
    safety_margin: float = 1.0
    planner_spacing: float = 0.1
    planner: Any = None
    rotor_turn_deg: float | str | None = "auto"
    blade_index: int = 0
    surface_index: int = 0
    ctrl_hz: float = 100.0
    physics_hz: float = 400.0
    integrator: str = "compiled"
    camera_hz: float = 10.0
    time_limit_s: float | None = None
    start_noise: float = 0.0
    start_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_progress: float = 0.0
    start_near_structure: float = 0.0
    start_near_distance: float = 4.0
    start_far: float = 0.0
    start_far_distance: float = 30.0
    working_margin: float = 30.0
    pose_error_limit: float | None = None
    clearance_limit: float | None = None
    occlusion: bool = True
    end_hold_s: float = 2.0
    seed: int | None = None
    randomization: Any = None
    obs_mode: str = "state"
    camera_resolution: tuple[int, int] = (84, 84)
    depth_far: float = 50.0
    structure_observation: bool = False

    def __post_init__(self) -> None:
        check_field_types(self, "")
        put = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 - frozen dataclass setter
        check_choice("task", self.task, TASKS)
        if self.turbine_mesh is None:
            put("turbine", coerce_config("turbine", self.turbine, TurbineSpec))
        elif self.turbine is not None:
            raise ValueError("give either turbine (a spec) or turbine_mesh (a file), not both")
        put("camera", coerce_config("camera", self.camera, CameraConfig))
        put("reward", coerce_config("reward", self.reward, RewardConfig))
        if isinstance(self.drone, str):
            put("drone", get_preset(self.drone))
        elif not isinstance(self.drone, QuadrotorParams):
            raise ValueError(f"drone must be a preset name or QuadrotorParams, got {self.drone!r}")
        check_positive("reference_speed", self.reference_speed)
        check_choice("reference_mode", self.reference_mode, REFERENCE_MODES)
        check_choice("integrator", self.integrator, INTEGRATORS)
        check_positive("standoff", self.standoff)
        if self.reference_lag is None:
            put("reference_lag", self.standoff / 7.0)
        if self.reference_stop is None:
            put("reference_stop", 2.0 * self.reference_lag)
        check_positive("reference_lag", self.reference_lag)
        check_positive("reference_stop", self.reference_stop)
        if self.reference_stop <= self.reference_lag:
            raise ValueError(f"reference_stop must exceed reference_lag ({self.reference_lag}), "
                             f"got {self.reference_stop!r}")
        if self.reference_stall_time is not None:
            check_positive("reference_stall_time", self.reference_stall_time)
        check_choice("reference_on_stall", self.reference_on_stall, REFERENCE_ON_STALL)
        if self.d_min is None:
            put("d_min", D_MIN_RATIO * self.standoff)
        check_positive("d_min", self.d_min)
        if self.d_min >= self.standoff:
            raise ValueError(f"d_min must be below standoff ({self.standoff}), got {self.d_min!r}")
        if isinstance(self.reference_approach_speed, str):
            if self.reference_approach_speed != "auto":
                raise ValueError("reference_approach_speed must be a number, None or 'auto', "
                                 f"got {self.reference_approach_speed!r}")
            put("reference_approach_speed", math.sqrt(2.0 * CLEARANCE_BRAKE * (self.standoff - self.d_min)))
        elif self.reference_approach_speed is not None:
            if isinstance(self.reference_approach_speed, bool):
                raise ValueError("reference_approach_speed must be a number, None or 'auto', "
                                 f"got {self.reference_approach_speed!r}")
            check_positive("reference_approach_speed", self.reference_approach_speed)
        check_positive("safety_margin", self.safety_margin)
        check_positive("planner_spacing", self.planner_spacing)
        if isinstance(self.rotor_turn_deg, str):
            if self.rotor_turn_deg != "auto":
                raise ValueError(f"rotor_turn_deg must be a number, None or 'auto', got {self.rotor_turn_deg!r}")
            paper = self.turbine_mesh is None and self.turbine == TurbineSpec()
            put("rotor_turn_deg", PAPER_ROTOR_TURN_DEG if paper else None)
        elif self.rotor_turn_deg is not None:
            if isinstance(self.rotor_turn_deg, bool):
                raise ValueError(f"rotor_turn_deg must be a number, None or 'auto', got {self.rotor_turn_deg!r}")
            check_finite("rotor_turn_deg", self.rotor_turn_deg)
        for name in ("blade_index", "surface_index"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be a non-negative integer, got {v!r}")
        check_positive("ctrl_hz", self.ctrl_hz)
        check_positive("physics_hz", self.physics_hz)
        check_positive("camera_hz", self.camera_hz, allow_zero=True)
        if self.camera_hz > self.ctrl_hz:
            raise ValueError(f"camera_hz must not exceed ctrl_hz ({self.ctrl_hz}), got {self.camera_hz!r}")
        if self.time_limit_s is not None:
            check_positive("time_limit_s", self.time_limit_s)
        check_start_noise(self.start_noise)
        put("start_offset", check_start_offset(self.start_offset))
        check_positive("start_progress", self.start_progress, allow_zero=True)
        if self.start_progress >= 1.0:
            raise ValueError(f"start_progress must be below 1, got {self.start_progress!r}")
        check_positive("start_near_structure", self.start_near_structure, allow_zero=True)
        if self.start_near_structure > 1.0:
            raise ValueError(f"start_near_structure must be a share in [0, 1], got {self.start_near_structure!r}")
        check_positive("start_near_distance", self.start_near_distance)
        if self.start_near_structure > 0.0 and self.start_progress <= 0.0:
            raise ValueError(f"start_near_structure ({self.start_near_structure!r}) needs start_progress > 0 "
                             "(the starts are drawn along that part of the path)")
        check_positive("start_far", self.start_far, allow_zero=True)
        if self.start_far > 1.0:
            raise ValueError(f"start_far must be a share in [0, 1], got {self.start_far!r}")
        check_positive("start_far_distance", self.start_far_distance)
        if self.start_far > 0.0 and self.reference_approach_speed is None:
            raise ValueError(f"start_far ({self.start_far!r}) needs a reference_approach_speed (the reference "
                             "approaches from a far start), got None")
        check_positive("working_margin", self.working_margin)
        if self.pose_error_limit is not None:
            check_positive("pose_error_limit", self.pose_error_limit)
        if self.clearance_limit is not None:
            check_positive("clearance_limit", self.clearance_limit)
        check_positive("end_hold_s", self.end_hold_s, allow_zero=True)
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0):
            raise ValueError(f"seed must be a non-negative integer or None, got {self.seed!r}")
        if self.planner is None:
            put("planner", {})
        elif not isinstance(self.planner, Mapping):
            raise ValueError(f"planner must be a dict of PlannerConfig options, got {self.planner!r}")
        else:
            owned = {"standoff", "spacing", "rotor_turn_deg"} & set(self.planner)
            if owned:
                raise ValueError(f"planner options {sorted(owned)} are set by the environment's standoff, "
                                 f"planner_spacing and rotor_turn_deg fields")
        if not isinstance(self.occlusion, bool):
            raise ValueError(f"occlusion must be a bool, got {self.occlusion!r}")
        put("randomization", coerce_randomization(self.randomization))
        if self.randomization is not None:
            self.randomization.check_airframe(self.drone)
        check_choice("obs_mode", self.obs_mode, OBS_MODES)
        if not isinstance(self.structure_observation, bool):
            raise ValueError(f"structure_observation must be a bool, got {self.structure_observation!r}")
        res = self.camera_resolution
        if (isinstance(res, (str, bytes)) or not hasattr(res, "__len__") or len(res) != 2
                or any(isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 1024 for v in res)):
            raise ValueError(f"camera_resolution must be (width, height), two integers in [1, 1024], got {res!r}")
        put("camera_resolution", (int(res[0]), int(res[1])))
        check_positive("depth_far", self.depth_far)
        if self.depth_far <= 0.1:
            raise ValueError(f"depth_far must exceed the 0.1 m near plane, got {self.depth_far!r}")
        if self.depth_far > MAX_DEPTH_FAR:
            raise ValueError(f"depth_far must be at most {MAX_DEPTH_FAR:g} m (the float32 depth buffer has no "
                             f"resolution left beyond it), got {self.depth_far!r}")

    def for_episode(self, options: Mapping[str, Any] | None) -> "EnvConfig":
        """This configuration with one episode's ``reset(options=...)`` applied, validated as the
        constructor validates (the fields are re-checked by ``__post_init__``); unknown or
        unsupported keys are a one-line ``ValueError`` naming them. ``options`` empty or ``None``:
        ``self``."""
        if not options:
            return self
        if not isinstance(options, Mapping):
            raise ValueError(f"reset options must be a dict, got {options!r}")
        refused = sorted(set(options) & set(_REFUSED_RESET_OPTIONS))
        if refused:
            raise ValueError(f"reset option {refused[0]!r} is not supported: {_REFUSED_RESET_OPTIONS[refused[0]]}")
        check_unknown_options("reset", options.keys(), RESET_OPTIONS)
        return dataclasses.replace(self, **dict(options))

    @classmethod
    def from_kwargs(cls, **options: Any) -> "EnvConfig":
        """Build from ``gym.make`` keyword options; unknown names raise ``ValueError``."""
        check_unknown_options("environment", options.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**options)
