"""Collective thrust in newtons <-> PX4's normalised thrust, through the airframe's thrust curve.

Why: every policy here commands a collective thrust in newtons (``[p, q, r, T]``, the paper's
input), while PX4's SET_ATTITUDE_TARGET takes a normalised thrust in [0, 1]. PX4 treats the
normalised set-point as linear in force and turns it into a motor command ``u`` by inverting its
thrust model ``THR_MDL_FAC``: ``f / f_max = (1 - k) u + k u^2``. The vehicle's motors follow their
own curve (the preset's :attr:`~wt_inspect_env.physics.quadrotor.QuadrotorParams.thrust_curve`). So the set-point
that produces a force ``f`` per rotor is ``n = model_px4(model_true^-1(f / f_max))`` - ``n = f / f_max``
exactly when PX4's ``THR_MDL_FAC`` matches the motors.

The check against PX4's own number: the normalised thrust this map gives for the preset's weight
must match the hover thrust PX4 reports (``MPC_THR_HOVER``, which its hover-thrust estimator
learns in flight). A mismatch means the preset's mass, rotor thrust or curve is not this vehicle,
and the policy's thrust commands would be off by the same factor: the runner refuses to fly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from wt_inspect_env.physics.quadrotor import QuadrotorParams
from wt_inspect_env.util.validation import check_finite, check_positive, check_range


def curve(k: float, u: float) -> float:
    """Thrust fraction f / f_max of motor command ``u`` in [0, 1] for model factor ``k``."""
    return (1.0 - k) * u + k * u * u


def inverse_curve(k: float, x: float) -> float:
    """Motor command ``u`` in [0, 1] giving thrust fraction ``x`` in [0, 1] (the model's inverse)."""
    x = min(max(x, 0.0), 1.0)
    if k < 1e-9:
        return x
    b = 1.0 - k
    return (-b + math.sqrt(b * b + 4.0 * k * x)) / (2.0 * k)


@dataclass(frozen=True)
class ThrustMap:
    """Newtons <-> PX4 normalised collective thrust for one airframe (see the module docstring).

    ``rotor_max`` [N] per rotor, ``n_rotors``, ``motor_curve`` = the motors' true model factor (the
    preset's ``thrust_curve``), ``px4_curve`` = PX4's ``THR_MDL_FAC`` (read from the vehicle;
    defaults to the motors' own).
    """

    rotor_max: float
    n_rotors: int = 4
    motor_curve: float = 0.0
    px4_curve: float | None = None

    def __post_init__(self) -> None:
        check_positive("rotor_max", self.rotor_max)
        check_range("thrust_curve", self.motor_curve, 0.0, 1.0)
        if self.px4_curve is not None:
            check_range("THR_MDL_FAC", self.px4_curve, 0.0, 1.0)

    @classmethod
    def for_params(cls, params: QuadrotorParams, px4_curve: float | None = None) -> "ThrustMap":
        """The map of a drone's parameter set (four rotors; ``px4_curve`` if PX4's differs from the motors')."""
        return cls(float(params.max_rotor_thrust), 4, float(params.thrust_curve), px4_curve)

    @property
    def _k_px4(self) -> float:
        return self.motor_curve if self.px4_curve is None else self.px4_curve

    @property
    def max_total(self) -> float:
        """Largest collective thrust the rotors give [N]."""
        return self.rotor_max * self.n_rotors

    def to_normalised(self, thrust_n: float) -> float:
        """Normalised set-point in [0, 1] for a collective thrust [N] (clipped to what the rotors give)."""
        t = check_finite("thrust", thrust_n)
        u = inverse_curve(self.motor_curve, t / self.max_total)
        return curve(self._k_px4, u)

    def to_newtons(self, normalised: float) -> float:
        """Collective thrust [N] that a normalised set-point produces on the vehicle."""
        n = min(max(check_finite("normalised thrust", normalised), 0.0), 1.0)
        return self.max_total * curve(self.motor_curve, inverse_curve(self._k_px4, n))

    def motor_thrust(self, u: float) -> float:
        """Thrust [N] of one rotor at motor command ``u`` in [0, 1] (the SITL motor model)."""
        return self.rotor_max * curve(self.motor_curve, min(max(u, 0.0), 1.0))

    def check_hover(self, mass: float, px4_hover: float, tolerance: float) -> float:
        """The hover thrust this map predicts for ``mass``; ValueError naming both numbers when it
        differs from PX4's ``MPC_THR_HOVER`` by more than ``tolerance`` (absolute, normalised)."""
        predicted = self.to_normalised(check_positive("mass", mass) * 9.81)
        if abs(predicted - px4_hover) > tolerance:
            raise ValueError(
                f"MPC_THR_HOVER={px4_hover:.3f} reported by the vehicle, but the drone preset predicts "
                f"{predicted:.3f} (mass {mass} kg, {self.n_rotors} x {self.rotor_max} N rotors, thrust_curve "
                f"{self.motor_curve}, THR_MDL_FAC {self._k_px4}); differ by more than --hover-tolerance "
                f"{tolerance}: the preset does not describe this vehicle (fix the preset, or raise the tolerance)")
        return predicted
