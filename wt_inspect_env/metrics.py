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
* heading ``h = (R e_x) . a_xy / |a_xy|`` with R the body-to-world rotation (full attitude, as in
  the paper) and centering ``CM`` = mean h; ``h = 0`` when the drone is straight above the point;
* coverage = sum(n_new) / n_triangles; redundancy = sum(n_visible) / sum(n_new), the mean number of
  frames in which a seen triangle appeared, and ``mean_view_time_s`` the same in seconds;
* what an inspection engineer also asks: min/max/mean distance, RMS and max distance error,
  heading error of the (yaw-following) camera in degrees, incidence angle between n and the line
  of sight, the offset of the drone from the normal line through p (the paper's orthogonality
  ``o = |a - (a.n) n|``), ground sampling distance (if the camera's per-pixel angle is given),
  collisions (events = rising edges of the flag, and samples in collision), path length, flight
  time, mean speed.

Distance, safety, centering, incidence and GSD statistics use the inspecting samples; time, path,
collisions and coverage use all samples. Samples are weighted equally (the paper averages "over
the entire trajectory"), so record them at a fixed rate.

:class:`MetricAccumulator` (incremental, used by the environment) buffers raw samples in a fixed
block of rows and reduces each full block with the same vectorised kernel that
:func:`compute_metrics` (whole trajectories) applies to the same blocks, so both return *identical*
numbers, per-step cost is a row write, and memory stays flat however long the episode.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .validation import check_array, check_positive

BLOCK = 256  # rows per reduction block (flush cost amortised; result() reduces at most this many)
# Column layout of the raw sample rows.
_T, _X, _Q, _P, _N, _DREF, _COL, _NEW, _VIS, _INSP = 0, slice(1, 4), slice(4, 8), slice(8, 11), slice(11, 14), 14, 15, 16, 17, 18
_NCOLS = 19


@dataclass(frozen=True)
class MetricsConfig:
    """Reference stand-off and safety margin [m]; optional camera per-pixel angle for the GSD."""

    d_ref: float = 7.0
    safety_margin: float = 1.0
    pixel_ifov_rad: float | None = None

    def __post_init__(self) -> None:
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
        return dataclasses.asdict(self)


@dataclass
class _Totals:
    """Partial sums over blocks; merged in block order so every path adds in the same order."""

    n: int = 0
    n_insp: int = 0
    safe: int = 0
    sum_h: float = 0.0
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

    def merged(self, o: "_Totals") -> "_Totals":
        if o.n == 0:
            return dataclasses.replace(self)
        return _Totals(
            n=self.n + o.n, n_insp=self.n_insp + o.n_insp, safe=self.safe + o.safe,
            sum_h=self.sum_h + o.sum_h, min_h=min(self.min_h, o.min_h),
            sum_herr=self.sum_herr + o.sum_herr, max_herr=max(self.max_herr, o.max_herr),
            sum_d=self.sum_d + o.sum_d, min_d=min(self.min_d, o.min_d), max_d=max(self.max_d, o.max_d),
            sum_err2=self.sum_err2 + o.sum_err2, max_abs_err=max(self.max_abs_err, o.max_abs_err),
            sum_inc=self.sum_inc + o.sum_inc, max_inc=max(self.max_inc, o.max_inc),
            sum_o=self.sum_o + o.sum_o, sum_dist3=self.sum_dist3 + o.sum_dist3, path=self.path + o.path,
            col_events=self.col_events + o.col_events, col_samples=self.col_samples + o.col_samples,
            new=self.new + o.new, vis=self.vis + o.vis,
            t_first=self.t_first if self.n else o.t_first, t_last=o.t_last)


def _block_totals(rows: np.ndarray, prev_position: np.ndarray | None, prev_collision: bool,
                  margin: float) -> _Totals:
    """Vectorised reduction of a block of raw rows (the one kernel both code paths use)."""
    tot = _Totals(n=len(rows))
    if len(rows) == 0:
        return tot
    x, n = rows[:, _X], rows[:, _N]
    insp = rows[:, _INSP] > 0.5
    col = rows[:, _COL] > 0.5
    a = rows[:, _P] - x
    q = rows[:, _Q]
    qq = np.einsum("ij,ij->i", q, q)
    qx, qy, qz, qw = q.T
    # body x axis in the world (first column of R for the normalised quaternion), horizontal part
    bx0 = 1.0 - 2.0 * (qy * qy + qz * qz) / qq
    bx1 = 2.0 * (qx * qy + qw * qz) / qq
    dot = bx0 * a[:, 0] + bx1 * a[:, 1]
    crs = bx0 * a[:, 1] - bx1 * a[:, 0]
    d = np.hypot(a[:, 0], a[:, 1])
    ok = d > 1e-9
    dist3 = np.sqrt(np.einsum("ij,ij->i", a, a))
    nu = n / np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]                        # unit normals
    a_n = np.einsum("ij,ij->i", a, nu)
    err = d - rows[:, _DREF]
    # columns: h, heading error [deg], d, |err|, err^2, incidence [deg], orthogonal offset, 3-D distance
    stats = np.empty((len(rows), 8))
    stats[:, 0] = np.where(ok, dot / np.where(ok, d, 1.0), 0.0)
    stats[:, 1] = np.where(ok, np.degrees(np.abs(np.arctan2(crs, dot))), 90.0)
    stats[:, 2] = d
    stats[:, 3] = np.abs(err)
    stats[:, 4] = err * err
    far = dist3 > 1e-9
    stats[:, 5] = np.where(far, np.degrees(np.arccos(np.clip(-a_n / np.where(far, dist3, 1.0), -1.0, 1.0))), 90.0)
    perp = a - a_n[:, None] * nu
    stats[:, 6] = np.sqrt(np.einsum("ij,ij->i", perp, perp))
    stats[:, 7] = dist3
    tot.n_insp = int(np.count_nonzero(insp))
    if tot.n_insp:
        si = stats[insp]
        sums, mins, maxs = si.sum(axis=0), si.min(axis=0), si.max(axis=0)
        tot.safe = int(np.count_nonzero(si[:, 3] < margin))
        tot.sum_h, tot.min_h = float(sums[0]), float(mins[0])
        tot.sum_herr, tot.max_herr = float(sums[1]), float(maxs[1])
        tot.sum_d, tot.min_d, tot.max_d = float(sums[2]), float(mins[2]), float(maxs[2])
        tot.max_abs_err, tot.sum_err2 = float(maxs[3]), float(sums[4])
        tot.sum_inc, tot.max_inc = float(sums[5]), float(maxs[5])
        tot.sum_o, tot.sum_dist3 = float(sums[6]), float(sums[7])
    if prev_position is not None:
        steps = np.diff(x, axis=0, prepend=prev_position[None, :])
    else:
        steps = np.diff(x, axis=0)
    tot.path = float(np.sqrt(np.einsum("ij,ij->i", steps, steps)).sum())
    col_prev = np.empty(len(rows), dtype=bool)
    col_prev[0] = prev_collision
    col_prev[1:] = col[:-1]
    tot.col_events = int(np.count_nonzero(col & ~col_prev))
    tot.col_samples = int(np.count_nonzero(col))
    counts = rows[:, _NEW:_VIS + 1].sum(axis=0)
    tot.new, tot.vis = int(round(float(counts[0]))), int(round(float(counts[1])))
    tot.t_first, tot.t_last = float(rows[0, _T]), float(rows[-1, _T])
    return tot


def heading_and_distance(position, quaternion, point) -> tuple[float, float]:
    """The paper's heading function h and horizontal distance d for one sample, in plain floats
    (a couple of microseconds; for reward shaping - the same definitions as the metrics)."""
    ax, ay = float(point[0]) - float(position[0]), float(point[1]) - float(position[1])
    qx, qy, qz, qw = (float(v) for v in quaternion)
    qq = qx * qx + qy * qy + qz * qz + qw * qw
    bx0 = 1.0 - 2.0 * (qy * qy + qz * qz) / qq
    bx1 = 2.0 * (qx * qy + qw * qz) / qq
    d = math.hypot(ax, ay)
    return ((bx0 * ax + bx1 * ay) / d if d > 1e-9 else 0.0), d


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
        centering_cm=tot.sum_h / ni if ni else nan, min_heading=tot.min_h if ni else nan,
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


def _check_rows(rows: np.ndarray, first_index: int) -> None:
    """Name the first bad field of a block of raw rows."""
    fields = (("time", slice(0, 1)), ("position", _X), ("quaternion", _Q), ("point", _P), ("normal", _N),
              ("d_ref", slice(14, 15)), ("n_new", slice(16, 17)), ("n_visible", slice(17, 18)))
    for name, cols in fields:
        bad = ~np.all(np.isfinite(rows[:, cols]), axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"metrics {name} must be finite, got {rows[i, cols].tolist()} at sample {first_index + i}")
    for name, cols in (("quaternion", _Q), ("normal", _N)):
        bad = np.einsum("ij,ij->i", rows[:, cols], rows[:, cols]) < 1e-12
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"metrics {name} must be non-zero, got {rows[i, cols].tolist()} at sample {first_index + i}")
    for name, col in (("d_ref", _DREF),):
        bad = rows[:, col] <= 0
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"metrics {name} must be positive, got {rows[i, col]} at sample {first_index + i}")
    for name, col in (("n_new", _NEW), ("n_visible", _VIS)):
        bad = rows[:, col] < 0
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"metrics {name} must be >= 0, got {rows[i, col]} at sample {first_index + i}")
    dt = np.diff(rows[:, _T])
    if np.any(dt < 0):
        i = int(np.flatnonzero(dt < 0)[0]) + 1
        raise ValueError(f"metrics time must be non-decreasing, got {rows[i, _T]} after {rows[i - 1, _T]} "
                         f"at sample {first_index + i}")


