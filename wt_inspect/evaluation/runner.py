"""One evaluation run: build the environment, fly one policy, record the trajectory, save it.

Run file format (``.npz``, written atomically: temporary file + rename, so a file that exists is
complete and an interrupted run leaves nothing). One sample per control step; sample 0 is the
state after ``reset``, sample k the state after the k-th step. ``N`` samples, ``M`` triangles:

===================  ===========  =========================================================
key                  shape/dtype  meaning
===================  ===========  =========================================================
``meta``             str (JSON)   ``format``, ``spec`` (:class:`RunSpec` as a dict),
                                  ``env_options``, ``metrics`` (InspectionMetrics dict),
                                  ``termination``, ``mission_complete``, ``steps``,
                                  ``sim_time_s``, ``wall_time_s``, ``d_ref``,
                                  ``safety_margin``, solve-time statistics, ``record_every``
``t``                (N,) f8      simulated time [s]
``position``         (N,3) f4     drone position, world frame [m]
``quaternion``       (N,4) f4     attitude (qx, qy, qz, qw)
``velocity_body``    (N,3) f4     body-frame velocity [m/s]
``action``           (N,4) f4     normalised action chosen from sample k (NaN for the last)
``point``/``normal`` (N,3) f4     inspection point and its outward normal
``ideal_position``   (N,3) f4     the stand-off pose the reference asks for
``wind``             (N,3) f4     air velocity at the drone [m/s]
``distance``         (N,) f4      horizontal distance |a_xy| to the inspection point [m]
``heading``          (N,) f4      heading function h of the gimbal camera (horizontal part of
                                  body x, normalised): CM is its mean over inspecting samples
``heading_body``     (N,) f4      the paper's printed full-attitude h ((R e_x) . a_xy / |a_xy|)
``inspecting``       (N,) bool    sample counts for SM/CM (False while waiting for the rotor)
``phase``            (N,) i1      mission phase (1, 2)
``collision``        (N,) bool    in contact with the turbine or the ground
``coverage``         (N,) f4      coverage so far (fraction of the mission's triangles)
``solve_ms``         (N,) f4      the policy's own solve time (``last_stats.solve_ms``) or
                                  NaN if it reports none; NaN for the last sample
``act_ms``           (N,) f4      wall time of ``policy.act`` measured here (NaN for last)
``latency_ms``       (N,) f4      the policy's observation-to-command latency
                                  (``last_stats.latency_ms``, else its ``solve_ms``), NaN if
                                  it reports neither; NaN for the last sample
``clearance``        (N,) f4      distance of the drone's centre to the turbine mesh in force
                                  at the sample [m] (see :mod:`.harness_metrics`: exact where
                                  it can be the minimum or below d_min, never below the truth)
``rotor_thrust``     (N,4) f4     the four rotor thrusts [N] (simulator's rotor state)
``power``            (N,) f4      electrical power of those thrusts [W] (the energy model)
``coverage_counts``  (M,) i4      frames in which each mission triangle was seen
``inspected``        (M,) i4      indices of those triangles in the turbine's blade arrays
``blade_triangles``  (P,B,3,3) f4 the turbine's blade triangles in each of its P phases
``triangle_blade``   (B,) i2      blade of each blade triangle (phase 1 numbering)
``triangle_face``    (B,) i2      face (0..3 around the chord) of each blade triangle
``rotor_center``     (3,) f8      rotor centre in phase 1 [m]
===================  ===========  =========================================================

``record_every`` > 1 keeps every k-th sample (and always the last) to make files smaller; the
metrics are always those of the environment over every step, plus the harness's own clearance
and energy metrics (:mod:`.harness_metrics`), also over every step.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import gymnasium as gym
import numpy as np

import wt_inspect_env  # noqa: F401 - registers the environment ids
from wt_inspect_env.task.geometry import camera_heading, heading_and_distance
from wt_inspect_env.task.reference import PACING
from wt_inspect_env.util.atomic_io import atomic_path

from . import registry
from .harness_metrics import clearance_metrics, energy_metrics, geometry_index, mesh_clearance, rotor_power

FORMAT = "wt-inspect-run/1"
ENV_ID = "WindTurbineInspection-v0"   # the task comes from the options
# Metric columns of a run (results.csv): name -> key of the run's metrics (InspectionMetrics, and
# the harness's clearance and energy metrics). ``*_distance`` are to the inspection point;
# ``clearance_*`` to the turbine's mesh.
METRIC_COLUMNS = {
    "coverage": "coverage", "safety": "safety_sm", "centering": "centering_cm",
    "centering_body": "centering_body_cm",
    "mean_distance": "mean_distance_m", "min_distance": "min_distance_m", "max_distance": "max_distance_m",
    "rms_distance_error": "rms_distance_error_m", "collisions": "collisions", "flight_time": "flight_time_s",
    "path_length": "path_length_m", "mean_heading_error_deg": "mean_heading_error_deg",
    "clearance_min_m": "clearance_min_m", "clearance_body_min_m": "clearance_body_min_m",
    "time_below_d_min_s": "time_below_d_min_s", "d_min_m": "d_min_m",
    "energy_wh": "energy_wh", "mean_power_w": "mean_power_w",
    "stalls": "stalls", "skipped_path_m": "skipped_path_m",
}

ProgressCallback = Callable[[float, float], None]


# The harness's own modules that decide a run's outcome (the episode loop, the scenarios' options,
# name resolution); its reporting, figures and backends only present or schedule results.
_HARNESS_SOURCES = ("runner.py", "harness_metrics.py", "scenarios.py", "registry.py")


def code_sources() -> list[Path]:
    """Every source file that can change a run's result: the environment package, every package
    that registers a policy (``controllers``, ``agents`` and any third-party one, found through
    the entry points) - their Python and the C they compile (the flight and world cores) - and the
    harness's outcome-deciding modules (:data:`_HARNESS_SOURCES`)."""
    roots = [Path(wt_inspect_env.__file__).parent]
    roots += [r for r in registry.source_roots() if r not in roots]
    files = [f for root in roots for pattern in ("*.py", "*.c") for f in sorted(root.rglob(pattern))]
    here = Path(__file__).parent
    return files + [here / name for name in _HARNESS_SOURCES]


