"""Inspection metrics: one extractor for the environment and every evaluation.

Per sample (one per control step; record the state at reset too) the inputs are the time, the drone
position and attitude quaternion (qx, qy, qz, qw), the current inspection point p and its outward
normal n, the reference stand-off d_ref, a collision flag, how many triangles were seen for the
first time (``n_new``) and how many were in view (``n_visible``), and whether the sample belongs to
the inspection proper (``inspecting``; e.g. False while flying to the first point).

With ``a = p - x_drone`` and ``a_xy`` its horizontal part (the paper's notation):

* distance ``d = |a_xy|`` (horizontal, as in the paper's cost and metric);
* safety ``SM`` = share of inspecting samples with ``|d - d_ref| < safety_margin`` (1 m default;
  the paper used 0.1 m in the lab);
* heading ``h = (R e_x) . a_xy / |a_xy|`` with R the body-to-world rotation (full attitude, the
  paper's printed formula): its mean is ``centering_body_cm``. The camera sits on a roll/pitch
  gimbal, so what decides whether the point is centred in the image is the *camera's* heading, the
  horizontal projection of ``R e_x`` (normalised): its mean is the centering metric ``CM``
  (``centering_cm``), which is also what the authors' implementation computed (a yaw-only heading).
  The two differ when the drone tilts against the wind: at 4 m/s the default drone pitches ~17 deg
  and ``h_body = cos 17 deg = 0.96`` while the image stays centred. ``h = 0`` when the drone is
  straight above the point;
* coverage = sum(n_new) / n_triangles; redundancy = sum(n_visible) / sum(n_new), the mean number of
  frames in which a seen triangle appeared, and ``mean_view_time_s`` the same in seconds (times
  the mean sample interval);
* what an inspection engineer also asks: min/max/mean distance, RMS and max distance error,
  heading error of the (yaw-following) camera in degrees, incidence angle between n and the line
  of sight, the offset of the drone from the normal line through p (the paper's orthogonality
  ``o = |a - (a.n) n|``), ground sampling distance (if the camera's per-pixel angle is given),
  collisions (events = rising edges of the flag, and samples in collision), path length, flight
  time, mean speed.

Distance, safety, centering, incidence and GSD statistics use the inspecting samples; time, path,
collisions and coverage use all samples. Samples are weighted equally (the paper averages "over
the entire trajectory"), so record them at a fixed rate.

:class:`MetricAccumulator` (incremental, used by the environment) keeps running sums, minima and
maxima in plain floats: ``add`` is a few scalar updates, ``result`` is O(1) and memory does not grow.
:func:`compute_metrics` (whole trajectories) evaluates the same per-sample formulas vectorised,
with the same floating-point operations in the same order (explicit products instead of ``einsum``,
sequential sums through ``np.cumsum``, ``math.atan2``/``math.acos`` per sample), so both return
*bitwise identical* numbers - the test suite checks it on random flights.
"""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

import numpy as np

from ..util.validation import check_array, check_field_types, check_positive
from .geometry import heading_and_distance  # noqa: F401 - the per-step h and d (held to the accumulator by the tests)


@dataclass(frozen=True)
class MetricsConfig:
    """Reference stand-off and safety margin [m]; optional camera per-pixel angle for the GSD."""

    d_ref: float = 7.0
    safety_margin: float = 1.0
    pixel_ifov_rad: float | None = None

    def __post_init__(self) -> None:
        check_field_types(self, "metrics ")
        check_positive("metrics d_ref", self.d_ref)
        check_positive("metrics safety_margin", self.safety_margin)
        if self.pixel_ifov_rad is not None:
            check_positive("metrics pixel_ifov_rad", self.pixel_ifov_rad)


