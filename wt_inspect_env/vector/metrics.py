"""The running inspection metrics of :class:`~wt_inspect_env.metrics.MetricAccumulator`, for N drones.

The totals (counts, sums, minima, maxima) are arrays over drones, and :meth:`BatchedMetrics.add`
is the scalar ``add`` written over them: the per-sample quantities come from
:func:`~wt_inspect_env.metrics.inspection_terms`, the function :func:`compute_metrics` uses too. Every drone's
sums are still sequential in time, so :meth:`result` of drone ``i`` - built by the scalar
``_finish`` - is bitwise the scalar accumulator's (tested). Inputs come from the environment, which
has validated them, so the per-sample checks of the scalar class are not repeated here.
"""
from __future__ import annotations

import math

import numpy as np

from ..metrics import InspectionMetrics, MetricsConfig, _finish, _Totals, inspection_terms

_SUMS = ("sum_h", "sum_hb", "sum_herr", "sum_d", "sum_err2", "sum_inc", "sum_o", "sum_dist3", "path")
_MINS = ("min_h", "min_d")
_MAXS = ("max_herr", "max_d", "max_abs_err", "max_inc")
_COUNTS = ("n", "n_insp", "safe", "col_events", "col_samples", "new", "vis")


class BatchedMetrics:
    """Per-drone metric totals; ``add`` one sample per drone and step, ``result(i)`` any time."""

    def __init__(self, n: int, n_triangles: int, config: MetricsConfig) -> None:
        self.n, self.n_triangles, self.config = n, n_triangles, config
        self.tot: dict[str, np.ndarray] = {}
        for k in _SUMS:
            self.tot[k] = np.zeros(n)
        for k in _MINS:
            self.tot[k] = np.full(n, math.inf)
        for k in _MAXS:
            self.tot[k] = np.full(n, -math.inf)
        for k in _COUNTS:
            self.tot[k] = np.zeros(n, dtype=np.int64)
        self.tot["t_first"] = np.full(n, math.nan)
        self.tot["t_last"] = np.full(n, math.nan)
        self._prev = np.zeros((n, 3))
        self._prev_col = np.zeros(n, dtype=bool)

    def reset(self, i: int) -> None:
        for k in _SUMS:
            self.tot[k][i] = 0.0
        for k in _MINS:
            self.tot[k][i] = math.inf
        for k in _MAXS:
            self.tot[k][i] = -math.inf
        for k in _COUNTS:
            self.tot[k][i] = 0
        self.tot["t_first"][i] = self.tot["t_last"][i] = math.nan
        self._prev_col[i] = False

    def add(self, idx: np.ndarray, t: np.ndarray, position: np.ndarray, quaternion: np.ndarray,
            point: np.ndarray, normal: np.ndarray, collision: np.ndarray, n_new: np.ndarray,
            n_visible: np.ndarray, inspecting: np.ndarray) -> None:
        """One sample for each drone in ``idx`` (the other arguments are rows for those drones)."""
        if len(idx) == 0:
            return
        tot = self.tot
        x0, x1, x2 = position[:, 0], position[:, 1], position[:, 2]
        qx, qy, qz, qw = quaternion[:, 0], quaternion[:, 1], quaternion[:, 2], quaternion[:, 3]
        p0, p1, p2 = point[:, 0], point[:, 1], point[:, 2]
        n0, n1, n2 = normal[:, 0], normal[:, 1], normal[:, 2]
        dref = self.config.d_ref
        qq = qx * qx + qy * qy + qz * qz + qw * qw
        nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        first = tot["n"][idx] == 0
        tot["t_first"][idx[first]] = t[first]
        rest = ~first
        if rest.any():
            ir = idx[rest]
            pv = self._prev[ir]
            dx, dy, dz = x0[rest] - pv[:, 0], x1[rest] - pv[:, 1], x2[rest] - pv[:, 2]
            tot["path"][ir] += np.sqrt(dx * dx + dy * dy + dz * dz)
        tot["n"][idx] += 1
        tot["t_last"][idx] = t
        self._prev[idx] = position
        col = collision.astype(bool)
        tot["col_samples"][idx] += col
        tot["col_events"][idx] += col & ~self._prev_col[idx]
        self._prev_col[idx] = col
        tot["new"][idx] += n_new
        tot["vis"][idx] += n_visible
        s = np.flatnonzero(inspecting)
        if len(s) == 0:
            return
        ii = idx[s]
        x0, x1, x2, qx, qy, qz, qw = x0[s], x1[s], x2[s], qx[s], qy[s], qz[s], qw[s]
        p0, p1, p2, n0, n1, n2, qq, nn = p0[s], p1[s], p2[s], n0[s], n1[s], n2[s], qq[s], nn[s]
        h, hb, herr, d, inc, o, dist3 = inspection_terms(x0, x1, x2, qx, qy, qz, qw, qq, p0, p1, p2, n0, n1, n2, nn)
        err = d - dref
        abs_err = np.abs(err)
        tot["n_insp"][ii] += 1
        tot["safe"][ii] += abs_err < self.config.safety_margin
        tot["sum_h"][ii] += h
        tot["sum_hb"][ii] += hb
        tot["min_h"][ii] = np.minimum(tot["min_h"][ii], h)
        tot["sum_herr"][ii] += herr
        tot["max_herr"][ii] = np.maximum(tot["max_herr"][ii], herr)
        tot["sum_d"][ii] += d
        tot["min_d"][ii] = np.minimum(tot["min_d"][ii], d)
        tot["max_d"][ii] = np.maximum(tot["max_d"][ii], d)
        tot["sum_err2"][ii] += err * err
        tot["max_abs_err"][ii] = np.maximum(tot["max_abs_err"][ii], abs_err)
        tot["sum_inc"][ii] += inc
        tot["max_inc"][ii] = np.maximum(tot["max_inc"][ii], inc)
        tot["sum_o"][ii] += o
        tot["sum_dist3"][ii] += dist3

    def result(self, i: int) -> InspectionMetrics:
        """Metrics of drone ``i`` since its last reset (the scalar ``_finish`` on its totals)."""
        tot = _Totals(**{k: (int(v[i]) if v.dtype.kind == "i" else float(v[i])) for k, v in self.tot.items()})
        return _finish(tot, self.n_triangles, self.config)