def code_fingerprint() -> str:
    """Hash of :func:`code_sources` (paths relative to their package's parent, and contents).
    Stored in every run file: a resumed run made by other code is reported (results.md, stderr),
    since its numbers may not be comparable."""
    h = hashlib.sha256()
    for f in code_sources():
        h.update(str(f.relative_to(_package_root(f))).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def _package_root(f: Path) -> Path:
    """The directory holding ``f``'s top-level package (so the hashed path is ``pkg/mod.py``
    wherever the checkout is)."""
    root = f.parent
    while (root.parent / "__init__.py").is_file():
        root = root.parent
    return root.parent


@dataclass(frozen=True)
class RunSpec:
    """What one run is: plain data (picklable, JSON-able) so any backend can execute it."""

    scenario: str
    controller: str
    wind: float
    seed: int
    env_options: Mapping[str, Any]
    max_time: float | None = None
    record_every: int = 1
    controller_id: str = ""       # registry.fingerprint(controller); filled by make_spec
    trust_model: bool = False     # --trust-model: the user lets a model file run code (not in the key)

    @property
    def key(self) -> str:
        """Hash of everything that changes the outcome: a changed option is a different run."""
        payload = json.dumps({"controller": self.controller_id or self.controller, "wind": self.wind,
                              "seed": self.seed, "env": self.env_options, "max_time": self.max_time,
                              "record_every": self.record_every}, sort_keys=True, default=str)
        return hashlib.sha256(payload.encode()).hexdigest()[:10]

    @property
    def filename(self) -> str:
        """The run file's name: scenario, controller, wind, seed and the spec's key."""
        ctrl = "".join(c if c.isalnum() or c in "-_" else "-" for c in self.controller)[:40]
        return f"{self.scenario}_{ctrl}_w{self.wind:g}_s{self.seed}_{self.key}.npz"

    def to_dict(self) -> dict[str, Any]:
        """The spec as plain JSON-able data (stored in the run file)."""
        return asdict(self) | {"env_options": dict(self.env_options)}


def make_spec(scenario: str, controller: str, wind: float, seed: int, env_options: Mapping[str, Any],
              max_time: float | None = None, record_every: int = 1, *, custom: bool = False,
              trust_model: bool = False) -> RunSpec:
    """A validated :class:`RunSpec` (controller name checked, model file fingerprinted).
    ``custom``: ``controller`` is only a label for a policy supplied by the caller (resuming then
    trusts the label: give a changed policy a new label, or rerun)."""
    if custom:
        if not isinstance(controller, str) or not controller:
            raise ValueError(f"a custom policy needs a non-empty label, got {controller!r}")
        controller_id = f"custom:{controller}"
    else:
        registry.check_controller(controller, trust_model=trust_model)
        controller_id = registry.fingerprint(controller)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if max_time is not None and not (isinstance(max_time, (int, float)) and math.isfinite(max_time)
                                     and max_time > 0):
        raise ValueError(f"max_time must be a positive number of simulated seconds, got {max_time!r}")
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
        raise ValueError(f"record_every must be a positive integer, got {record_every!r}")
    env_options = json.loads(json.dumps(env_options))   # plain JSON data, stable for hashing
    return RunSpec(scenario, controller, float(wind), int(seed), env_options,
                   None if max_time is None else float(max_time), int(record_every), controller_id,
                   bool(trust_model) and not custom)


@dataclass
class RunResult:
    """Outcome of one run: the environment's metrics, how it ended, timing, and (optionally) the
    recorded trajectory (see the module docstring for the arrays)."""

    spec: RunSpec
    metrics: dict[str, Any]      # InspectionMetrics (the env's) + the harness's (harness_metrics)
    termination: str | None
    mission_complete: bool
    steps: int
    sim_time_s: float
    wall_time_s: float
    solve: dict[str, float]
    d_ref: float
    safety_margin: float
    arrays: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    path: Path | None = None
    code: str = ""               # code_fingerprint() of the process that made the run
    stall_log: list[dict[str, Any]] = field(default_factory=list)   # one record per reference stall

    def row(self) -> dict[str, Any]:
        """One row of results.csv (fractions in [0, 1], distances in m, times in s / ms)."""
        s = self.spec
        row: dict[str, Any] = {"scenario": s.scenario, "controller": s.controller, "wind": s.wind, "seed": s.seed}
        for col, key in METRIC_COLUMNS.items():
            row[col] = self.metrics.get(key, math.nan)
        row.update(self.solve)
        row.update({"termination": self.termination or "", "mission_complete": self.mission_complete,
                    "steps": self.steps, "sim_time": self.sim_time_s, "wall_time": self.wall_time_s,
                    "run_file": self.path.name if self.path else ""})
        return row

    def meta(self) -> dict[str, Any]:
        """What the run file stores beside the arrays: spec, metrics, termination and timings."""
        return {"format": FORMAT, "spec": self.spec.to_dict(), "metrics": self.metrics,
                "termination": self.termination, "mission_complete": self.mission_complete,
                "steps": self.steps, "sim_time_s": self.sim_time_s, "wall_time_s": self.wall_time_s,
                "solve": self.solve, "d_ref": self.d_ref, "safety_margin": self.safety_margin, "code": self.code,
                "stall_log": self.stall_log}


def _stats_ms(values: np.ndarray) -> tuple[float, float]:
    v = values[np.isfinite(values)]
    if not len(v):
        return math.nan, math.nan
    return float(np.median(v)), float(np.percentile(v, 99))


class _Recorder:
    """Per-step arrays in preallocated, growing float32 buffers (appending Python lists of 30
    floats per step for 110k steps would cost more than the arrays' final size)."""

    SPECS = {"t": (np.float64, ()), "position": (np.float32, (3,)), "quaternion": (np.float32, (4,)),
             "velocity_body": (np.float32, (3,)), "action": (np.float32, (4,)), "point": (np.float32, (3,)),
             "normal": (np.float32, (3,)), "ideal_position": (np.float32, (3,)), "wind": (np.float32, (3,)),
             "distance": (np.float32, ()), "heading": (np.float32, ()), "heading_body": (np.float32, ()),
             "inspecting": (np.bool_, ()),
             "phase": (np.int8, ()), "collision": (np.bool_, ()), "coverage": (np.float32, ()),
             "solve_ms": (np.float32, ()), "act_ms": (np.float32, ()),
             "latency_ms": (np.float32, ())}

    def __init__(self, capacity: int) -> None:
        self.n = 0
        self.buf = {k: np.zeros((max(capacity, 16),) + shp, dt) for k, (dt, shp) in self.SPECS.items()}

    def row(self) -> int:
        if self.n == len(self.buf["t"]):
            self.buf = {k: np.concatenate([v, np.zeros_like(v)]) for k, v in self.buf.items()}
        self.n += 1
        return self.n - 1

    def arrays(self, every: int) -> dict[str, np.ndarray]:
        idx = _kept(self.n, every)
        return {k: v[idx] for k, v in self.buf.items()}


def _kept(n: int, every: int) -> np.ndarray:
    """Rows a run file keeps of ``n``: every ``every``-th and always the last."""
    idx = np.arange(0, n, every)
    if n and idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx


class _Track:
    """What the harness's own metrics need at every control step, recorded even without
    ``record`` (a few float64s per step): time, the drone's true position (not the observation,
    which domain randomisation may make noisy), whether the reference waits for the rotor turn
    (which mesh is in force) and the four rotor thrusts."""

    def __init__(self, capacity: int) -> None:
        n = max(capacity, 16)
        self.n = 0
        self.t, self.pos, self.thrust = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 4))
        self.waiting = np.zeros(n, dtype=bool)

    def add(self, sim: Any, info: Mapping[str, Any]) -> None:
        if self.n == len(self.t):
            self.t, self.pos, self.thrust, self.waiting = (np.concatenate([a, np.zeros_like(a)]) for a in
                                                           (self.t, self.pos, self.thrust, self.waiting))
        i = self.n
        self.t[i] = info["time"]
        self.pos[i], self.thrust[i] = _position_and_thrusts(sim)
        self.waiting[i] = info["waiting_for_phase_change"]
        self.n += 1

    def results(self, env: Any) -> tuple[dict[str, float], dict[str, np.ndarray]]:
        """The clearance and energy metrics (see :mod:`.harness_metrics`) and their per-sample
        arrays (clearance [m], rotor thrusts [N], power [W])."""
        n, sim = self.n, env.sim
        t = self.t[:n]
        turbines = env.mission.turbines
        geo = geometry_index(self.waiting[:n], len(turbines))
        d_min = float(env.config.d_min)
        clearance = mesh_clearance(self.pos[:n], [tb.mesh for tb in turbines], geo, d_min=d_min)
        plant = _plant(sim)
        power = rotor_power(plant, self.thrust[:n])
        body_radius = float(np.linalg.norm(env.params.collision_half_extents))   # the nominal box collides
        metrics = clearance_metrics(t, clearance, d_min, body_radius) | energy_metrics(t, power, plant)
        return metrics, {"clearance": clearance, "rotor_thrust": self.thrust[:n], "power": power}