@dataclass
class InspectionMetrics:
    """Scores of one flight. Shares are fractions in [0, 1]; NaN where undefined (e.g. no
    inspecting samples, or coverage without a triangle count)."""

    n_samples: int
    n_inspecting: int
    flight_time_s: float
    path_length_m: float
    mean_speed_mps: float
    collisions: int
    collision_samples: int
    n_triangles: int
    n_seen: int
    coverage: float
    redundancy: float
    mean_view_time_s: float
    safety_margin_m: float
    safety_sm: float
    centering_cm: float
    centering_body_cm: float
    min_heading: float
    mean_heading_error_deg: float
    max_heading_error_deg: float
    mean_distance_m: float
    min_distance_m: float
    max_distance_m: float
    rms_distance_error_m: float
    max_distance_error_m: float
    mean_incidence_deg: float
    max_incidence_deg: float
    mean_orthogonal_offset_m: float
    mean_gsd_mm: float

    def to_dict(self) -> dict:
        """Plain ``{name: int | float}`` (cheap: called for the env's ``info`` every step)."""
        return dict(self.__dict__)


@dataclass
class _Totals:
    """Running sums / extrema (sums are sequential in sample order in both code paths)."""

    n: int = 0
    n_insp: int = 0
    safe: int = 0
    sum_h: float = 0.0
    sum_hb: float = 0.0
    min_h: float = math.inf
    sum_herr: float = 0.0
    max_herr: float = -math.inf
    sum_d: float = 0.0
    min_d: float = math.inf
    max_d: float = -math.inf
    sum_err2: float = 0.0
    max_abs_err: float = -math.inf
    sum_inc: float = 0.0
    max_inc: float = -math.inf
    sum_o: float = 0.0
    sum_dist3: float = 0.0
    path: float = 0.0
    col_events: int = 0
    col_samples: int = 0
    new: int = 0
    vis: int = 0
    t_first: float = math.nan
    t_last: float = math.nan


def _finish(tot: _Totals, n_triangles: int | None, config: MetricsConfig) -> InspectionMetrics:
    nan = math.nan
    ni = tot.n_insp
    flight = tot.t_last - tot.t_first if tot.n else 0.0
    redundancy = tot.vis / tot.new if tot.new else nan
    dt_mean = flight / (tot.n - 1) if tot.n > 1 else nan
    mean_dist3 = tot.sum_dist3 / ni if ni else nan
    return InspectionMetrics(
        n_samples=tot.n, n_inspecting=ni, flight_time_s=flight, path_length_m=tot.path,
        mean_speed_mps=tot.path / flight if flight > 0 else nan,
        collisions=tot.col_events, collision_samples=tot.col_samples,
        n_triangles=int(n_triangles or 0), n_seen=tot.new,
        coverage=tot.new / n_triangles if n_triangles else nan,
        redundancy=redundancy, mean_view_time_s=redundancy * dt_mean,
        safety_margin_m=config.safety_margin,
        safety_sm=tot.safe / ni if ni else nan,
        centering_cm=tot.sum_h / ni if ni else nan, centering_body_cm=tot.sum_hb / ni if ni else nan,
        min_heading=tot.min_h if ni else nan,
        mean_heading_error_deg=tot.sum_herr / ni if ni else nan, max_heading_error_deg=tot.max_herr if ni else nan,
        mean_distance_m=tot.sum_d / ni if ni else nan, min_distance_m=tot.min_d if ni else nan,
        max_distance_m=tot.max_d if ni else nan,
        rms_distance_error_m=math.sqrt(tot.sum_err2 / ni) if ni else nan,
        max_distance_error_m=tot.max_abs_err if ni else nan,
        mean_incidence_deg=tot.sum_inc / ni if ni else nan, max_incidence_deg=tot.max_inc if ni else nan,
        mean_orthogonal_offset_m=tot.sum_o / ni if ni else nan,
        mean_gsd_mm=(mean_dist3 * config.pixel_ifov_rad * 1000.0
                     if config.pixel_ifov_rad is not None and ni else nan),
    )


def _check_n_triangles(n_triangles) -> int | None:
    if n_triangles is None:
        return None
    if isinstance(n_triangles, bool) or not isinstance(n_triangles, (int, np.integer)) or n_triangles < 1:
        raise ValueError(f"n_triangles must be a positive integer or None, got {n_triangles!r}")
    return int(n_triangles)


