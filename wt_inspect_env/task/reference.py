"""The moving inspection point: where on the planned path the camera should look now.

The VT-NMPC tracks an *inspection point* p on the blade surface with its outward normal n and the
point's velocity, not a drone trajectory. This module advances that point along the planner's
path (points, normals, arc length s, phase) and hands out one :class:`ReferenceSample` per control
step.

Timing
------
* ``open_loop`` (the paper's implementation): the point advances at the nominal ``speed``
  whatever the drone does.
* ``closed_loop`` (default): the point advances at ``speed * sigma`` where ``sigma`` depends on the
  drone's distance ``e`` to the ideal stand-off pose ``q = p + d_ref * n_xy / |n_xy|`` (the pose the
  VT-NMPC drives to): ``sigma = 1`` while ``e <= lag_threshold``, ``0`` once ``e >= stop_threshold``
  and ``sqrt((stop_threshold - e) / (stop_threshold - lag_threshold))`` in between. So the point
  slows, then waits, while the drone lags behind or is blown off its pose (wind gusts), and never
  runs ahead of what the drone can inspect; it is never faster than nominal. ``e`` is the 3-D
  distance, so height errors count too. (The square root makes a point running away from a
  hovering drone actually stop, at ``stop_threshold``, in finite time; a linear ramp would only
  approach it exponentially.)

Clearance and stalls
--------------------
Where the ideal pose lies closer to the structure than the flight's minimum distance d_min (a
steep face seen from the horizontal stand-off, a blade root beside the hub), the clearance
constraint stops the drone short of it. ``reach`` (per path sample, from the mission) says by how
much, and the closed loop measures ``e`` less that shortfall: the point does not wait for a pose the
drone may not take. Should the point still make no progress (``sigma < 0.1``) for ``stall_time``
seconds - the drone blocked, or held off by wind it cannot beat - the reference *stalls*, and the stall is
counted (:attr:`BatchedReference.stalls`). With ``on_stall="skip"`` (default) the point moves on at
the nominal speed whatever the drone does until the drone is back within ``lag_threshold`` (or the
run ends), the path length so skipped summed (:attr:`BatchedReference.skipped`): the mission goes on
past a pose the drone cannot take, and the coverage it cost shows in the metrics. Moving on is safe
for the MPCs because their clearance constraint, not the reference, keeps them off the structure.
With ``on_stall="end"`` the environment ends the episode there instead (truncated,
``reference_stall``), the stall on record.

A drone held 1-2 m off its poses (a controller that cannot hold against the wind) keeps its point
moving, slowly: no stall, and the mission would end at the time limit. So with ``on_stall="skip"``
the environment also gives the reference a *deadline* (:meth:`BatchedReference.set_deadline`: its
time limit less the end hold, when the nominal mission fits in it): a point so far behind that only
the nominal speed from its place reaches the path's end by then stalls too (counted once) and keeps
that speed to the end (*pacing*); the path it passes while the drone lags counts as skipped.

Approach from a far start
-------------------------
A drone that starts farther than ``stop_threshold`` from the path's first stand-off pose would
see that pose as its target at once, and an MPC would race to it - tens of metres at up to
16 m/s, past the structure it is to keep clear of. With ``approach_speed`` set, :meth:`approach`
(called by the world after placing the drone) prepends an *approach* from the drone's start to the
first pose: the ideal pose (and the point, carried along with it at d_ref) moves along it at
``approach_speed`` - closed loop like the rest of the path, so it waits for a drone that lags - and
the path proper starts where it ends. The env's default is the braking bound
``sqrt(2 a (d_ref - d_min))`` (``a`` = :data:`~wt_inspect_env.planner.config.CLEARANCE_BRAKE`):
at that speed a drone on its moving pose can stop within the margin between the stand-off and the
clearance the MPCs keep. ``tau`` runs from minus the approach's length to 0 over it; the samples
of the approach report ``progress`` 0 and count in the metrics like any other (the drone holds
d_ref from the carried point). The route is a polyline of up to :data:`APPROACH_MAX` vertices that
a *router* supplies; the world's router
(:class:`~wt_inspect_env.planner.approach.ApproachRouter`) keeps it d_min clear of the
structure and the ground, detouring around a blade that lies between the start and the first
pose (a straight approach through it held the drone against the clearance constraint until the
reference stalled).

Stand-off speed limit
---------------------
Where the normal turns (around a blade edge) the inspection point hardly moves while the ideal
pose swings round an arc of radius ``d_ref``; advancing by the point's arc length alone would ask
the drone to fly that arc at many times the nominal speed (the authors' open-loop reference just
"slowed when the normal changed"). With ``limit_standoff_speed`` (default) the reference is
parametrised by ``tau``, the cumulative ``max(|dp|, |dq|)`` along the path, and ``tau`` advances at
the nominal speed: neither the point nor the ideal pose moves faster than ``speed``. On straight
stretches ``tau == s`` and the timing is exactly ``s = v t``.

Phases
------
The path is split into runs of constant ``phase``. At the end of a run that is not the last the
reference *holds*: it reports ``waiting_for_phase_change`` (velocity zero, point fixed at the run's
end) while the environment holds the drone, turns the rotor and swaps the collision mesh; after
``phase_hold_time`` seconds (or, with ``phase_hold_time=None``, when :meth:`release_hold` is
called) it continues from the first point of the next run with ``phase_changed`` set on that one
sample. ``hold_started`` is set on the first sample of the hold.

Interpolation is linear in ``tau`` between path samples (``np.searchsorted``), normals are
interpolated and renormalised; the reported velocity is ``sigma * speed * dp/dtau``.
"""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..util.validation import check_array, check_choice, check_field_types, check_positive