def _position_and_thrusts(sim: Any) -> tuple[np.ndarray, np.ndarray]:
    """The drone's world position (3,) and its four rotor thrusts [N] (4,) (times the plant's
    thrust factor) from the environment's simulator (its world's, of which the drone is row 0)."""
    return sim.state[0, 0:3], sim.f[0] * sim.thrust_scales[0]


def _plant(sim: Any) -> Any:
    """The airframe the simulator integrates (domain randomisation may change it), drone 0's."""
    return sim.plants[0]


def _record(rec: _Recorder, env: Any, obs: Mapping[str, np.ndarray], info: Mapping[str, Any]) -> int:
    i = rec.row()
    b = rec.buf
    pos, q, point = obs["position"], obs["quaternion"], obs["point"]
    h_body, d = heading_and_distance(pos, q, point)
    h = camera_heading(pos, q, point)   # the gimbal camera's heading (CM's h)
    b["t"][i] = info["time"]
    b["position"][i] = pos
    b["quaternion"][i] = q
    b["velocity_body"][i] = obs["velocity_body"]
    b["point"][i] = point
    b["normal"][i] = obs["normal"]
    b["ideal_position"][i] = info["ideal_position"]
    b["wind"][i] = info["wind"]
    b["distance"][i] = d
    b["heading"][i] = h
    b["heading_body"][i] = h_body
    b["inspecting"][i] = not info["waiting_for_phase_change"]
    b["phase"][i] = info["phase"]
    b["collision"][i] = bool(env.sim.in_collision[0])
    b["coverage"][i] = info["coverage"]
    b["action"][i] = np.nan
    b["solve_ms"][i] = np.nan
    b["act_ms"][i] = np.nan
    b["latency_ms"][i] = np.nan
    return i


