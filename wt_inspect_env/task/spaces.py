"""The environment's action scaling and observation layout, shared by the Env, MPC policies and RL
wrappers so that all of them read one definition.

Action: ``a in [-1, 1]^4`` = normalised ``[p, q, r, T]`` (the PX4-offboard command, same order as the
model input). Rates map linearly to ``[-max_rate, max_rate]`` (paper: 100 deg/s); thrust maps
linearly from ``[-1, 1]`` to ``[0.3 m g, 2 m g]`` (paper's bounds), so ``a = 0`` is *not* hover:
use :meth:`ActionScaling.to_action` on ``[0, 0, 0, m g]``.

Observation (``gymnasium.spaces.Dict``, every entry float32, fixed size whatever the rates):

=================  =====  ==========================================================
key                shape  meaning
=================  =====  ==========================================================
position           (3,)   drone position, world frame [m]
velocity_body      (3,)   drone velocity in the body frame (u, v, w) [m/s]
quaternion         (4,)   body-to-world attitude (qx, qy, qz, qw)
body_rates         (3,)   measured body rates (p, q, r) [rad/s]
point              (3,)   current inspection point on the surface, world frame [m]
normal             (3,)   outward unit normal of the surface at the point
point_velocity     (3,)   velocity of the inspection point, world frame [m/s]
coverage           (1,)   share of blade triangles seen so far, in [0, 1]
progress           (1,)   mission progress (arc length done / total), in [0, 1]
=================  =====  ==========================================================
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..physics.quadrotor import QuadrotorParams, hover_thrust
from ..util.validation import check_actions, check_array, check_field_types, check_positive

OBS_KEYS: tuple[str, ...] = (
    "position", "velocity_body", "quaternion", "body_rates",
    "point", "normal", "point_velocity", "coverage", "progress",
)
OBS_SHAPES: dict[str, tuple[int, ...]] = {
    "position": (3,), "velocity_body": (3,), "quaternion": (4,), "body_rates": (3,),
    "point": (3,), "normal": (3,), "point_velocity": (3,), "coverage": (1,), "progress": (1,),
}
#: entries an env adds on request (``structure``: EnvConfig.structure_observation) and their shapes
OPTIONAL_OBS_SHAPES: dict[str, tuple[int, ...]] = {"structure": (4,)}


@dataclass(frozen=True)
class ActionScaling:
    """Maps normalised actions to (p, q, r, T) commands and back (the paper's input bounds)."""

    mass: float
    max_rate: float = np.deg2rad(100.0)
    min_thrust_factor: float = 0.3
    max_thrust_factor: float = 2.0

    def __post_init__(self) -> None:
        check_field_types(self, "action scaling ")
        check_positive("mass", self.mass)
        check_positive("max_rate", self.max_rate)
        check_positive("min_thrust_factor", self.min_thrust_factor, allow_zero=True)
        if self.max_thrust_factor <= max(1.0, self.min_thrust_factor):
            raise ValueError(f"max_thrust_factor must exceed 1 and min_thrust_factor, "
                             f"got {self.max_thrust_factor!r}")

    @classmethod
    def from_params(cls, params: QuadrotorParams, **kw) -> "ActionScaling":
        """The scaling of an airframe (its mass; other fields as keywords)."""
        return cls(mass=params.mass, **kw)

    @property
    def hover_thrust(self) -> float:
        """m g [N] of the scaled airframe."""
        return hover_thrust(self.mass)

    @property
    def thrust_bounds(self) -> tuple[float, float]:
        """(lowest, highest) collective thrust [N] an action can command."""
        w = self.hover_thrust
        return self.min_thrust_factor * w, self.max_thrust_factor * w

    @property
    def lower(self) -> np.ndarray:
        """Lower bounds of the physical command [p, q, r, T]."""
        return np.array([-self.max_rate] * 3 + [self.thrust_bounds[0]])

    @property
    def upper(self) -> np.ndarray:
        """Upper bounds of the physical command [p, q, r, T]."""
        return np.array([self.max_rate] * 3 + [self.thrust_bounds[1]])

    def to_command(self, action) -> np.ndarray:
        """Normalised action in [-1, 1]^4 -> physical command [p, q, r, T]. Rejects NaN/shape;
        values outside [-1, 1] are an error, not silently clipped."""
        a = check_actions(action)
        lo, hi = self.lower, self.upper
        return lo + (np.clip(a, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo)

    def to_action(self, command) -> np.ndarray:
        """Physical command [p, q, r, T] -> normalised action, clipped to [-1, 1] (commands beyond
        the bounds saturate, as the MPCs' constraints already keep them inside)."""
        c = check_array("command", command, (4,))
        lo, hi = self.lower, self.upper
        return np.clip(2.0 * (c - lo) / (hi - lo) - 1.0, -1.0, 1.0).astype(np.float32)

    def hover_action(self) -> np.ndarray:
        """The normalised action that commands hover (no rates, m g)."""
        return self.to_action([0.0, 0.0, 0.0, self.hover_thrust])