MODES = ("closed_loop", "open_loop")
#: most vertices of an approach route (start, two detour via points, the first pose); the C core's APPROACH_MAX
APPROACH_MAX = 4
#: ``router(start, first_pose) -> (m, 3)`` polyline from the start to the path's first stand-off pose
Router = Callable[[np.ndarray, np.ndarray], np.ndarray]
ON_STALL = ("end", "skip")


@dataclass(frozen=True)
class ReferenceConfig:
    """Timing of the inspection point. Distances in metres, speed in m/s, times in seconds."""

    speed: float = 0.7
    mode: str = "closed_loop"
    lag_threshold: float = 1.0
    stop_threshold: float = 2.0
    standoff: float = 7.0
    limit_standoff_speed: bool = True
    phase_hold_time: float | None = 5.0
    stall_time: float | None = 20.0
    on_stall: str = "skip"
    approach_speed: float | None = None

    def __post_init__(self) -> None:
        check_field_types(self, "reference ")
        check_positive("reference speed", self.speed)
        check_choice("reference mode", self.mode, MODES)
        lag = check_positive("reference lag_threshold", self.lag_threshold)
        stop = check_positive("reference stop_threshold", self.stop_threshold)
        if stop <= lag:
            raise ValueError(f"reference stop_threshold must exceed lag_threshold ({lag}), got {self.stop_threshold!r}")
        check_positive("reference standoff", self.standoff)
        if not isinstance(self.limit_standoff_speed, (bool, np.bool_)):
            raise ValueError(f"reference limit_standoff_speed must be a bool, got {self.limit_standoff_speed!r}")
        if self.phase_hold_time is not None:
            check_positive("reference phase_hold_time", self.phase_hold_time, allow_zero=True)
        if self.stall_time is not None:
            check_positive("reference stall_time", self.stall_time)
        check_choice("reference on_stall", self.on_stall, ON_STALL)
        if self.approach_speed is not None:
            check_positive("reference approach_speed", self.approach_speed)


@dataclass(frozen=True, slots=True)
class ReferenceSample:
    """The inspection reference at one control step."""

    point: np.ndarray            # (3,) inspection point on the surface
    normal: np.ndarray           # (3,) outward unit normal there
    velocity: np.ndarray         # (3,) velocity of the point [m/s]
    ideal_position: np.ndarray   # (3,) stand-off pose p + d_ref n_xy/|n_xy|
    s: float                     # arc length along the planned path (planner's s)
    phase: int                   # 1 or 2 (the run's phase label)
    progress: float              # share of the mission's tau-length done, in [0, 1]
    speed_factor: float          # sigma used on this step (0 while holding or done)
    lag: float                   # drone distance to ideal_position before the step (NaN if unknown)
    time: float                  # time since reset [s]
    done: bool                   # end of the last run reached
    waiting_for_phase_change: bool
    hold_started: bool           # first sample of a phase-change hold
    phase_changed: bool          # first sample of a new phase
    stalled: bool = False        # first sample of a stall (the point moves on without the drone)