def _stat_ms(policy: Any, name: str) -> float:
    """``policy.last_stats.<name>`` (an attribute or a mapping key) as a float, NaN if absent."""
    stats = getattr(policy, "last_stats", None)
    v = getattr(stats, name, None)
    if v is None and isinstance(stats, Mapping):
        v = stats.get(name)
    try:
        return float(v) if v is not None else math.nan
    except (TypeError, ValueError):
        return math.nan


def _solve_ms(policy: Any) -> float:
    return _stat_ms(policy, "solve_ms")


def _latency_ms(policy: Any) -> float:
    """Observation-to-command latency as the policy reports it; a policy that reports only its
    solve time has no part of ``act`` that runs ahead of the observation."""
    v = _stat_ms(policy, "latency_ms")
    return _solve_ms(policy) if math.isnan(v) else v


def make_env(env_options: Mapping[str, Any]) -> gym.Env:
    """The environment of a run (options as built by :func:`~.scenarios.env_options`)."""
    return gym.make(ENV_ID, **dict(env_options))


def check_policy(policy: Any) -> None:
    """A policy needs ``act(obs)`` and ``reset(seed=None)`` (see :mod:`wt_inspect_env.policy`)."""
    missing = [m for m in ("act", "reset") if not callable(getattr(policy, m, None))]
    if missing:
        raise ValueError(f"policy {type(policy).__name__} lacks {' and '.join(missing)}(); a policy needs "
                         "reset(seed=None) and act(obs) -> normalised action (see wt_inspect_env.policy.Policy)")