def _check_count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"metrics {name} must be a non-negative integer, got {value!r}")
    return int(value)


class MetricAccumulator:
    """Incremental metrics of one drone: ``add`` one sample per step, ``result()`` any time (O(1)).

    The validated front of a :class:`BatchedMetrics` of one drone - the accumulation the
    environments run for N drones - so the metrics have one implementation."""

    def __init__(self, n_triangles: int | None = None, config: MetricsConfig | None = None) -> None:
        self.config = config if config is not None else MetricsConfig()
        if not isinstance(self.config, MetricsConfig):
            raise ValueError(f"config must be a MetricsConfig, got {type(self.config).__name__}")
        self.n_triangles = _check_n_triangles(n_triangles)
        self._batch = BatchedMetrics(1, self.n_triangles, self.config)
        self._idx = np.zeros(1, dtype=np.int64)

    def reset(self) -> None:
        """Start a new episode's metrics."""
        self._batch.reset(0)

    @property
    def n_samples(self) -> int:
        """Number of samples recorded so far."""
        return self._batch.n_samples(0)

    def add(self, t: float, position, quaternion, point, normal, *, collision: bool = False, n_new: int = 0,
            n_visible: int = 0, d_ref: float | None = None, inspecting: bool = True) -> None:
        """Record one sample (see the module docstring for the meaning of each input)."""
        try:
            t = float(t)
            x0, x1, x2 = (float(v) for v in position)
            qx, qy, qz, qw = (float(v) for v in quaternion)
            p0, p1, p2 = (float(v) for v in point)
            n0, n1, n2 = (float(v) for v in normal)
            dref = self.config.d_ref if d_ref is None else float(d_ref)
        except (TypeError, ValueError):
            self._explain(t, position, quaternion, point, normal, d_ref)
            raise
        if not math.isfinite(t + x0 + x1 + x2 + qx + qy + qz + qw + p0 + p1 + p2 + n0 + n1 + n2 + dref):
            self._explain(t, position, quaternion, point, normal, d_ref)
        last = float(self._batch.t_last[0])
        if self.n_samples and not t >= last:
            raise ValueError(f"metrics time must be non-decreasing, got {t} after {last}")
        new, vis = n_new, n_visible
        if type(new) is not int or type(vis) is not int or new < 0 or vis < 0:
            new, vis = _check_count("n_new", n_new), _check_count("n_visible", n_visible)
        qq = qx * qx + qy * qy + qz * qz + qw * qw
        nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if qq < 1e-12 or nn < 1e-6 or dref <= 0.0:
            self._explain(t, position, quaternion, point, normal, d_ref)
        self._batch.add(self._idx, np.array([t]), np.array([[x0, x1, x2]]), np.array([[qx, qy, qz, qw]]),
                        np.array([[p0, p1, p2]]), np.array([[n0, n1, n2]]), np.array([bool(collision)]),
                        np.array([new]), np.array([vis]), np.array([bool(inspecting)]),
                        d_ref=None if d_ref is None else dref)

    def _explain(self, t, position, quaternion, point, normal, d_ref) -> None:
        """Raise a ValueError naming the bad field (slow path, only on bad input)."""
        try:
            tf = float(t)
        except (TypeError, ValueError):
            raise ValueError(f"metrics time must be a finite number, got {t!r}") from None
        if not math.isfinite(tf):
            raise ValueError(f"metrics time must be finite, got {t!r}")
        for name, value, k in (("position", position, 3), ("quaternion", quaternion, 4), ("point", point, 3),
                               ("normal", normal, 3)):
            arr = check_array(f"metrics {name}", value, (k,))
            if name in ("quaternion", "normal") and float(arr @ arr) < 1e-12:
                raise ValueError(f"metrics {name} must be non-zero, got {np.asarray(value).tolist()}")
        if d_ref is not None:
            check_positive("metrics d_ref", d_ref)

    def result(self) -> InspectionMetrics:
        """Metrics of everything added since the last reset (O(1); does not consume the samples)."""
        return self._batch.result(0)