class _Run:
    """One constant-phase stretch of the path with its tau parametrisation."""

    def __init__(self, points: np.ndarray, normals: np.ndarray, s: np.ndarray, phase: int,
                 standoff: float, limit: bool, reach: np.ndarray) -> None:
        self.points, self.normals, self.s, self.phase, self.reach = points, normals, s, phase, reach
        self.hdir = _horizontal_directions(normals)
        self.ideal = points + standoff * self.hdir
        ds = np.diff(s)
        if limit:
            dq = np.linalg.norm(np.diff(self.ideal, axis=0), axis=1)
            dp = np.linalg.norm(np.diff(points, axis=0), axis=1)
            dtau = np.maximum(np.maximum(ds, dq), dp)
        else:
            dtau = ds
        self.tau = np.concatenate([[0.0], np.cumsum(dtau)])
        self.length = float(self.tau[-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            self.dp_dtau = np.where(dtau[:, None] > 0, np.diff(points, axis=0) / dtau[:, None], 0.0)
            self.ds_dtau = np.where(dtau > 0, ds / dtau, 0.0)
        self.dtau = dtau
        # point | normal | horizontal direction | s, stacked so one interpolation serves all
        self.geom = np.column_stack([points, normals, self.hdir, s])

    def locate(self, tau: float) -> tuple[int, float]:
        n = len(self.tau)
        if n == 1:
            return 0, 0.0
        k = int(np.searchsorted(self.tau, tau, side="right")) - 1
        k = min(max(k, 0), n - 2)
        d = self.dtau[k]
        frac = 0.0 if d <= 0 else min(1.0, max(0.0, (tau - self.tau[k]) / d))
        return k, frac


def standoff_poses(points: np.ndarray, normals: np.ndarray, standoff: float) -> np.ndarray:
    """The ideal stand-off poses ``p + d_ref n_xy / |n_xy|`` of path samples (what the reference
    hands out as ``ideal_position``)."""
    return np.asarray(points, dtype=float) + standoff * _horizontal_directions(np.asarray(normals, dtype=float))


def _horizontal_directions(normals: np.ndarray) -> np.ndarray:
    """Unit horizontal parts of the normals; where a normal is (nearly) vertical, the nearest
    sample's direction along the path is used (and +x if none has a horizontal part)."""
    h = normals.copy()
    h[:, 2] = 0.0
    norm = np.linalg.norm(h, axis=1)
    good = norm > 1e-6
    if not good.any():
        out = np.zeros_like(h)
        out[:, 0] = 1.0
        return out
    idx = np.flatnonzero(good)
    nearest = idx[np.clip(np.searchsorted(idx, np.arange(len(h))), 0, len(idx) - 1)]
    prev = idx[np.clip(np.searchsorted(idx, np.arange(len(h))) - 1, 0, len(idx) - 1)]
    pick = np.where(np.abs(prev - np.arange(len(h))) < np.abs(nearest - np.arange(len(h))), prev, nearest)
    return h[pick] / norm[pick, None]


class InspectionReference:
    """Advances the inspection point along the planned path; see the module docstring."""

    def __init__(self, points, normals, s, phase, config: ReferenceConfig | None = None, reach=None) -> None:
        self.config = config if config is not None else ReferenceConfig()
        if not isinstance(self.config, ReferenceConfig):
            raise ValueError(f"config must be a ReferenceConfig, got {type(self.config).__name__}")
        P = check_array("reference points", points, (None, 3))
        K = len(P)
        if K == 0:
            raise ValueError("reference points must hold at least one point, got 0")
        N = check_array("reference normals", normals, (K, 3))
        S = check_array("reference s", s, (K,))
        ph = check_array("reference phase", phase, (K,))
        nn = np.linalg.norm(N, axis=1)
        if np.any(nn < 1e-9):
            i = int(np.flatnonzero(nn < 1e-9)[0])
            raise ValueError(f"reference normals must be non-zero, got normals[{i}] = {N[i].tolist()}")
        if np.any(np.diff(S) < 0):
            i = int(np.flatnonzero(np.diff(S) < 0)[0])
            raise ValueError(f"reference s must be non-decreasing, got s[{i}] = {S[i]} > s[{i + 1}] = {S[i + 1]}")
        if np.any(ph != np.round(ph)) or np.any(ph < 1) or np.any(np.diff(ph) < 0):
            raise ValueError(f"reference phase must be integers >= 1, non-decreasing, got {np.unique(ph).tolist()}")
        N = N / nn[:, None]
        R = np.zeros(K) if reach is None else check_array("reference reach", reach, (K,))
        if np.any(R < 0):
            i = int(np.flatnonzero(R < 0)[0])
            raise ValueError(f"reference reach must be >= 0, got reach[{i}] = {R[i]}")
        breaks = np.flatnonzero(np.diff(ph) != 0) + 1
        bounds = np.concatenate([[0], breaks, [K]])
        cfg = self.config
        self._runs = [_Run(P[a:b], N[a:b], S[a:b], int(ph[a]), cfg.standoff, bool(cfg.limit_standoff_speed),
                           R[a:b]) for a, b in zip(bounds[:-1], bounds[1:])]
        self._run_offsets = np.concatenate([[0.0], np.cumsum([r.length for r in self._runs])])
        self.total_length = float(self._run_offsets[-1])
        self._closed = cfg.mode == "closed_loop"
        self._inv_band = 1.0 / (cfg.stop_threshold - cfg.lag_threshold)
        self._batch = BatchedReference(self, 1)     # the stepping: a batch of one, one implementation
        self.reset()

    @classmethod
    def from_plan(cls, plan, config: ReferenceConfig | None = None, reach=None) -> "InspectionReference":
        """Build from an ``InspectionPlan`` (anything with points, normals, s and phase)."""
        return cls(plan.points, plan.normals, plan.s, plan.phase, config, reach)

    @property
    def n_phases(self) -> int:
        """Number of phases (rotor positions) of the path."""
        return len(self._runs)

    @property
    def phase_starts(self) -> np.ndarray:
        """The progress (share of the tau-length) at which each phase after the first begins: the
        end of the run before, reached on the first sample of its phase-change hold."""
        if self.total_length <= 0:
            return np.zeros(len(self._runs) - 1)
        return self._run_offsets[1:-1] / self.total_length

    @property
    def nominal_duration(self) -> float:
        """Mission time [s] if the drone never lags: path tau-length / speed plus the holds."""
        hold = self.config.phase_hold_time or 0.0
        return self.total_length / self.config.speed + hold * (len(self._runs) - 1)

    # ------------------------------------------------------------------------------------------
    def reset(self, start_fraction: float = 0.0) -> ReferenceSample:
        """Back to the start of the path - or ``start_fraction`` (in [0, 1)) of the way along the
        first phase's path, so that RL training sees every part of a long path (transitions round
        blade edges, the tip) without flying all that precedes it; returns the initial sample."""
        f = check_positive("reference start_fraction", start_fraction, allow_zero=True)
        if f >= 1.0:
            raise ValueError(f"reference start_fraction must be below 1, got {start_fraction!r}")
        self._batch.reset(0, f)
        return self._row()

    def approach(self, start_position, router: Router | None = None) -> ReferenceSample:
        """After :meth:`reset` to the path's start: approach from ``start_position`` along the route
        ``router`` gives (default: straight; see the module docstring); returns the (new) initial
        sample."""
        self._batch.approach(0, check_array("start_position", start_position, (3,)), router)
        return self._row()

    @property
    def approaching(self) -> bool:
        """Whether the point is still on the approach to the path."""
        return bool(self._batch.approaching[0])

    def release_hold(self) -> None:
        """End a phase-change hold now (needed when ``phase_hold_time`` is None)."""
        self._batch.release_hold(0)

    def ideal_position(self) -> np.ndarray:
        """The current ideal stand-off pose."""
        return self._batch.ideal[0].copy()

    def step(self, dt: float, drone_position=None) -> ReferenceSample:
        """Advance by ``dt`` seconds given the drone's current position (needed in closed loop)."""
        dt = check_positive("reference dt", dt)
        if drone_position is not None:
            x = check_array("drone_position", drone_position, (3,))
        elif self._closed:
            raise ValueError("drone_position is required in closed_loop mode, got None")
        else:
            x = np.full(3, np.nan)
        self._batch.step(dt, x[None])
        return self._row()

    def _row(self) -> ReferenceSample:
        b = self._batch.sample
        return ReferenceSample(point=b.point[0].copy(), normal=b.normal[0].copy(), velocity=b.velocity[0].copy(),
                               ideal_position=b.ideal_position[0].copy(), s=float(b.s[0]), phase=int(b.phase[0]),
                               progress=float(b.progress[0]), speed_factor=float(b.speed_factor[0]),
                               lag=float(b.lag[0]), time=float(b.time[0]), done=bool(b.done[0]),
                               waiting_for_phase_change=bool(b.waiting_for_phase_change[0]),
                               hold_started=bool(b.hold_started[0]), phase_changed=bool(b.phase_changed[0]),
                               stalled=bool(b.stalled[0]))

    @property
    def stalls(self) -> int:
        """Stalls since the reset (see the module docstring)."""
        return int(self._batch.stalls[0])

    @property
    def skipped(self) -> float:
        """Path (tau) length the point moved on without the drone since the reset [m]."""
        return float(self._batch.skipped[0])

    @property
    def pacing(self) -> bool:
        """The point fell behind the deadline's schedule and keeps the nominal speed to the end."""
        return bool(self._batch.skipping[0] == PACING)

    def set_deadline(self, deadline: float | None) -> None:
        """See :meth:`BatchedReference.set_deadline`."""
        self._batch.set_deadline(deadline)


# ------------------------------------------------------------------------------------------ batched
# The inspection reference for N drones at once: :class:`BatchedReference` advances N independent
# inspection points along the *same* planned path (the runs and their tau parametrisation come from one
# :class:`InspectionReference`, so the path data has one home), and :class:`InspectionReference` itself
# steps through a batch of one. The arithmetic is compiled (world_core.c): per drone, scalar and in a
# fixed order, so drone i of N and the only drone of a batch of one follow the same reference bit for bit.


@dataclass
class BatchedSample:
    """The reference of every drone at one control step (arrays over drones, like ReferenceSample)."""

    point: np.ndarray            # (N, 3)
    normal: np.ndarray           # (N, 3)
    velocity: np.ndarray         # (N, 3)
    ideal_position: np.ndarray   # (N, 3)
    phase: np.ndarray            # (N,) int
    progress: np.ndarray         # (N,)
    done: np.ndarray             # (N,) bool
    waiting_for_phase_change: np.ndarray   # (N,) bool
    hold_started: np.ndarray     # (N,) bool
    phase_changed: np.ndarray    # (N,) bool: first sample of a new phase
    s: np.ndarray                # (N,) arc length along the planned path
    speed_factor: np.ndarray     # (N,) sigma used on this step (0 while holding or done)
    lag: np.ndarray              # (N,) distance to the ideal pose before the step (NaN if unknown)
    time: np.ndarray             # (N,) time since reset [s]
    stalled: np.ndarray          # (N,) bool: first sample of a stall
    deficit: np.ndarray          # (N,) clearance shortfall of the ideal pose (reach at this sample) [m]


#: :attr:`BatchedReference.skipping` values: moving on after a stall until the drone is back on its
#: pose; at the nominal speed to the end after falling behind the deadline (mirrors world_core.c)
SKIPPING, PACING = 1, 2


class BatchedReference:
    """N inspection points on one path; see the comment above. The stepping is compiled
    (:mod:`~wt_inspect_env.native.world_core`); the state and the current sample are arrays written in
    place (the :attr:`sample`'s arrays change at every step and reset - copy what you keep)."""

    def __init__(self, reference: InspectionReference, n: int) -> None:
        from ..native import world_core as wc

        self._wc = wc
        self._lib = wc.library()
        self.ref = reference
        self.n = n
        cfg = reference.config
        runs = reference._runs
        self.total_length = reference.total_length
        counts = np.array([len(r.tau) for r in runs], dtype=np.int64)
        self._path_arrays = {
            "run_start": np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64),
            "run_count": counts,
            "run_length": np.array([r.length for r in runs], dtype=float),
            "run_offset": np.ascontiguousarray(reference._run_offsets[:-1], dtype=float),
            "run_phase": np.array([r.phase for r in runs], dtype=np.int64),
            "tau": np.concatenate([r.tau for r in runs]).astype(float),
            "dtau": np.concatenate([np.append(r.dtau, 0.0) for r in runs]).astype(float),
            "geom": np.ascontiguousarray(np.concatenate([r.geom for r in runs]), dtype=float),
            "dp_dtau": np.ascontiguousarray(np.concatenate([np.vstack([r.dp_dtau, np.zeros((1, 3))]) for r in runs]),
                                            dtype=float),
            "normals": np.ascontiguousarray(np.concatenate([r.normals for r in runs]), dtype=float),
            "hdir": np.ascontiguousarray(np.concatenate([r.hdir for r in runs]), dtype=float),
            "reach": np.ascontiguousarray(np.concatenate([r.reach for r in runs]), dtype=float),
        }
        path = self._path = wc.RefPath()
        path.n_runs = len(runs)
        for name, arr in self._path_arrays.items():
            setattr(path, name, wc.addr(arr))
        path.total_length, path.speed, path.stop = self.total_length, cfg.speed, cfg.stop_threshold
        path.inv_band, path.standoff = reference._inv_band, cfg.standoff
        path.hold_limit = math.nan if cfg.phase_hold_time is None else cfg.phase_hold_time
        path.closed = int(cfg.mode == "closed_loop")
        path.lag_threshold = cfg.lag_threshold
        path.stall_time = math.nan if cfg.stall_time is None else cfg.stall_time
        path.stall_skip = int(cfg.on_stall == "skip")
        path.approach_speed = math.nan if cfg.approach_speed is None else cfg.approach_speed
        path.deadline = math.nan
        self.approach_len = np.zeros(n)
        self.approach_pts = np.zeros((n, APPROACH_MAX, 3))
        self.approach_nv = np.zeros(n, dtype=np.int64)
        self.run = np.zeros(n, dtype=np.int64)
        self.tau, self.time, self.hold_elapsed = np.zeros(n), np.zeros(n), np.zeros(n)
        self.holding, self.done, self.release = (np.zeros(n, dtype=bool) for _ in range(3))
        # 0 following the drone, SKIPPING after a stall, PACING to the end after falling behind the deadline
        self.skipping = np.zeros(n, dtype=np.uint8)
        self.stalled_for, self.skipped = np.zeros(n), np.zeros(n)
        self.stalls = np.zeros(n, dtype=np.int64)
        self.ideal = np.zeros((n, 3))
        self._sample = BatchedSample(
            point=np.zeros((n, 3)), normal=np.zeros((n, 3)), velocity=np.zeros((n, 3)), ideal_position=self.ideal,
            phase=np.zeros(n, dtype=np.int64), progress=np.zeros(n), done=np.zeros(n, dtype=bool),
            waiting_for_phase_change=np.zeros(n, dtype=bool), hold_started=np.zeros(n, dtype=bool),
            phase_changed=np.zeros(n, dtype=bool), s=np.zeros(n), speed_factor=np.zeros(n), lag=np.zeros(n),
            time=np.zeros(n), stalled=np.zeros(n, dtype=bool), deficit=np.zeros(n))
        st = self._state = wc.RefState()
        smp = self._sample
        for name, arr in (("run", self.run), ("tau", self.tau), ("time", self.time),
                          ("hold_elapsed", self.hold_elapsed), ("holding", self.holding), ("done", self.done),
                          ("release", self.release), ("point", smp.point), ("normal", smp.normal),
                          ("velocity", smp.velocity), ("ideal", self.ideal), ("phase", smp.phase),
                          ("progress", smp.progress), ("s_done", smp.done),
                          ("waiting", smp.waiting_for_phase_change), ("hold_started", smp.hold_started),
                          ("phase_changed", smp.phase_changed), ("s", smp.s), ("speed_factor", smp.speed_factor),
                          ("lag", smp.lag), ("s_time", smp.time), ("stalled_for", self.stalled_for),
                          ("skipping", self.skipping), ("stalls", self.stalls), ("skipped", self.skipped),
                          ("s_stalled", smp.stalled), ("deficit", smp.deficit),
                          ("approach_len", self.approach_len), ("approach_pts", self.approach_pts),
                          ("approach_nv", self.approach_nv)):
            setattr(st, name, wc.addr(arr))
        self._pp, self._sp = ctypes.addressof(path), ctypes.addressof(st)
        all_idx = np.arange(n, dtype=np.int64)
        self._lib.wt_ref_sample(self._pp, self._sp, n, wc.addr(all_idx))

    @property
    def config(self) -> ReferenceConfig:
        """The reference's configuration."""
        return self.ref.config

    @property
    def phase_starts(self) -> np.ndarray:
        """:attr:`InspectionReference.phase_starts` of the path."""
        return self.ref.phase_starts

    @property
    def sample(self) -> BatchedSample:
        """The drones' current reference samples (updated in place)."""
        return self._sample

    def reset(self, i: int, start_fraction: float = 0.0) -> None:
        """Back to the start (or ``start_fraction`` of the first phase) for drone ``i``; the new
        sample is in :attr:`sample`."""
        self.run[i] = 0
        self.tau[i] = start_fraction * self.ref._runs[0].length
        self.time[i] = 0.0
        self.holding[i] = False
        self.hold_elapsed[i] = 0.0
        self.done[i] = False
        self.release[i] = False
        self.skipping[i] = 0
        self.stalled_for[i] = 0.0
        self.stalls[i] = 0
        self.skipped[i] = 0.0
        self.approach_len[i] = 0.0
        idx = np.array([i], dtype=np.int64)
        self._lib.wt_ref_sample(self._pp, self._sp, 1, idx.ctypes.data)

    def approach(self, i: int, start: np.ndarray, router: Router | None = None) -> bool:
        """Drone ``i``, just reset to the path's start, starts at ``start``: farther than
        ``stop_threshold`` from the first stand-off pose, and with an ``approach_speed``, its point
        first approaches along the route ``router(start, first pose)`` returns (a polyline of 2 to
        :data:`APPROACH_MAX` vertices from ``start`` to that pose; without a router, the straight
        segment; module docstring). Returns whether it does; the new sample is in :attr:`sample`."""
        cfg = self.config
        if cfg.approach_speed is None or self.run[i] != 0 or self.tau[i] != 0.0:
            return False
        start = np.asarray(start, dtype=float)
        goal = self.ideal[i].copy()
        gap = float(np.linalg.norm(start - goal))
        if not math.isfinite(gap) or gap <= cfg.stop_threshold:
            return False
        route = np.stack([start, goal]) if router is None else np.asarray(router(start, goal), dtype=float)
        if route.ndim != 2 or route.shape[1] != 3 or not 2 <= len(route) <= APPROACH_MAX \
                or not np.allclose(route[0], start) or not np.allclose(route[-1], goal):
            raise ValueError(f"an approach route must be 2 to {APPROACH_MAX} points (3,) from the start to the first "
                             f"pose, got shape {route.shape}")
        self.approach_nv[i] = len(route)
        self.approach_pts[i, :len(route)] = route
        self.approach_len[i] = float(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())
        self.tau[i] = -self.approach_len[i]
        idx = np.array([i], dtype=np.int64)
        self._lib.wt_ref_sample(self._pp, self._sp, 1, idx.ctypes.data)
        return True

    @property
    def approaching(self) -> np.ndarray:
        """(N,) bool: the drones whose point is still on its approach."""
        return self.tau < 0.0

    def set_deadline(self, deadline: float | None) -> None:
        """The simulated time [s] by which every point must reach the path's end (None: none).
        With ``on_stall="skip"`` and stall detection on, a point so far behind that only the
        nominal speed from its place (approach, runs and phase holds to come) reaches the end by
        then stalls, and keeps that speed to the end whatever its drone does (:attr:`skipping`
        :data:`PACING`; the path it passes while the drone lags is counted in :attr:`skipped`).
        The environment sets its time limit less the end hold, so that a mission ends by its
        time limit with what the drone covered, never at the limit because the point waited."""
        if deadline is None:
            self._path.deadline = math.nan
            return
        check_positive("reference deadline", deadline)
        self._path.deadline = float(deadline)

    def release_hold(self, i: int) -> None:
        """End drone ``i``'s phase-change hold at its next step (needed when ``phase_hold_time`` is None)."""
        if self.holding[i]:
            self.release[i] = True

    def step(self, dt: float, positions: np.ndarray) -> BatchedSample:
        """Advance every drone's point by ``dt`` given the drone positions (N, 3) (closed loop)."""
        pos = np.ascontiguousarray(positions, dtype=float)
        if pos.shape != (self.n, 3):
            raise ValueError(f"positions must have shape ({self.n}, 3), got {pos.shape}")
        self._lib.wt_ref_step(self._pp, self._sp, self.n, float(dt), self._wc.addr(pos))
        return self._sample