def fly(env: gym.Env, policy: Any, spec: RunSpec, *, record: bool = True,
        progress: ProgressCallback | None = None) -> RunResult:
    """Fly ``policy`` in ``env`` for one episode of ``spec`` (seeded reset, optional time cap).

    The run ends when the environment terminates (collision, leaving the working volume) or
    truncates (mission complete, time limit), or when the simulated time reaches ``max_time``.
    """
    check_policy(policy)
    u = env.unwrapped
    t_start = time.perf_counter()
    obs, info = env.reset(seed=spec.seed)
    policy.reset(seed=spec.seed)
    limit = u.time_limit if spec.max_time is None else min(u.time_limit, spec.max_time)
    rec = _Recorder(int(limit / u.dt) + 2 if record else 0)
    track = _Track(int(limit / u.dt) + 2)
    i = _record(rec, u, obs, info) if record else 0
    track.add(u.sim, info)
    termination, complete, steps = None, False, 0
    solve: list[float] = []
    stalls: list[dict[str, Any]] = []
    act_ms: list[float] = []
    next_report = t_start
    while True:
        t0 = time.perf_counter()
        action = np.asarray(policy.act(obs), dtype=np.float64)
        dt_act = (time.perf_counter() - t0) * 1000.0
        solve.append(_solve_ms(policy))
        act_ms.append(dt_act)
        if record:
            rec.buf["action"][i] = action.reshape(-1)[:4] if action.size >= 4 else np.nan
            rec.buf["solve_ms"][i] = solve[-1]
            rec.buf["act_ms"][i] = dt_act
            rec.buf["latency_ms"][i] = _latency_ms(policy)
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        track.add(u.sim, info)
        if info["stalls"] > len(stalls):
            stalls.append(_stall_event(u, info, track.n - 1))
        if record:
            i = _record(rec, u, obs, info)
        if terminated or truncated:
            termination = info["termination"] or ("mission_complete" if info["mission_complete"] else
                                                   "reference_stall" if info["stalls"] and
                                                   u.config.reference_on_stall == "end" else "time_limit")
            complete = bool(info["mission_complete"])
            break
        if spec.max_time is not None and info["time"] >= spec.max_time - 1e-9:
            termination = "max_time"
            break
        if progress is not None and time.perf_counter() >= next_report:
            progress(float(info["time"]), float(limit))
            next_report = time.perf_counter() + 0.5
    if progress is not None:
        progress(float(info["time"]), float(limit))
    med, p99 = _stats_ms(np.asarray(solve))
    amed, ap99 = _stats_ms(np.asarray(act_ms))
    extra, per_sample = track.results(u)
    arrays: dict[str, np.ndarray] = {}
    if record:
        arrays = rec.arrays(spec.record_every)
        kept = _kept(track.n, spec.record_every)
        arrays.update({k: np.asarray(v[kept], dtype=np.float32) for k, v in per_sample.items()})
        arrays["coverage_counts"] = np.asarray(u.coverage_counts, dtype=np.int32)
        arrays["inspected"] = np.asarray(u.mission.inspected, dtype=np.int32)
        arrays["blade_triangles"] = np.stack([t.blade_vertices for t in u.mission.turbines]).astype(np.float32)
        t0 = u.mission.turbines[0]
        arrays["triangle_blade"] = np.asarray(t0.triangle_blade, dtype=np.int16)
        arrays["triangle_face"] = np.asarray(t0.triangle_face, dtype=np.int16)
        arrays["rotor_center"] = np.asarray(t0.rotor_center, dtype=np.float64)
    extra |= {"stalls": float(info["stalls"]), "skipped_path_m": float(info["skipped_m"])}
    stall_log = [_stall_why(e, per_sample["clearance"], u.config.d_min) for e in stalls]
    solve = {"solve_median_ms": med, "solve_p99_ms": p99, "act_median_ms": amed, "act_p99_ms": ap99}
    report = getattr(getattr(policy, "stats", None), "as_dict", None)   # a safety filter's counts
    if callable(report):
        solve |= {k: float(v) for k, v in report().items() if k.startswith("filter_")}
    return RunResult(spec=spec, metrics=dict(info["metrics"]) | extra, termination=termination,
                     mission_complete=complete,
                     steps=steps, sim_time_s=float(info["time"]), wall_time_s=time.perf_counter() - t_start,
                     solve=solve,
                     d_ref=float(u.config.standoff), safety_margin=float(u.config.safety_margin), arrays=arrays,
                     code=code_fingerprint(), stall_log=stall_log)


