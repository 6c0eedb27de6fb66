"""The inspection reference of :mod:`~wt_inspect_env.reference` for N drones at once.

:class:`BatchedReference` advances N independent inspection points along the *same* planned path
(the runs, their tau parametrisation and the stacked geometry come from one
:class:`~wt_inspect_env.reference.InspectionReference`, so the path data has one home). Its state is
arrays - run index, tau, hold clock, done - and :meth:`step` is the scalar ``step`` written over
them with the same floating-point operations in the same order; ``math.hypot`` (which NumPy's
``hypot`` need not match to the last bit) is evaluated per drone. Drone ``i`` therefore follows the
scalar reference bit for bit (tested).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..reference import InspectionReference


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


class BatchedReference:
    """N inspection points on one path; see the module docstring."""

    def __init__(self, reference: InspectionReference, n: int) -> None:
        self.ref = reference
        self.n = n
        cfg = reference.config
        self._runs = reference._runs
        self._offsets = reference._run_offsets
        self.total_length = reference.total_length
        self._closed = cfg.mode == "closed_loop"
        self._inv_band = reference._inv_band
        self._speed = cfg.speed
        self._stop = cfg.stop_threshold
        self._standoff = cfg.standoff
        self._hold_limit = cfg.phase_hold_time
        self.run = np.zeros(n, dtype=np.int64)
        self.tau = np.zeros(n)
        self.time = np.zeros(n)
        self.holding = np.zeros(n, dtype=bool)
        self.hold_elapsed = np.zeros(n)
        self.done = np.zeros(n, dtype=bool)
        self.ideal = np.zeros((n, 3))
        self._sample = self._compute(np.arange(n), np.zeros(n), np.zeros(n, dtype=bool))

    @property
    def sample(self) -> BatchedSample:
        return self._sample

    def reset(self, i: int, start_fraction: float = 0.0) -> None:
        """Back to the start (or ``start_fraction`` of the first phase) for drone ``i``; the new
        sample is in :attr:`sample`."""
        self.run[i] = 0
        self.tau[i] = start_fraction * self._runs[0].length
        self.time[i] = 0.0
        self.holding[i] = False
        self.hold_elapsed[i] = 0.0
        self.done[i] = False
        idx = np.array([i])
        self._write(idx, self._compute(idx, np.zeros(1), np.zeros(1, dtype=bool)))

    def step(self, dt: float, positions: np.ndarray) -> BatchedSample:
        """Advance every drone's point by ``dt`` given the drone positions (N, 3) (closed loop)."""
        q = self.ideal
        d0, d1, d2 = positions[:, 0] - q[:, 0], positions[:, 1] - q[:, 1], positions[:, 2] - q[:, 2]
        lag = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        self.time += dt
        done0, hold0 = self.done.copy(), self.holding.copy()
        sigma = np.zeros(self.n)
        hold_started = np.zeros(self.n, dtype=bool)
        # Holding drones: count the hold, then release into the next run.
        h = np.flatnonzero(hold0 & ~done0)
        if len(h):
            self.hold_elapsed[h] += dt
            if self._hold_limit is not None:
                rel = h[self.hold_elapsed[h] >= self._hold_limit - 1e-12]
                self.holding[rel] = False
                self.run[rel] += 1
                self.tau[rel] = 0.0
        # Moving drones.
        m = np.flatnonzero(~hold0 & ~done0)
        if len(m):
            if self._closed:
                sm = np.sqrt(np.minimum(1.0, np.maximum(0.0, (self._stop - lag[m]) * self._inv_band)))
            else:
                sm = np.ones(len(m))
            sigma[m] = sm
            self.tau[m] += sm * self._speed * dt
            lengths = np.array([r.length for r in self._runs])[self.run[m]]
            end = self.tau[m] >= lengths
            if end.any():
                e = m[end]
                self.tau[e] = lengths[end]
                last = self.run[e] == len(self._runs) - 1
                self.done[e[last]] = True
                hs = e[~last]
                self.holding[hs] = True
                self.hold_elapsed[hs] = 0.0
                hold_started[hs] = True
        all_idx = np.arange(self.n)
        self._write(all_idx, self._compute(all_idx, sigma, hold_started))
        return self._sample

    # ------------------------------------------------------------------------------------------
    def _write(self, idx: np.ndarray, s: BatchedSample) -> None:
        if len(idx) == self.n:
            self._sample = s
            self.ideal = s.ideal_position
            return
        t = self._sample
        for name in ("point", "normal", "velocity", "ideal_position", "phase", "progress", "done",
                     "waiting_for_phase_change", "hold_started"):
            getattr(t, name)[idx] = getattr(s, name)
        self.ideal = t.ideal_position

    def _compute(self, idx: np.ndarray, sigma: np.ndarray, hold_started: np.ndarray) -> BatchedSample:
        """The scalar ``_sample`` (locate, interpolate, velocity, progress) for drones ``idx``."""
        k_n = len(idx)
        point, normal = np.empty((k_n, 3)), np.empty((k_n, 3))
        velocity, ideal = np.zeros((k_n, 3)), np.empty((k_n, 3))
        phase = np.empty(k_n, dtype=np.int64)
        run_of = self.run[idx]
        tau = self.tau[idx]
        holding, done = self.holding[idx], self.done[idx]
        d = self._standoff
        for r_i in np.unique(run_of).tolist():
            sel = np.flatnonzero(run_of == r_i)
            run = self._runs[r_i]
            t = tau[sel]
            n_tau = len(run.tau)
            if n_tau == 1:
                k = np.zeros(len(sel), dtype=np.int64)
                g = np.repeat(run.geom[0:1], len(sel), axis=0)
                frac = np.zeros(len(sel))
            else:
                k = np.searchsorted(run.tau, t, side="right") - 1
                k = np.minimum(np.maximum(k, 0), n_tau - 2)
                dk = run.dtau[k]
                with np.errstate(divide="ignore", invalid="ignore"):
                    frac = np.where(dk <= 0, 0.0, np.minimum(1.0, np.maximum(0.0, (t - run.tau[k]) / dk)))
                g0 = run.geom[k]
                g = g0 + frac[:, None] * (run.geom[k + 1] - g0)
            nv = g[:, 3:6]
            nn = np.sqrt(nv[:, 0] * nv[:, 0] + nv[:, 1] * nv[:, 1] + nv[:, 2] * nv[:, 2])
            good = nn > 1e-9
            nrm = np.where(good[:, None], nv / np.where(good, nn, 1.0)[:, None], run.normals[k])
            hx, hy = g[:, 6].copy(), g[:, 7].copy()
            hn = np.array([math.hypot(a, b) for a, b in zip(hx.tolist(), hy.tolist())])
            okh = hn > 1e-9
            safe = np.where(okh, hn, 1.0)
            hx = np.where(okh, hx / safe, run.hdir[k, 0])
            hy = np.where(okh, hy / safe, run.hdir[k, 1])
            point[sel] = g[:, 0:3]
            normal[sel] = nrm
            ideal[sel, 0] = g[:, 0] + d * hx
            ideal[sel, 1] = g[:, 1] + d * hy
            ideal[sel, 2] = g[:, 2]
            phase[sel] = run.phase
            moving = ~(holding[sel] | done[sel]) & (n_tau > 1)
            sg = sigma[sel]
            mv = moving & (sg > 0.0)
            if mv.any():
                velocity[sel[mv]] = (sg[mv] * self._speed)[:, None] * run.dp_dtau[k[mv]]
        done_len = self._offsets[run_of] + tau
        if self.total_length > 0:
            progress = np.minimum(1.0, done_len / self.total_length)
        else:
            progress = np.where(done, 1.0, 0.0)
        return BatchedSample(point=point, normal=normal, velocity=velocity, ideal_position=ideal, phase=phase,
                             progress=progress, done=done.copy(), waiting_for_phase_change=holding.copy(),
                             hold_started=hold_started.copy())
