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

import math
from dataclasses import dataclass

import numpy as np

from .validation import check_array, check_choice, check_field_types, check_positive

MODES = ("closed_loop", "open_loop")


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


class _Run:
    """One constant-phase stretch of the path with its tau parametrisation."""

    def __init__(self, points: np.ndarray, normals: np.ndarray, s: np.ndarray, phase: int,
                 standoff: float, limit: bool) -> None:
        self.points, self.normals, self.s, self.phase = points, normals, s, phase
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

    def __init__(self, points, normals, s, phase, config: ReferenceConfig | None = None) -> None:
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
        breaks = np.flatnonzero(np.diff(ph) != 0) + 1
        bounds = np.concatenate([[0], breaks, [K]])
        cfg = self.config
        self._runs = [_Run(P[a:b], N[a:b], S[a:b], int(ph[a]), cfg.standoff, bool(cfg.limit_standoff_speed))
                      for a, b in zip(bounds[:-1], bounds[1:])]
        self._run_offsets = np.concatenate([[0.0], np.cumsum([r.length for r in self._runs])])
        self.total_length = float(self._run_offsets[-1])
        self._closed = cfg.mode == "closed_loop"
        self._inv_band = 1.0 / (cfg.stop_threshold - cfg.lag_threshold)
        self.reset()

    @classmethod
    def from_plan(cls, plan, config: ReferenceConfig | None = None) -> "InspectionReference":
        """Build from an ``InspectionPlan`` (anything with points, normals, s and phase)."""
        return cls(plan.points, plan.normals, plan.s, plan.phase, config)

    @property
    def n_phases(self) -> int:
        return len(self._runs)

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
        self._run = 0
        self._tau = f * self._runs[0].length
        self._time = 0.0
        self._holding = False
        self._hold_elapsed = 0.0
        self._done = False
        self._release = False
        return self._sample(0.0, float("nan"), hold_started=False, phase_changed=False)

    def release_hold(self) -> None:
        """End a phase-change hold now (needed when ``phase_hold_time`` is None)."""
        if self._holding:
            self._release = True

    def ideal_position(self) -> np.ndarray:
        """The current ideal stand-off pose."""
        return self._ideal.copy()

    def step(self, dt: float, drone_position=None) -> ReferenceSample:
        """Advance by ``dt`` seconds given the drone's current position (needed in closed loop)."""
        dt = check_positive("reference dt", dt)
        lag = float("nan")
        if drone_position is not None:
            try:
                x0, x1, x2 = (float(v) for v in drone_position)
            except (TypeError, ValueError):
                check_array("drone_position", drone_position, (3,))
                raise
            q = self._ideal
            e0, e1, e2 = x0 - q[0], x1 - q[1], x2 - q[2]
            lag = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)   # products, as the batched reference
            if not math.isfinite(lag):
                check_array("drone_position", drone_position, (3,))
        elif self._closed:
            raise ValueError("drone_position is required in closed_loop mode, got None")
        self._time += dt
        if self._done:
            return self._sample(0.0, lag, hold_started=False, phase_changed=False)
        if self._holding:
            self._hold_elapsed += dt
            limit = self.config.phase_hold_time
            if self._release or (limit is not None and self._hold_elapsed >= limit - 1e-12):
                self._holding = False
                self._release = False
                self._run += 1
                self._tau = 0.0
                return self._sample(0.0, lag, hold_started=False, phase_changed=True)
            return self._sample(0.0, lag, hold_started=False, phase_changed=False)
        sigma = 1.0
        if self._closed:
            sigma = math.sqrt(min(1.0, max(0.0, (self.config.stop_threshold - lag) * self._inv_band)))
        run = self._runs[self._run]
        self._tau += sigma * self.config.speed * dt
        hold_started = False
        if self._tau >= run.length:
            self._tau = run.length
            if self._run == len(self._runs) - 1:
                self._done = True
            else:
                self._holding = True
                self._hold_elapsed = 0.0
                hold_started = True
        return self._sample(sigma, lag, hold_started=hold_started, phase_changed=False)

    # ------------------------------------------------------------------------------------------
    def _interp(self, run: _Run, k: int, frac: float):
        if len(run.tau) == 1:
            g = run.geom[0].copy()
        else:
            g0 = run.geom[k]
            g = g0 + frac * (run.geom[k + 1] - g0)
        p = g[0:3]
        n = g[3:6]
        nn = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        n = n / nn if nn > 1e-9 else run.normals[k].copy()
        hx, hy = g[6], g[7]
        hn = math.hypot(hx, hy)
        if hn > 1e-9:
            hx, hy = hx / hn, hy / hn
        else:
            hx, hy = run.hdir[k, 0], run.hdir[k, 1]
        d = self.config.standoff
        ideal = np.array([p[0] + d * hx, p[1] + d * hy, p[2]])
        return p, n, float(g[9]), ideal

    def _sample(self, sigma: float, lag: float, *, hold_started: bool, phase_changed: bool) -> ReferenceSample:
        run = self._runs[self._run]
        k, frac = run.locate(self._tau)
        p, n, s, ideal = self._interp(run, k, frac)
        self._ideal = ideal
        moving = not (self._holding or self._done) and len(run.tau) > 1
        if moving and sigma > 0.0:
            velocity = (sigma * self.config.speed) * run.dp_dtau[k]
        else:
            velocity = np.zeros(3)
            sigma = sigma if moving else 0.0
        done_len = self._run_offsets[self._run] + self._tau
        progress = 1.0 if self.total_length <= 0 and self._done else (
            done_len / self.total_length if self.total_length > 0 else 0.0)
        return ReferenceSample(point=p, normal=n, velocity=velocity, ideal_position=ideal, s=s, phase=run.phase,
                               progress=float(min(1.0, progress)), speed_factor=float(sigma), lag=lag,
                               time=self._time, done=self._done, waiting_for_phase_change=self._holding,
                               hold_started=hold_started, phase_changed=phase_changed)