# A stall whose drone was within this much [m] of d_min is put down to the clearance constraint
# (it holds the drone off a pose that lies too close to the structure); farther out, to wind or
# the controller (the drone is free to move towards its pose and does not).
STALL_AT_CLEARANCE_M = 0.3


def _stall_event(env: Any, info: Mapping[str, Any], step: int) -> dict[str, Any]:
    """What the run records when the reference stalls: when, where along the mission, how far the
    drone was from its stand-off pose and what the reference then did (``skipped``: on until the
    drone is back on its pose; ``paced``: at the nominal speed to the end, having fallen behind the
    time limit's schedule; ``ended``) (the step index is resolved
    to the drone's clearance once the run's clearance is computed, see :func:`_stall_why`)."""
    ref = env.world.reference
    pos = _position_and_thrusts(env.sim)[0]
    return {"time_s": float(info["time"]), "progress": float(ref.sample.progress[0]),
            "phase": int(info["phase"]),
            "distance_to_pose_m": float(np.linalg.norm(np.asarray(info["ideal_position"]) - pos)),
            "wind_m_s": float(np.linalg.norm(info["wind"])),
            "action": ("paced" if int(ref.skipping[0]) == PACING else
                       "skipped" if env.config.reference_on_stall == "skip" else "ended"), "_step": step}


def _stall_why(event: dict[str, Any], clearance: np.ndarray, d_min: float) -> dict[str, Any]:
    """``event`` with the drone's clearance at the stall and the reason read from it."""
    e = dict(event)
    c = float(clearance[e.pop("_step")])
    e["clearance_m"] = c
    e["why"] = ("behind the schedule that ends the mission by its time limit" if e["action"] == "paced" else
                "held at d_min by the clearance constraint" if c <= d_min + STALL_AT_CLEARANCE_M
                else "held off its pose (wind or the controller)")
    return e


_STALL_FIELDS = {"time_s", "progress", "phase", "distance_to_pose_m", "wind_m_s", "action", "clearance_m", "why"}


def _check_stall_log(path: Path, log: Any) -> list[dict[str, Any]]:
    """The stall records of a run file, each a JSON object with exactly :data:`_STALL_FIELDS`."""
    for e in log:
        if not isinstance(e, dict) or set(e) != _STALL_FIELDS:
            raise ValueError(f"{path} is not a run file of this format: stall_log entry {e!r}")
    return list(log)


