"""The simulators' options and the per-sub-step constants derived from them: one home below both.

:class:`SimConfig` is what :class:`~wt_inspect_env.world.sim.QuadrotorSim`, the batched simulator and
the compiled :class:`~wt_inspect_env.physics.flight_core.FlightCore` are configured with, and
:class:`SubstepConstants` the numbers each sub-step integrates with. They live apart from the
simulators (which import PyBullet and the integrator) so that the flight core, which the
integrator drives, can name its configuration's type without importing the simulator back.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..util.validation import check_field_types, check_positive
from .quadrotor import AIR_DENSITY, QuadrotorParams
from .rate_control import Mixer, RateGains

INTEGRATORS = ("compiled", "bullet")   # SimConfig.integrator: this core (+ PyBullet near contacts), or PyBullet alone


@dataclass(frozen=True)
class SimConfig:
    """Simulator options.

    ctrl_hz: command rate [Hz]; physics_hz: physics and rate-loop rate [Hz], a multiple of ctrl_hz.
    motor_lag / drag / rate_loop / ground switch those effects (the model-agreement test turns the
    first three off). ``rate_gains`` default to :meth:`RateGains.for_params` of the airframe.
    ``ground_height``: z of the ground plane [m]. ``integrator``: ``"compiled"`` integrates free
    flight with the compiled flight core and hands drones that may touch something to PyBullet;
    ``"bullet"`` lets PyBullet integrate every sub-step (the reference; see
    :mod:`~wt_inspect_env.world.integration`). ``per_rotor_forces`` applies the four rotor forces at
    the rotor positions instead of their resultant wherever PyBullet integrates.
    """

    ctrl_hz: float = 100.0
    physics_hz: float = 400.0
    motor_lag: bool = True
    drag: bool = True
    rate_loop: bool = True
    ground: bool = True
    ground_height: float = 0.0
    per_rotor_forces: bool = False
    rate_gains: RateGains | None = None
    integrator: str = "compiled"

    def __post_init__(self) -> None:
        check_field_types(self, "sim ")
        check_positive("ctrl_hz", self.ctrl_hz)
        check_positive("physics_hz", self.physics_hz)
        ratio = self.physics_hz / self.ctrl_hz
        if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"physics_hz must be a positive multiple of ctrl_hz, got "
                             f"physics_hz={self.physics_hz!r}, ctrl_hz={self.ctrl_hz!r}")
        for name in ("motor_lag", "drag", "rate_loop", "ground", "per_rotor_forces"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        if not math.isfinite(self.ground_height):
            raise ValueError(f"ground_height must be finite, got {self.ground_height!r}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {self.integrator!r}")
        if self.rate_gains is not None and not isinstance(self.rate_gains, RateGains):
            raise ValueError(f"rate_gains must be a RateGains, got {self.rate_gains!r}")

    @property
    def substeps(self) -> int:
        """Physics sub-steps per control step."""
        return int(round(self.physics_hz / self.ctrl_hz))


@dataclass(frozen=True)
class SubstepConstants:
    """Per-sub-step constants of the motor lag, torque rows of the mixer and drag, shared by
    :class:`QuadrotorSim` and the batched simulator (one home, so both integrate the same numbers).

    First-order motor lag, exact for a command held over a sub-step: the rotor state moves by a
    fraction ``alpha`` of the gap, and the thrust *averaged over the sub-step* (what the force
    should be) by a fraction ``beta`` (~ alpha / 2), which keeps the impulse right to O(dt^2).
    Drag in body axes is ``-(lin + quad |v_rel|) v_rel`` per axis.
    """

    alpha: float
    beta: float
    A_tau: tuple[tuple[float, ...], ...]
    lin_drag: tuple[float, float, float]
    quad_drag: tuple[float, float, float]
    has_drag: bool

    @classmethod
    def of(cls, params: QuadrotorParams, config: SimConfig, mixer: Mixer) -> "SubstepConstants":
        """The constants of an airframe, simulator configuration and mixer."""
        tau = params.motor_time_constant
        if config.motor_lag and tau > 0:
            r = (1.0 / config.physics_hz) / tau
            alpha = 1.0 - math.exp(-r)
            beta = 1.0 - alpha / r
        else:
            alpha = beta = 1.0
        lin = tuple(float(x) for x in params.rotor_drag) if config.drag else (0.0,) * 3
        quad = tuple(0.5 * AIR_DENSITY * float(x) for x in params.body_drag_area) if config.drag else (0.0,) * 3
        return cls(alpha, beta, tuple(tuple(float(x) for x in mixer.A[row]) for row in (1, 2, 3)), lin, quad,
                   bool(config.drag and (any(lin) or any(quad))))
