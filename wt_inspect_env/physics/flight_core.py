"""The drones' flight state in arrays and its compiled integration: one home for the dynamics.

:class:`FlightCore` holds ``n`` quadrotors - pose, world velocities, rotor thrusts, the PX4-like
rate loop's integrators and filters, the mixer's saturation flags, and each drone's plant (mass,
inertia, motor lag, drag, thrust factor) - as NumPy arrays, and advances any subset of them
through all physics sub-steps of a control step in one call into ``flight_core.c``:

* the controller side (rate PID with anti-windup, desaturating mixer, first-order motor lag,
  relative-airspeed drag) is the same arithmetic as :class:`~wt_inspect_env.physics.rate_control.RateController`,
  :class:`~wt_inspect_env.physics.rate_control.Mixer` and :class:`~wt_inspect_env.physics.sim_config.SubstepConstants`,
  which remain the readable reference (tests compare them step by step);
* the rigid body is integrated with the step Bullet applies to a free multibody base (semi-implicit
  Euler, gyroscopic term, exponential-map quaternion update, Bullet's velocity clamp), so a
  drone integrated here and one integrated by PyBullet follow the same trajectory to rounding.

The simulators use it for every drone that cannot touch anything during the next control step and
hand the others - near the ground or the turbine - to PyBullet, which resolves contacts; for those
:meth:`FlightCore.wrench` runs the controller side alone, one sub-step at a time.

Why C and not the alternatives: the kernel is ~150 lines of scalar arithmetic per drone and
sub-step, which NumPy can only batch across drones (per-operation dispatch costs dominate at
small N, the single environment's case) and which a JIT such as numba would add a large
dependency and a compile at every new process for. It is compiled once per machine with the C
compiler the MPCs' code generation already needs (``-O2 -ffp-contract=off``, no fast-math, so the
floating-point operations are the ones written) and cached in the guarded library cache
(:mod:`~wt_inspect_env.util.native_cache`). Without a compiler the simulators fall back to PyBullet's
integrator with a warning (the same physics, slower).
"""
from __future__ import annotations

import ctypes
import os
import threading
from importlib import resources
from typing import Any

import numpy as np

from ..util.native_cache import load_c_source
from .quadrotor import GRAVITY, QuadrotorParams
from .rate_control import Mixer, RateController, RateGains
from .sim_config import SimConfig, SubstepConstants

_SOURCE_NAME = "flight_core.c"
_ABI = 2
_LOCK = threading.Lock()
MAX_COORDINATE_VELOCITY = 100.0    # Bullet clamps every velocity component to this [m/s, rad/s]

_D = ctypes.c_double
_P = ctypes.c_void_p


class _World(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int64), ("nsub", ctypes.c_int64), ("rate_loop", ctypes.c_int64),
                ("dt", _D), ("gravity", _D),
                ("kp", _D * 3), ("kd", _D * 3), ("ki_dt", _D * 3), ("J", _D * 3), ("ilim", _D * 3),
                ("d_beta", _D),
                ("bt", _D * 4), ("bx", _D * 4), ("by", _D * 4), ("bz", _D * 4), ("f_lo", _D), ("f_hi", _D),
                ("mass", _P), ("inertia", _P), ("alpha", _P), ("beta", _P), ("a_tau", _P),
                ("lin_drag", _P), ("quad_drag", _P), ("thrust_scale", _P),
                ("pos", _P), ("vel", _P), ("omega", _P), ("quat", _P), ("rotor", _P), ("thrust", _P),
                ("i_term", _P), ("d_term", _P), ("prev", _P), ("sat", _P)]


def _source() -> str:
    return resources.files(__package__).joinpath(_SOURCE_NAME).read_text()