class MetricAccumulator:
    """Incremental metrics for the environment: ``add`` one sample per step, ``result()`` any time.

    ``add`` writes one row into a fixed block; full blocks are validated and reduced (vectorised),
    so the cost per step is a few microseconds and memory does not grow.
    """

    def __init__(self, n_triangles: int | None = None, config: MetricsConfig | None = None) -> None:
        self.config = config if config is not None else MetricsConfig()
        if not isinstance(self.config, MetricsConfig):
            raise ValueError(f"config must be a MetricsConfig, got {type(self.config).__name__}")
        self.n_triangles = _check_n_triangles(n_triangles)
        self._buf = np.zeros((BLOCK, _NCOLS))
        self.reset()

    def reset(self) -> None:
        self._i = 0
        self._tot = _Totals()
        self._prev_pos: np.ndarray | None = None
        self._prev_col = False
        self._last_t = -math.inf
        self._cached: tuple[int, InspectionMetrics] | None = None

    def add(self, t: float, position, quaternion, point, normal, *, collision: bool = False, n_new: int = 0,
            n_visible: int = 0, d_ref: float | None = None, inspecting: bool = True) -> None:
        """Record one sample (see the module docstring for the meaning of each input)."""
        t = float(t)
        if not t >= self._last_t:   # also catches NaN
            raise ValueError(f"metrics time must be finite and non-decreasing, got {t} after {self._last_t}")
        if (np.shape(position) != (3,) or np.shape(quaternion) != (4,) or np.shape(point) != (3,)
                or np.shape(normal) != (3,)):
            for name, value, k in (("position", position, 3), ("quaternion", quaternion, 4), ("point", point, 3),
                                   ("normal", normal, 3)):
                check_array(f"metrics {name}", value, (k,))
        row = self._buf[self._i]
        row[_T] = t
        try:
            row[_X] = position
            row[_Q] = quaternion
            row[_P] = point
            row[_N] = normal
        except (ValueError, TypeError):
            for name, value, k in (("position", position, 3), ("quaternion", quaternion, 4), ("point", point, 3),
                                   ("normal", normal, 3)):
                check_array(f"metrics {name}", value, (k,))
            raise
        row[_DREF] = self.config.d_ref if d_ref is None else d_ref
        row[_COL] = 1.0 if collision else 0.0
        row[_NEW] = n_new
        row[_VIS] = n_visible
        row[_INSP] = 1.0 if inspecting else 0.0
        if (not np.isfinite(row).all() or row[_DREF] <= 0.0 or row[_NEW] < 0.0 or row[_VIS] < 0.0
                or np.dot(row[_Q], row[_Q]) < 1e-12 or np.dot(row[_N], row[_N]) < 1e-12):
            _check_rows(row[None, :], self._tot.n + self._i)
        self._last_t = t
        self._i += 1
        if self._i == BLOCK:
            self._flush()

    def _flush(self) -> None:
        rows = self._buf[:self._i]           # every row was validated by add()
        self._tot = self._tot.merged(_block_totals(rows, self._prev_pos, self._prev_col, self.config.safety_margin))
        self._prev_pos = rows[-1, _X].copy()
        self._prev_col = bool(rows[-1, _COL] > 0.5)
        self._i = 0

    @property
    def n_samples(self) -> int:
        return self._tot.n + self._i

    def result(self) -> InspectionMetrics:
        """Metrics of everything added since the last reset (does not consume the samples).

        Costs ~50-100 us (it reduces the pending block), so call it at the end of an episode or
        every few hundred steps; :func:`heading_and_distance` gives per-step values cheaply."""
        if self._cached is not None and self._cached[0] == self.n_samples:
            return dataclasses.replace(self._cached[1])
        rows = self._buf[:self._i]
        tot = self._tot.merged(_block_totals(rows, self._prev_pos, self._prev_col, self.config.safety_margin))
        out = _finish(tot, self.n_triangles, self.config)
        self._cached = (self.n_samples, out)
        return dataclasses.replace(out)