def exception_result(spec: RunSpec, exc: BaseException, wall_time_s: float, steps: int = 0,
                     solve: Mapping[str, float] | None = None) -> RunResult:
    """The result of a run that raised: ``termination="exception"``, the exception's type, first
    line and where it was raised in ``metrics["error"]`` (what a study that goes on after a failing
    run records for it)."""
    import traceback
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    text = str(exc).strip()
    msg = f"{type(exc).__name__}: {text.splitlines()[0] if text else ''}"
    if where is not None:
        msg += f" ({Path(where.filename).name}:{where.lineno})"
    return RunResult(spec=spec, metrics={"error": msg}, termination="exception", mission_complete=False,
                     steps=steps, sim_time_s=math.nan, wall_time_s=wall_time_s, solve=dict(solve or {}),
                     d_ref=math.nan, safety_margin=math.nan)


def execute_or_record(spec: RunSpec, policy: Any = None, *, record: bool = True,
                      progress: ProgressCallback | None = None) -> RunResult:
    """:func:`execute`, with an exception returned as the run's result (:func:`exception_result`)
    instead of raised: the backends' ``task`` for studies where one failing run must not end the rest."""
    t0 = time.perf_counter()
    try:
        return execute(spec, policy, record=record, progress=progress)
    except Exception as exc:   # recorded in the result; the study goes on
        return exception_result(spec, exc, time.perf_counter() - t0)


def execute(spec: RunSpec, policy: Any = None, *, record: bool = True,
            progress: ProgressCallback | None = None) -> RunResult:
    """Build the environment of ``spec`` and fly it with ``policy`` - an object with the common
    interface, a factory ``env -> policy``, or None for the registered ``spec.controller``."""
    env = make_env(spec.env_options)
    try:
        if policy is None:
            policy = registry.resolve(spec.controller, trust_model=spec.trust_model)(env.unwrapped)
        elif not callable(getattr(policy, "act", None)) and callable(policy):
            policy = policy(env.unwrapped)
        return fly(env, policy, spec, record=record, progress=progress)
    finally:
        env.close()


#: environment options that change only what counts as seen, not the flight
COVERAGE_KEYS = ("camera", "occlusion")


def flight_key(env_options: Mapping[str, Any]) -> str:
    """The options that decide the flight, as one comparable string (all but :data:`COVERAGE_KEYS`;
    JSON, so a run file's lists equal the tuples they were made from)."""
    return json.dumps({k: v for k, v in env_options.items() if k not in COVERAGE_KEYS}, sort_keys=True,
                      default=_json_default)


def rescore_coverage(result: RunResult, env_options: Mapping[str, Any]) -> dict[str, Any]:
    """Coverage of a recorded run under other camera / coverage-rule options, without flying it.

    ``env_options``: the run's own options with only the camera or the coverage rule changed
    (:data:`COVERAGE_KEYS`; ValueError if anything else differs); the flight does not depend on
    them, so the run's frames are re-scored
    (:meth:`~wt_inspect_env.env.InspectionEnv.replay_coverage`). Needs the run's full trajectory
    (``record_every=1``). Returns ``coverage``, ``area_coverage`` and the per-triangle ``counts``.
    """
    spec = result.spec
    if flight_key(env_options) != flight_key(spec.env_options):
        raise ValueError(f"cannot re-score {result.path or spec.filename}: the options differ from the run's beyond "
                         f"{', '.join(COVERAGE_KEYS)}")
    if spec.record_every != 1:
        raise ValueError(f"rescoring needs every control step of the run; {result.path or spec.filename} was "
                         f"recorded with record_every={spec.record_every}")
    a = result.arrays
    missing = [k for k in ("position", "quaternion", "phase", "inspecting") if k not in a]
    if missing:
        raise ValueError(f"run {result.path or spec.filename} has no trajectory arrays ({', '.join(missing)})")
    env = make_env(env_options)
    try:
        env.reset(seed=spec.seed)
        tracker = env.unwrapped.replay_coverage(a["position"], a["quaternion"], a["phase"], ~a["inspecting"])
    finally:
        env.close()
    return {"coverage": float(tracker.coverage), "area_coverage": float(tracker.area_coverage),
            "counts": np.asarray(tracker.counts)}