def load_library(cache_dir: str | os.PathLike | None = None) -> ctypes.CDLL:
    """The compiled flight core (built on first use per source, compiler and flags, then loaded
    from the guarded cache). RuntimeError naming the cause when it cannot be built."""
    with _LOCK:
        lib = load_c_source(_source(), "wt_flight_core", "flight core", cache_dir)
        if getattr(lib, "_wt_ready", False):
            return lib
        if lib.wt_abi_version() != _ABI:   # pragma: no cover - a source/wrapper mismatch
            raise RuntimeError("flight core ABI mismatch")
        i64p = ctypes.c_void_p
        lib.wt_step.argtypes = [ctypes.c_void_p, ctypes.c_int64, i64p, _P, _P]
        lib.wt_step.restype = None
        lib.wt_wrench.argtypes = [ctypes.c_void_p, ctypes.c_int64, i64p, _P, _P, _P, _P]
        lib.wt_wrench.restype = None
        lib.wt_screen.argtypes = [ctypes.c_void_p, _P, _P, _D, _D, ctypes.c_int64, _D, _D, _P, _P, _P]
        lib.wt_screen.restype = ctypes.c_int64
        lib._wt_ready = True
        return lib


class FlightCore:
    """``n`` drones' flight state and plants in arrays, stepped by the compiled kernel.

    ``params`` is the nominal airframe (the controller side: rate gains, the rate loop's inertia,
    the mixer) and every drone's plant until :meth:`set_plant`; ``config`` a
    :class:`~wt_inspect_env.physics.sim_config.SimConfig`. Arrays are allocated once and written in place, so
    views of them stay valid: ``pos``, ``vel``, ``omega`` (n, 3; world frame), ``quat`` (n, 4;
    x, y, z, w), ``rotor`` (n, 4; rotor thrusts before the plant's thrust factor).
    """

    def __init__(self, params: QuadrotorParams, config: SimConfig, n: int,
                 cache_dir: str | os.PathLike | None = None) -> None:
        self.params, self.config, self.n = params, config, int(n)
        self._lib = load_library(cache_dir)
        n = self.n
        physics_dt = 1.0 / config.physics_hz
        gains = config.rate_gains or RateGains.for_params(params)
        ref = RateController(gains, params.inertia, physics_dt)
        self.mixer = Mixer(params)
        z3 = lambda: np.zeros((n, 3))   # noqa: E731
        self.mass, self.inertia = np.zeros(n), z3()
        self.alpha, self.beta, self.thrust_scale = np.zeros(n), np.zeros(n), np.ones(n)
        self.a_tau, self.lin_drag, self.quad_drag = np.zeros((n, 3, 4)), z3(), z3()
        self.pos, self.vel, self.omega = z3(), z3(), z3()
        self.quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
        self.rotor, self.thrust = np.zeros((n, 4)), np.zeros(n)
        self.i_term, self.d_term, self.prev = z3(), z3(), z3()
        self.sat = np.zeros((n, 3), dtype=np.int64)
        self.plants: list[QuadrotorParams] = [params] * n
        w = self._world = _World()
        w.n, w.nsub, w.rate_loop = n, config.substeps, int(bool(config.rate_loop))
        w.dt, w.gravity = physics_dt, GRAVITY
        w.kp[:], w.kd[:], w.ki_dt[:], w.J[:] = ref.kp_folded, ref.kd_folded, ref.ki_dt, ref.inertia
        w.ilim[:] = tuple(float(x) for x in gains.integral_limit)
        w.d_beta = ref.d_beta
        B = self.mixer.B
        w.bt[:], w.bx[:], w.by[:], w.bz[:] = (tuple(float(x) for x in B[:, k]) for k in range(4))
        w.f_lo, w.f_hi = self.mixer.f_min, self.mixer.f_max
        for name in ("mass", "inertia", "alpha", "beta", "a_tau", "lin_drag", "quad_drag", "thrust_scale",
                     "pos", "vel", "omega", "quat", "rotor", "thrust", "i_term", "d_term", "prev", "sat"):
            setattr(w, name, getattr(self, name).ctypes.data)
        self._wptr = ctypes.addressof(w)
        # Commands and winds of the next step (n, 4) / (n, 3), written by the caller in place.
        self.commands, self.winds = np.zeros((n, 4)), np.zeros((n, 3))
        self._idx = np.arange(n, dtype=np.int64)       # scratch list of drone indices
        self._all = np.arange(n, dtype=np.int64)
        self._force, self._torque = np.zeros((n, 3)), np.zeros((n, 3))
        self._ptr = {name: getattr(self, name).ctypes.data
                     for name in ("commands", "winds", "_idx", "_all", "_force", "_torque")}
        for i in range(n):
            self.set_plant(i, params, 1.0)

    # ------------------------------------------------------------------ plants and state
    def set_plant(self, i: int, plant: QuadrotorParams, thrust_scale: float = 1.0) -> None:
        """Drone ``i``'s physics follow ``plant`` (validated by the caller) with rotor thrusts
        times ``thrust_scale``; the controller side keeps the nominal ``params``."""
        mixer = self.mixer if plant is self.params else Mixer(plant)
        k = SubstepConstants.of(plant, self.config, mixer)   # the per-sub-step constants' one home
        self.mass[i] = plant.mass
        self.inertia[i] = plant.inertia
        self.alpha[i], self.beta[i] = k.alpha, k.beta
        self.a_tau[i] = k.A_tau
        self.lin_drag[i], self.quad_drag[i] = k.lin_drag, k.quad_drag
        self.thrust_scale[i] = float(thrust_scale)
        self.plants[i] = plant

    def reset(self, i: int, pos: Any, quat: Any, vel: Any, omega: Any, body_rates: Any) -> None:
        """Place drone ``i`` (world pose and velocities) with the rate loop at rest at
        ``body_rates`` and the rotors at the plant's hover thrust."""
        self.set_state(i, pos, quat, vel, omega)
        self.i_term[i] = self.d_term[i] = 0.0
        self.prev[i] = body_rates
        self.sat[i] = 0
        hover = self.plants[i].weight / self.thrust_scale[i]
        self.rotor[i] = hover / 4.0
        self.thrust[i] = hover

    def set_state(self, i: int, pos: Any, quat: Any, vel: Any, omega: Any) -> None:
        """Overwrite drone ``i``'s pose and world velocities (e.g. read back from PyBullet)."""
        self.pos[i], self.quat[i], self.vel[i], self.omega[i] = pos, quat, vel, omega

    # ------------------------------------------------------------------ stepping
    def step(self, idx: np.ndarray | None = None) -> None:
        """Advance drones ``idx`` (default all) through one control step holding their
        :attr:`commands` in their :attr:`winds`."""
        ptr = self._ptr
        if idx is None:
            self._lib.wt_step(self._wptr, self.n, ptr["_all"], ptr["commands"], ptr["winds"])
        elif len(idx):
            self._idx[:len(idx)] = idx
            self._lib.wt_step(self._wptr, len(idx), ptr["_idx"], ptr["commands"], ptr["winds"])

    def wrench(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One sub-step of the controller side for drones ``idx``: (force, torque) (len(idx), 3)
        in body axes to apply over the sub-step (views, overwritten by the next call). In the
        imposed-rate mode (``rate_loop=False``) it also sets their world angular velocity."""
        m = len(idx)
        self._idx[:m] = idx
        ptr = self._ptr
        self._lib.wt_wrench(self._wptr, m, ptr["_idx"], ptr["commands"], ptr["winds"], ptr["_force"], ptr["_torque"])
        return self._force[:m], self._torque[:m]

    def screen(self, control_dt: float, f_max: float, ground_z: float | None, need0: float,
               free: np.ndarray, reach: np.ndarray, code: np.ndarray) -> int:
        """The contact screen of :mod:`~wt_inspect_env.world.integration` over all drones (see
        ``wt_screen`` in ``flight_core.c``); ``free``, ``reach`` (n,) float64 and ``code`` (n,)
        int8 are written in place. Returns how many drones need attention."""
        ptr = self._ptr
        return int(self._lib.wt_screen(self._wptr, ptr["commands"], ptr["winds"], control_dt, f_max,
                                       ground_z is not None, 0.0 if ground_z is None else ground_z, need0,
                                       free.ctypes.data, reach.ctypes.data, code.ctypes.data))