def compute_metrics(t, positions, quaternions, points, normals, *, collisions=None, n_new=None, n_visible=None,
                    d_ref=None, inspecting=None, n_triangles: int | None = None,
                    config: MetricsConfig | None = None) -> InspectionMetrics:
    """Metrics of a whole recorded trajectory of N samples (validated, then the environments' own
    accumulation fed them in order: the same numbers as :class:`MetricAccumulator`).

    ``t`` (N,), ``positions`` (N, 3), ``quaternions`` (N, 4), ``points`` (N, 3), ``normals`` (N, 3);
    optional ``collisions`` (N,) bool, ``n_new`` / ``n_visible`` (N,) non-negative counts, ``d_ref``
    scalar or (N,) (default ``config.d_ref``), ``inspecting`` (N,) bool (default all True).
    """
    config = config if config is not None else MetricsConfig()
    if not isinstance(config, MetricsConfig):
        raise ValueError(f"config must be a MetricsConfig, got {type(config).__name__}")
    n_tri = _check_n_triangles(n_triangles)
    T = check_array("t", t, (None,))
    N = len(T)
    X = check_array("positions", positions, (N, 3))
    Q = check_array("quaternions", quaternions, (N, 4))
    P = check_array("points", points, (N, 3))
    Nv = check_array("normals", normals, (N, 3))

    def column(name, value, default, *, counts=False):
        if value is None:
            return np.full(N, default)
        arr = np.asarray(value)
        if arr.ndim == 0:
            arr = np.full(N, arr)
        if arr.shape != (N,):
            raise ValueError(f"{name} must be a scalar or have shape ({N},), got shape {arr.shape}")
        if counts:
            if arr.dtype.kind not in "iub" or np.any(arr < 0):
                raise ValueError(f"{name} must be non-negative integers, got {arr.dtype} values")
            return arr.astype(np.int64)
        return check_array(name, arr, (N,)) if default is not True and default is not False else arr.astype(bool)

    col = column("collisions", collisions, False)
    new = column("n_new", n_new, 0, counts=True)
    vis = column("n_visible", n_visible, 0, counts=True)
    dref = column("d_ref", d_ref, float(config.d_ref))
    insp = column("inspecting", inspecting, True)
    if np.any(dref <= 0):
        raise ValueError(f"d_ref must be positive, got {dref[dref <= 0][0]}")
    if np.any(np.diff(T) < 0):
        i = int(np.flatnonzero(np.diff(T) < 0)[0]) + 1
        raise ValueError(f"metrics time must be non-decreasing, got {T[i]} after {T[i - 1]} at sample {i}")
    qx, qy, qz, qw = Q.T
    qq = qx * qx + qy * qy + qz * qz + qw * qw
    n0, n1, n2 = Nv.T
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    for name, bad in (("quaternions", qq < 1e-12), ("normals", nn < 1e-6)):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"metrics {name} must be non-zero, got {(Q if name == 'quaternions' else Nv)[i].tolist()} "
                             f"at sample {i}")
    acc = BatchedMetrics(1, n_tri, config)       # the environments' accumulation, fed the samples in order
    acc.add(np.zeros(N, dtype=np.int64), T, X, Q, P, Nv, col, new, vis, insp, d_ref=dref)
    return acc.result(0)


# ------------------------------------------------------------------------------------------ batched
# Column order of BatchedMetrics' stacked totals (world_core.c writes them in this order).
_SUMS = ("sum_h", "sum_hb", "sum_herr", "sum_d", "sum_err2", "sum_inc", "sum_o", "sum_dist3", "path")
_MINS = ("min_h", "min_d")
_MAXS = ("max_herr", "max_d", "max_abs_err", "max_inc")
_COUNTS = ("n", "n_insp", "safe", "col_events", "col_samples", "new", "vis")