# ------------------------------------------------------------------ files
def save_run(result: RunResult, path: str | Path) -> Path:
    """Write the run file atomically (see the module docstring); returns its path."""
    path = Path(path)
    buf = io.BytesIO()
    meta = json.dumps(result.meta(), default=_json_default, allow_nan=True)
    np.savez_compressed(buf, meta=np.array(meta), **result.arrays)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())
    result.path = path
    return path


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


# What a run file's metadata holds (see :meth:`RunResult.meta`): key -> accepted types. A file
# written by this format's code has exactly these; anything else is refused naming the field.
_NUMBER = (int, float)
_META_FIELDS: dict[str, tuple[type, ...]] = {
    "format": (str,), "spec": (dict,), "metrics": (dict,), "termination": (str, type(None)),
    "mission_complete": (bool,), "steps": (int,), "sim_time_s": _NUMBER, "wall_time_s": _NUMBER,
    "solve": (dict,), "d_ref": _NUMBER, "safety_margin": _NUMBER, "code": (str,), "stall_log": (list,)}
_META_OPTIONAL = {"code", "stall_log"}
_SPEC_FIELDS: dict[str, tuple[type, ...]] = {
    "scenario": (str,), "controller": (str,), "wind": _NUMBER, "seed": (int,), "env_options": (dict,),
    "max_time": (int, float, type(None)), "record_every": (int,), "controller_id": (str,), "trust_model": (bool,)}
_SPEC_OPTIONAL = {"controller_id", "trust_model"}


def _check_fields(path: Path, where: str, doc: Any, fields: Mapping[str, tuple[type, ...]],
                  optional: set[str]) -> None:
    """ValueError naming the file and the field unless ``doc`` is a JSON object with exactly
    ``fields`` (the ``optional`` ones may be absent), each of an accepted type."""
    if not isinstance(doc, dict):
        raise ValueError(f"{path} is not a run file of this format: its {where} is a {type(doc).__name__}, "
                         "not an object")
    extra = sorted(set(doc) - set(fields))
    if extra:
        raise ValueError(f"{path} is not a run file of this format: unknown {where} field {extra[0]!r}")
    missing = [k for k in fields if k not in doc and k not in optional]
    if missing:
        raise ValueError(f"{path} is not a run file of this format: {where} field {missing[0]!r} is missing")
    for k, v in doc.items():
        ok = isinstance(v, fields[k]) and not (isinstance(v, bool) and bool not in fields[k])
        if not ok:
            raise ValueError(f"{path} is not a run file of this format: {where} field {k!r} is {v!r}")


def _check_meta(path: Path, meta: Any) -> "RunSpec":
    """The run spec of a run file's metadata, after checking every field (see :data:`_META_FIELDS`)."""
    if isinstance(meta, dict) and meta.get("format") != FORMAT:
        raise ValueError(f"{path} has format {meta.get('format')!r}, expected {FORMAT!r}")
    _check_fields(path, "metadata", meta, _META_FIELDS, _META_OPTIONAL)
    _check_fields(path, "spec", meta["spec"], _SPEC_FIELDS, _SPEC_OPTIONAL)
    for where in ("metrics", "solve"):
        for k, v in meta[where].items():
            if isinstance(v, bool) and where == "solve" or not isinstance(v, (int, float, str, type(None))):
                raise ValueError(f"{path} is not a run file of this format: {where} field {k!r} is {v!r}")
    return RunSpec(**meta["spec"])


def load_run(path: str | Path, *, arrays: bool = True) -> RunResult:
    """Read a run file (``ValueError`` naming the file - and the field, for metadata that is not
    this format's - if it is not one)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            arr = {k: data[k] for k in data.files if k != "meta"} if arrays else {}
    except Exception as exc:   # zip, key, JSON errors alike: the file is not a complete run file
        raise ValueError(f"{path} is not a readable run file: {exc}") from None
    spec = _check_meta(path, meta)
    return RunResult(spec=spec, metrics=meta["metrics"], termination=meta["termination"],
                     mission_complete=meta["mission_complete"], steps=meta["steps"],
                     sim_time_s=meta["sim_time_s"], wall_time_s=meta["wall_time_s"], solve=meta["solve"],
                     d_ref=meta["d_ref"], safety_margin=meta["safety_margin"], arrays=arr, path=path,
                     code=meta.get("code", ""), stall_log=_check_stall_log(path, meta.get("stall_log", [])))
