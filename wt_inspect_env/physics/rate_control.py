"""PX4-like inner loop: body-rate PID and a desaturating mixer, run at the physics rate.

PX4's multicopter rate controller (``mc_rate_control``) computes a normalised torque
``P e + I integral(e) - D d(omega)/dt (+ FF omega_sp)`` per axis, with the derivative taken on the
measured rate (no derivative kick on steps) and an anti-windup limit on the integrator, and a mixer
turns torque and collective thrust into motor commands, giving roll/pitch priority over yaw when
motors saturate. Here the same structure works in physical units: the PID output is an angular
*acceleration* that is multiplied by the inertia, so one set of gains fits any airframe, and the
gains are placed from the airframe's motor time constant (:meth:`RateGains.for_params`).

Design of the default gains (per roll/pitch axis, plant = inertia with first-order motor lag tau):
with ``alpha = Kp e + Ki int(e) - Kd omega_dot`` the closed loop is
``tau s^3 + (1 + Kd) s^2 + Kp s + Ki = 0``; we place its roots at ``(s + a)(s^2 + 2 zeta wn s +
wn^2)`` with ``wn = 1.2 / tau``, ``zeta = 0.7`` and ``a = wn / 6`` (a slow integral pole that removes
steady-state error; its zero costs ~10-20 % overshoot, as PX4 rate tunes typically show). For
tau = 0.04 s (13-inch props) that is wn = 30 rad/s and a measured 10-90 % rise time of 50 ms; PX4's
autotuner aims at a rate-loop rise time of 0.14 s by default (``MC_AT_RISE_TIME``), so this is a
crisp but realistic loop. Faster motors get a proportionally faster loop. Yaw authority comes
from rotor drag torque and is an order of magnitude weaker, so its response is saturation
limited (about 0.17 s rise for a 1 rad/s step on the default drone).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..util.validation import check_field_types, check_positive
from .quadrotor import QuadrotorParams

_MIN_DESIGN_TAU = 0.01
_NO_SATURATION = (0, 0, 0)  # motors faster than this are designed for as if tau = 10 ms


def _triple(name: str, value) -> tuple[float, float, float]:
    vals = tuple(value)
    if len(vals) != 3:
        raise ValueError(f"{name} must have 3 entries (roll, pitch, yaw), got {value!r}")
    return tuple(check_positive(f"{name}[{i}]", v, allow_zero=True) for i, v in enumerate(vals))


def _sign(x: float) -> int:
    return 1 if x > 0 else (-1 if x < 0 else 0)


@dataclass(frozen=True)
class RateGains:
    """Body-rate PID gains in angular-acceleration units, per axis (roll, pitch, yaw).

    The defaults are :meth:`for_params` of the default (Matrice 100) preset; the simulator uses
    :meth:`for_params` of its own airframe unless given gains.

    kp [1/s], ki [1/s^2], kd [-] (on the measured rate's derivative); ``integral_limit`` bounds
    ``ki * integral`` [rad/s^2] (anti-windup); ``d_cutoff_hz`` is the low-pass on the derivative
    (PX4 filters its D term at about 30 Hz; without it a 1-sample-delayed derivative rings at the
    Nyquist frequency when the motors have no lag).
    """

    kp: tuple[float, float, float] = (44.4, 44.4, 15.0)
    ki: tuple[float, float, float] = (180.0, 180.0, 9.0)
    kd: tuple[float, float, float] = (0.88, 0.88, 0.0)
    integral_limit: tuple[float, float, float] = (12.0, 12.0, 3.0)
    d_cutoff_hz: float = 40.0

    def __post_init__(self) -> None:
        check_field_types(self, "rate_gains ")
        for name in ("kp", "ki", "kd", "integral_limit"):
            object.__setattr__(self, name, _triple(name, getattr(self, name)))
        check_positive("d_cutoff_hz", self.d_cutoff_hz)

    @classmethod
    def for_params(cls, params: QuadrotorParams, zeta: float = 0.7,
                   wn_times_tau: float = 1.2) -> "RateGains":
        """Pole-placement gains for the airframe's motor time constant (see module docstring)."""
        check_positive("zeta", zeta)
        check_positive("wn_times_tau", wn_times_tau)
        tau = max(params.motor_time_constant, _MIN_DESIGN_TAU)
        wn = wn_times_tau / tau
        a = wn / 6.0
        kd = max(tau * (a + 2 * zeta * wn) - 1.0, 0.0)
        kp = tau * (2 * zeta * wn * a + wn**2)
        ki = tau * a * wn**2
        # Yaw: torque authority is small (rotor drag torque), so the step response is limited by
        # mixer saturation; a P gain of wn/2 and a slow integrator (pole ~ wn/50) avoid windup
        # overshoot. Tuned on both presets with the step-response test's metrics.
        kp_y, ki_y = 0.5 * wn, 0.01 * wn**2
        return cls(kp=(kp, kp, kp_y), ki=(ki, ki, ki_y), kd=(kd, kd, 0.0),
                   integral_limit=(0.4 * wn, 0.4 * wn, 0.1 * wn))


class Mixer:
    """Collective thrust + body torques -> four rotor thrusts within their limits.

    Unsaturated: ``f = A^-1 [T, tau_x, tau_y, tau_z]`` with ``A = params.mixer``. When a rotor would
    leave ``[min_rotor_thrust, max_rotor_thrust]`` the mixer behaves like PX4's with airmode off:
    roll/pitch torque keeps priority and is scaled down only if even the full thrust range cannot
    hold it; collective thrust is lowered (never raised) to make room at the top; yaw torque gets
    what is left (scaled down). The result is always within the limits.
    """

    def __init__(self, params: QuadrotorParams) -> None:
        self.A = np.asarray(params.mixer, float)
        B = np.linalg.inv(self.A)
        self.B = B
        self._bt = tuple(float(x) for x in B[:, 0])
        self._bx = tuple(float(x) for x in B[:, 1])
        self._by = tuple(float(x) for x in B[:, 2])
        self._bz = tuple(float(x) for x in B[:, 3])
        self.f_min = float(params.min_rotor_thrust)
        self.f_max = float(params.max_rotor_thrust)
        # Per-axis saturation of the last mix: +1/-1 when the torque about that axis was cut
        # while positive/negative, 0 otherwise. The rate controller stops integrating into it
        # (PX4's control allocator reports the same to mc_rate_control).
        self.saturation: tuple[int, int, int] = _NO_SATURATION

    def wrench(self, f) -> tuple[float, float, float, float]:
        """[T, tau_x, tau_y, tau_z] produced by rotor thrusts ``f``."""
        return tuple(float(x) for x in self.A @ np.asarray(f, float))

    def mix(self, T: float, tx: float, ty: float, tz: float) -> tuple[float, ...]:
        """Rotor thrusts for the requested wrench (desaturated as described above)."""
        bt, bx, by, bz = self._bt, self._bx, self._by, self._bz
        lo_lim, hi_lim = self.f_min, self.f_max
        f0 = T * bt[0] + tx * bx[0] + ty * by[0] + tz * bz[0]
        f1 = T * bt[1] + tx * bx[1] + ty * by[1] + tz * bz[1]
        f2 = T * bt[2] + tx * bx[2] + ty * by[2] + tz * bz[2]
        f3 = T * bt[3] + tx * bx[3] + ty * by[3] + tz * bz[3]
        if (lo_lim <= f0 <= hi_lim and lo_lim <= f1 <= hi_lim and lo_lim <= f2 <= hi_lim
                and lo_lim <= f3 <= hi_lim):   # fast path: nothing saturates
            self.saturation = _NO_SATURATION
            return f0, f1, f2, f3
        sat_x = sat_y = sat_z = 0
        # Roll/pitch first.
        base = [T * bt[i] for i in range(4)]
        rp = [tx * bx[i] + ty * by[i] for i in range(4)]
        rp_lo, rp_hi = min(rp), max(rp)
        span = hi_lim - lo_lim
        if rp_hi - rp_lo > span:
            sat_x = _sign(tx)
            sat_y = _sign(ty)
            s = span / (rp_hi - rp_lo)
            rp = [s * x for x in rp]
            rp_lo, rp_hi = s * rp_lo, s * rp_hi
        f = [base[i] + rp[i] for i in range(4)]
        top = max(f) - hi_lim
        if top > 0:                      # lower the collective to keep attitude authority
            f = [x - top for x in f]
        low = lo_lim - min(f)
        if low > 0:                      # only when the collective itself is below the minimum
            f = [x + low for x in f]
        # Yaw with what is left.
        yz = [tz * bz[i] for i in range(4)]
        k = 1.0
        for i in range(4):
            if yz[i] > 0:
                k = min(k, max(hi_lim - f[i], 0.0) / yz[i])
            elif yz[i] < 0:
                k = min(k, max(f[i] - lo_lim, 0.0) / -yz[i])
        if k < 1.0:
            sat_z = _sign(tz)
        self.saturation = (sat_x, sat_y, sat_z)
        return tuple(min(max(f[i] + k * yz[i], lo_lim), hi_lim) for i in range(4))


def mix_saturated(mixer: Mixer, T: np.ndarray, tx: np.ndarray, ty: np.ndarray,
                  tz: np.ndarray) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """:meth:`Mixer.mix`'s desaturating branch for many drones at once (the vector simulator's
    saturated drones), the same operations in the same order element by element, so each drone's
    rotor thrusts are bit-identical to its own scalar mix. Returns the four thrust arrays and the
    ``(3, m)`` saturation flags."""
    bt, bx, by, bz = mixer._bt, mixer._bx, mixer._by, mixer._bz
    lo_lim, hi_lim = mixer.f_min, mixer.f_max
    base = [T * bt[i] for i in range(4)]
    rp = [tx * bx[i] + ty * by[i] for i in range(4)]
    rp_lo = np.minimum(np.minimum(rp[0], rp[1]), np.minimum(rp[2], rp[3]))
    rp_hi = np.maximum(np.maximum(rp[0], rp[1]), np.maximum(rp[2], rp[3]))
    span = hi_lim - lo_lim
    wide = rp_hi - rp_lo > span
    sat = np.zeros((3, len(T)), dtype=np.int64)
    if wide.any():
        scale = np.where(wide, span / np.where(wide, rp_hi - rp_lo, 1.0), 1.0)
        rp = [np.where(wide, scale * x, x) for x in rp]
        sat[0] = np.where(wide, np.sign(tx), 0)
        sat[1] = np.where(wide, np.sign(ty), 0)
    f = [base[i] + rp[i] for i in range(4)]
    top = np.maximum(np.maximum(f[0], f[1]), np.maximum(f[2], f[3])) - hi_lim
    f = [np.where(top > 0, x - top, x) for x in f]
    low = lo_lim - np.minimum(np.minimum(f[0], f[1]), np.minimum(f[2], f[3]))
    f = [np.where(low > 0, x + low, x) for x in f]
    yz = [tz * bz[i] for i in range(4)]
    k = np.ones(len(T))
    for i in range(4):
        pos, neg = yz[i] > 0, yz[i] < 0
        safe = np.where(pos | neg, yz[i], 1.0)
        k = np.where(pos, np.minimum(k, np.maximum(hi_lim - f[i], 0.0) / safe), k)
        k = np.where(neg, np.minimum(k, np.maximum(f[i] - lo_lim, 0.0) / -safe), k)
    sat[2] = np.where(k < 1.0, np.sign(tz), 0)
    out = tuple(np.minimum(np.maximum(f[i] + k * yz[i], lo_lim), hi_lim) for i in range(4))
    return out, sat


class RateController:
    """Discrete PID on body rates at a fixed step ``dt`` producing body torques [N m].

    Works on plain floats: it runs at several hundred Hz inside the simulator, where NumPy's
    per-call overhead on 3-vectors would dominate.
    """

    def __init__(self, gains: RateGains, inertia, dt: float) -> None:
        self.gains = gains
        self.dt = check_positive("dt", dt)
        self.inertia = tuple(float(x) for x in inertia)
        # Fold inertia into the gains once: torque = J (kp e + I - kd d).
        J = self.inertia
        self._kp = tuple(J[i] * gains.kp[i] for i in range(3))
        self._kd = tuple(J[i] * gains.kd[i] / dt for i in range(3))  # per rate difference
        self._ki_dt = tuple(gains.ki[i] * dt for i in range(3))
        self._ilim = gains.integral_limit
        self._J = J
        # First-order low-pass on the rate difference (bilinear-free exact discretisation).
        self._beta = 1.0 - math.exp(-2 * math.pi * gains.d_cutoff_hz * dt)
        self.reset()

    @property
    def kp_folded(self) -> tuple[float, float, float]:
        """Proportional gains times the inertia [N m s]: torque per rate error."""
        return self._kp

    @property
    def kd_folded(self) -> tuple[float, float, float]:
        """Derivative gains times the inertia over dt: torque per filtered rate difference."""
        return self._kd

    @property
    def ki_dt(self) -> tuple[float, float, float]:
        """Integral gains times dt: the integrator's increment per rate error."""
        return self._ki_dt

    @property
    def d_beta(self) -> float:
        """Fraction of the gap the derivative's low-pass closes per step."""
        return self._beta

    def reset(self, rates=(0.0, 0.0, 0.0)) -> None:
        """Clear the integrators and start the derivative from the given measured rates."""
        self.i = [0.0, 0.0, 0.0]             # integral term, already times ki [rad/s^2]
        self.d = [0.0, 0.0, 0.0]             # filtered rate difference per step [rad/s]
        self.prev = [float(x) for x in rates]

    def update(self, p_sp: float, q_sp: float, r_sp: float, p: float, q: float, r: float,
               saturation: tuple[int, int, int] = (0, 0, 0)) -> tuple[float, float, float]:
        """Torques for setpoint rates (p_sp, q_sp, r_sp) and measured rates (p, q, r).

        ``saturation`` is :attr:`Mixer.saturation` of the previous mix: an axis whose torque was
        cut does not integrate further in that direction (anti-windup, as in PX4).
        """
        # Unrolled over the three axes: this runs at the physics rate in pure Python.
        i, d, prev, beta = self.i, self.d, self.prev, self._beta
        sx, sy, sz = saturation
        ex, ey, ez = p_sp - p, q_sp - q, r_sp - r
        dx = d[0] + beta * ((p - prev[0]) - d[0])
        dy = d[1] + beta * ((q - prev[1]) - d[1])
        dz = d[2] + beta * ((r - prev[2]) - d[2])
        d[0], d[1], d[2] = dx, dy, dz
        prev[0], prev[1], prev[2] = p, q, r
        ix, iy, iz = i
        kix, kiy, kiz = self._ki_dt
        lx, ly, lz = self._ilim
        if not (sx and (ex > 0) == (sx > 0)):
            ix += kix * ex
            ix = lx if ix > lx else (-lx if ix < -lx else ix)
        if not (sy and (ey > 0) == (sy > 0)):
            iy += kiy * ey
            iy = ly if iy > ly else (-ly if iy < -ly else iy)
        if not (sz and (ez > 0) == (sz > 0)):
            iz += kiz * ez
            iz = lz if iz > lz else (-lz if iz < -lz else iz)
        i[0], i[1], i[2] = ix, iy, iz
        kpx, kpy, kpz = self._kp
        kdx, kdy, kdz = self._kd
        Jx, Jy, Jz = self._J
        return (kpx * ex + Jx * ix - kdx * dx,
                kpy * ey + Jy * iy - kdy * dy,
                kpz * ez + Jz * iz - kdz * dz)