class BatchedMetrics:
    """Per-drone metric totals; ``add`` one sample per drone and step, ``result(i)`` any time.

    The totals are four stacked arrays (sums, minima, maxima, counts; columns in the order of
    ``_SUMS`` ... ``_COUNTS``) that the compiled accumulation (:mod:`~wt_inspect_env.native.world_core`)
    updates in place: each entry is a sequential sum / extremum over its drone's samples, computed
    per drone with the same scalar arithmetic whatever N is."""

    def __init__(self, n: int, n_triangles: int | None, config: MetricsConfig) -> None:
        from ..native import world_core as wc

        self._wc, self._lib = wc, wc.library()
        self.n, self.n_triangles, self.config = n, n_triangles, config
        self.sums = np.zeros((n, len(_SUMS)))
        self.mins = np.full((n, len(_MINS)), math.inf)
        self.maxs = np.full((n, len(_MAXS)), -math.inf)
        self.counts = np.zeros((n, len(_COUNTS)), dtype=np.int64)
        self.t_first = np.full(n, math.nan)
        self.t_last = np.full(n, math.nan)
        self._prev = np.zeros((n, 3))
        self._prev_col = np.zeros(n, dtype=bool)
        m = self._m = wc.Metrics()
        for name, arr in (("sums", self.sums), ("mins", self.mins), ("maxs", self.maxs), ("counts", self.counts),
                          ("t_first", self.t_first), ("t_last", self.t_last), ("prev", self._prev),
                          ("prev_col", self._prev_col)):
            setattr(m, name, wc.addr(arr))
        m.safety_margin = config.safety_margin
        self._mp = ctypes.addressof(m)
        self._dref = np.array([config.d_ref])

    def n_samples(self, i: int) -> int:
        """Number of samples recorded for drone ``i``."""
        return int(self.counts[i, 0])

    def reset(self, i: int) -> None:
        """Start a new episode's metrics for drone ``i``."""
        self.sums[i] = 0.0
        self.mins[i] = math.inf
        self.maxs[i] = -math.inf
        self.counts[i] = 0
        self.t_first[i] = self.t_last[i] = math.nan
        self._prev_col[i] = False

    def add(self, idx: np.ndarray, t: np.ndarray, position: np.ndarray, quaternion: np.ndarray,
            point: np.ndarray, normal: np.ndarray, collision: np.ndarray, n_new: np.ndarray,
            n_visible: np.ndarray, inspecting: np.ndarray, d_ref: float | np.ndarray | None = None) -> None:
        """Sample ``j`` of the arguments goes to drone ``idx[j]`` (a drone may appear several times,
        in time order); ``d_ref`` overrides the configuration's reference distance (one value, or
        one per sample)."""
        k = len(idx)
        if k == 0:
            return
        wc = self._wc
        if d_ref is None:
            dref, stride = self._dref, 0
        else:
            dref = np.ascontiguousarray(np.broadcast_to(np.asarray(d_ref, dtype=float), (k,)))
            stride = 1
        args = (wc.c_array(idx, np.int64), wc.c_array(t, float), wc.c_array(position, float),
                wc.c_array(quaternion, float), wc.c_array(point, float), wc.c_array(normal, float),
                wc.c_array(collision, np.bool_), wc.c_array(n_new, np.int64), wc.c_array(n_visible, np.int64),
                wc.c_array(inspecting, np.bool_), dref)
        self._lib.wt_metrics_add(self._mp, k, *(wc.addr(a) for a in args), stride)

    def result(self, i: int) -> InspectionMetrics:
        """Metrics of drone ``i`` since its last reset (the scalar ``_finish`` on its totals)."""
        tot = _Totals(**dict(zip(_SUMS, self.sums[i].tolist())), **dict(zip(_MINS, self.mins[i].tolist())),
                      **dict(zip(_MAXS, self.maxs[i].tolist())), **dict(zip(_COUNTS, self.counts[i].tolist())),
                      t_first=float(self.t_first[i]), t_last=float(self.t_last[i]))
        return _finish(tot, self.n_triangles, self.config)