def compute_metrics(t, positions, quaternions, points, normals, *, collisions=None, n_new=None, n_visible=None,
                    d_ref=None, inspecting=None, n_triangles: int | None = None,
                    config: MetricsConfig | None = None) -> InspectionMetrics:
    """Metrics of a whole recorded trajectory of N samples.

    ``t`` (N,), ``positions`` (N, 3), ``quaternions`` (N, 4), ``points`` (N, 3), ``normals`` (N, 3);
    optional ``collisions`` (N,) bool, ``n_new`` / ``n_visible`` (N,) counts, ``d_ref`` scalar or (N,)
    (default ``config.d_ref``), ``inspecting`` (N,) bool (default all True).
    """
    config = config if config is not None else MetricsConfig()
    if not isinstance(config, MetricsConfig):
        raise ValueError(f"config must be a MetricsConfig, got {type(config).__name__}")
    n_tri = _check_n_triangles(n_triangles)
    T = np.asarray(t, dtype=float)
    if T.ndim != 1:
        raise ValueError(f"t must have shape (N,), got shape {T.shape}")
    N = len(T)
    X = check_array("positions", positions, (N, 3))
    Q = check_array("quaternions", quaternions, (N, 4))
    P = check_array("points", points, (N, 3))
    Nn = check_array("normals", normals, (N, 3))

    def column(name, value, default):
        if value is None:
            return np.full(N, float(default))
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 0:
            return np.full(N, float(arr))
        if arr.shape != (N,):
            raise ValueError(f"{name} must be a scalar or have shape ({N},), got shape {arr.shape}")
        return arr

    cols = [column("collisions", collisions, 0.0), column("n_new", n_new, 0.0), column("n_visible", n_visible, 0.0),
            column("d_ref", d_ref, config.d_ref), column("inspecting", inspecting, 1.0)]
    tot = _Totals()
    prev_pos, prev_col = None, False
    rows = np.zeros((BLOCK, _NCOLS))
    for start in range(0, N, BLOCK):
        stop = min(N, start + BLOCK)
        r = rows[:stop - start]
        r[:, _T] = T[start:stop]
        r[:, _X], r[:, _Q], r[:, _P], r[:, _N] = X[start:stop], Q[start:stop], P[start:stop], Nn[start:stop]
        r[:, _COL] = cols[0][start:stop] > 0.5
        r[:, _NEW], r[:, _VIS], r[:, _DREF] = cols[1][start:stop], cols[2][start:stop], cols[3][start:stop]
        r[:, _INSP] = cols[4][start:stop] > 0.5
        _check_rows(r, start)
        if start and r[0, _T] < T[start - 1]:
            raise ValueError(f"metrics time must be non-decreasing, got {r[0, _T]} after {T[start - 1]} at sample {start}")
        tot = tot.merged(_block_totals(r, prev_pos, prev_col, config.safety_margin))
        prev_pos, prev_col = r[-1, _X].copy(), bool(r[-1, _COL] > 0.5)
    return _finish(tot, n_tri, config)
