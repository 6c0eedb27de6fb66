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
maxima in plain floats: ``add`` costs ~10 us, ``result`` is O(1) and memory does not grow.
:func:`compute_metrics` (whole trajectories) evaluates the same per-sample formulas vectorised,
with the same floating-point operations in the same order (explicit products instead of ``einsum``,
sequential sums through ``np.cumsum``, ``math.atan2``/``math.acos`` per sample), so both return
*bitwise identical* numbers - the test suite checks it on random flights.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .geometry import heading_and_distance  # noqa: F401 - the per-step h and d (held to the accumulator by the tests)
from .validation import check_array, check_field_types, check_positive

RAD2DEG = 180.0 / math.pi


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
        self._batch.reset(0)

    @property
    def n_samples(self) -> int:
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


def _seq_sum(values: np.ndarray) -> float:
    """Left-to-right sum (what ``+=`` in a loop gives), unlike ``np.sum``'s pairwise order."""
    return float(np.cumsum(values)[-1]) if len(values) else 0.0


def inspection_terms(x0, x1, x2, qx, qy, qz, qw, qq, p0, p1, p2, n0, n1, n2, nn) -> tuple[np.ndarray, ...]:
    """Per-sample inspection quantities of arrays of samples - ``(h, hb, herr, d, inc, o, dist3)``
    (see the module docstring) - from positions, quaternions with their squared norm ``qq``, points
    and normals with their norm ``nn``. Element-wise, with ``atan2``/``acos`` per sample through
    :mod:`math`, so a sample's numbers do not depend on the batch it is in: :func:`compute_metrics`
    (recorded flights) and :class:`BatchedMetrics` (every environment) agree bit for bit."""
    ax, ay, az = p0 - x0, p1 - x1, p2 - x2
    bx0 = 1.0 - 2.0 * (qy * qy + qz * qz) / qq
    bx1 = 2.0 * (qx * qy + qw * qz) / qq
    dot = bx0 * ax + bx1 * ay
    crs = bx0 * ay - bx1 * ax
    d = np.sqrt(ax * ax + ay * ay)
    bxy = np.sqrt(bx0 * bx0 + bx1 * bx1)
    ok = (d > 1e-9) & (bxy > 1e-9)
    hb = np.where(ok, dot / np.where(ok, d, 1.0), 0.0)
    h = np.where(ok, hb / np.where(ok, bxy, 1.0), 0.0)
    herr = np.array([RAD2DEG * math.atan2(c, v) if k else 90.0
                     for c, v, k in zip(np.abs(crs).tolist(), dot.tolist(), ok.tolist())])
    u0, u1, u2 = n0 / nn, n1 / nn, n2 / nn
    a_n = ax * u0 + ay * u1 + az * u2
    dist3 = np.sqrt(ax * ax + ay * ay + az * az)
    far = dist3 > 1e-9
    cosi = np.minimum(1.0, np.maximum(-1.0, -a_n / np.where(far, dist3, 1.0)))
    inc = np.array([RAD2DEG * math.acos(c) if k else 90.0 for c, k in zip(cosi.tolist(), far.tolist())])
    o0, o1, o2 = ax - a_n * u0, ay - a_n * u1, az - a_n * u2
    o = np.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    return h, hb, herr, d, inc, o, dist3


def compute_metrics(t, positions, quaternions, points, normals, *, collisions=None, n_new=None, n_visible=None,
                    d_ref=None, inspecting=None, n_triangles: int | None = None,
                    config: MetricsConfig | None = None) -> InspectionMetrics:
    """Metrics of a whole recorded trajectory of N samples (vectorised; same numbers as
    :class:`MetricAccumulator` fed the same samples).

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
    tot = _Totals(n=N)
    if N:
        tot.t_first, tot.t_last = float(T[0]), float(T[-1])
        dX = np.diff(X, axis=0)
        tot.path = _seq_sum(np.sqrt(dX[:, 0] * dX[:, 0] + dX[:, 1] * dX[:, 1] + dX[:, 2] * dX[:, 2]))
        prev = np.concatenate([[False], col[:-1]])
        tot.col_events = int(np.count_nonzero(col & ~prev))
        tot.col_samples = int(np.count_nonzero(col))
        tot.new, tot.vis = int(new.sum()), int(vis.sum())
    sel = np.flatnonzero(insp)
    tot.n_insp = len(sel)
    if len(sel):
        x0, x1, x2 = X[sel].T
        p0, p1, p2 = P[sel].T
        qx, qy, qz, qw, qq = qx[sel], qy[sel], qz[sel], qw[sel], qq[sel]
        n0, n1, n2, nn = n0[sel], n1[sel], n2[sel], nn[sel]
        h, hb, herr, d, inc, o, dist3 = inspection_terms(x0, x1, x2, qx, qy, qz, qw, qq, p0, p1, p2, n0, n1, n2, nn)
        err = d - dref[sel]
        abs_err = np.abs(err)
        tot.safe = int(np.count_nonzero(abs_err < config.safety_margin))
        tot.sum_h, tot.min_h = _seq_sum(h), float(h.min())
        tot.sum_hb = _seq_sum(hb)
        tot.sum_herr, tot.max_herr = _seq_sum(herr), float(herr.max())
        tot.sum_d, tot.min_d, tot.max_d = _seq_sum(d), float(d.min()), float(d.max())
        tot.sum_err2, tot.max_abs_err = _seq_sum(err * err), float(abs_err.max())
        tot.sum_inc, tot.max_inc = _seq_sum(inc), float(inc.max())
        tot.sum_o, tot.sum_dist3 = _seq_sum(o), _seq_sum(dist3)
    return _finish(tot, n_tri, config)


# ------------------------------------------------------------------------------------------ batched
# The running inspection metrics of :class:`~wt_inspect_env.metrics.MetricAccumulator`, for N drones.
#
# The totals (counts, sums, minima, maxima) are arrays over drones, and :meth:`BatchedMetrics.add`
# is the scalar ``add`` written over them: the per-sample quantities come from
# :func:`~wt_inspect_env.metrics.inspection_terms`, the function :func:`compute_metrics` uses too. Every drone's
# sums are still sequential in time, so :meth:`result` of drone ``i`` - built by the scalar
# ``_finish`` - is bitwise the scalar accumulator's (tested). Inputs come from the environment, which
# has validated them, so the per-sample checks of the scalar class are not repeated here.

_SUMS = ("sum_h", "sum_hb", "sum_herr", "sum_d", "sum_err2", "sum_inc", "sum_o", "sum_dist3", "path")
_MINS = ("min_h", "min_d")
_MAXS = ("max_herr", "max_d", "max_abs_err", "max_inc")
_COUNTS = ("n", "n_insp", "safe", "col_events", "col_samples", "new", "vis")


class BatchedMetrics:
    """Per-drone metric totals; ``add`` one sample per drone and step, ``result(i)`` any time.

    The totals are four stacked arrays (sums, minima, maxima, counts; columns in the order of
    ``_SUMS`` ... ``_COUNTS``), so one sample costs a few whole-row NumPy operations whatever N is;
    each entry is still a sequential sum / extremum over its drone's samples."""

    def __init__(self, n: int, n_triangles: int, config: MetricsConfig) -> None:
        self.n, self.n_triangles, self.config = n, n_triangles, config
        self.sums = np.zeros((n, len(_SUMS)))
        self.mins = np.full((n, len(_MINS)), math.inf)
        self.maxs = np.full((n, len(_MAXS)), -math.inf)
        self.counts = np.zeros((n, len(_COUNTS)), dtype=np.int64)
        self.t_first = np.full(n, math.nan)
        self.t_last = np.full(n, math.nan)
        self._prev = np.zeros((n, 3))
        self._prev_col = np.zeros(n, dtype=bool)

    def n_samples(self, i: int) -> int:
        return int(self.counts[i, 0])

    def reset(self, i: int) -> None:
        self.sums[i] = 0.0
        self.mins[i] = math.inf
        self.maxs[i] = -math.inf
        self.counts[i] = 0
        self.t_first[i] = self.t_last[i] = math.nan
        self._prev_col[i] = False

    def add(self, idx: np.ndarray, t: np.ndarray, position: np.ndarray, quaternion: np.ndarray,
            point: np.ndarray, normal: np.ndarray, collision: np.ndarray, n_new: np.ndarray,
            n_visible: np.ndarray, inspecting: np.ndarray, d_ref: float | None = None) -> None:
        """One sample for each drone in ``idx`` (sorted; the other arguments are rows for those
        drones; ``d_ref`` overrides the configuration's reference distance for this sample)."""
        if len(idx) == 0:
            return
        full = len(idx) == self.n
        rows = slice(None) if full else idx    # every drone: whole-array updates, no fancy indexing

        def subset(mask: np.ndarray):
            return rows if mask.all() else (np.flatnonzero(mask) if full else idx[mask])

        counts = self.counts
        first = counts[rows, 0] == 0
        if first.any():
            self.t_first[subset(first)] = t[first]
        rest = ~first
        if rest.any():
            ir = subset(rest)
            dv = position[rest] - self._prev[ir]
            dx, dy, dz = dv[:, 0], dv[:, 1], dv[:, 2]
            self.sums[ir, 8] += np.sqrt(dx * dx + dy * dy + dz * dz)
        self.t_last[rows] = t
        self._prev[rows] = position
        col = collision.astype(bool)
        inc_counts = np.empty((len(idx), 7), dtype=np.int64)
        inc_counts[:, 0] = 1
        inc_counts[:, 1] = 0
        inc_counts[:, 2] = 0
        inc_counts[:, 3] = col & ~self._prev_col[rows]
        inc_counts[:, 4] = col
        inc_counts[:, 5] = n_new
        inc_counts[:, 6] = n_visible
        self._prev_col[rows] = col
        if not inspecting.any():
            counts[rows] += inc_counts
            return
        if inspecting.all():
            ii, sel = rows, slice(None)
        else:
            sel = np.flatnonzero(inspecting)
            ii = subset(inspecting)
        x, q, pt, nv = position[sel], quaternion[sel], point[sel], normal[sel]
        qx, qy, qz, qw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        n0, n1, n2 = nv[:, 0], nv[:, 1], nv[:, 2]
        qq = qx * qx + qy * qy + qz * qz + qw * qw
        nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        h, hb, herr, d, inc, o, dist3 = inspection_terms(x[:, 0], x[:, 1], x[:, 2], qx, qy, qz, qw, qq,
                                                         pt[:, 0], pt[:, 1], pt[:, 2], n0, n1, n2, nn)
        err = d - (self.config.d_ref if d_ref is None else d_ref)
        abs_err = np.abs(err)
        inc_counts[sel, 1] = 1
        inc_counts[sel, 2] = abs_err < self.config.safety_margin
        counts[rows] += inc_counts
        sums = self.sums[ii]
        sums[:, 0:8] += np.column_stack([h, hb, herr, d, err * err, inc, o, dist3])
        self.sums[ii] = sums
        self.mins[ii] = np.minimum(self.mins[ii], np.column_stack([h, d]))
        self.maxs[ii] = np.maximum(self.maxs[ii], np.column_stack([herr, d, abs_err, inc]))

    def result(self, i: int) -> InspectionMetrics:
        """Metrics of drone ``i`` since its last reset (the scalar ``_finish`` on its totals)."""
        tot = _Totals(**dict(zip(_SUMS, self.sums[i].tolist())), **dict(zip(_MINS, self.mins[i].tolist())),
                      **dict(zip(_MAXS, self.maxs[i].tolist())), **dict(zip(_COUNTS, self.counts[i].tolist())),
                      t_first=float(self.t_first[i]), t_last=float(self.t_last[i]))
        return _finish(tot, self.n_triangles, self.config)
