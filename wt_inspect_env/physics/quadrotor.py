"""Quadrotor parameters: the single source of truth for the simulator, the MPC models and the
action scaling.

The authors' implementation used three different masses (3.8 kg in the MPC model, 3.5 kg in the
thrust scaling, ~2.9 kg in Gazebo); here everything reads one :class:`QuadrotorParams`.

Rotor layout is an "X" configuration in the body frame (x forward, y left, z up): rotor i sits at
angle 45 + 90 i degrees, spinning with direction ``rotor_spin[i]`` (+1 counter-clockwise seen from
above, producing a clockwise reaction torque -c_tau f on the body about +z).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..util.validation import check_choice, check_field_types, check_positive

GRAVITY = 9.81
AIR_DENSITY = 1.225


def hover_thrust(mass: float) -> float:
    """m g [N]: the collective thrust that holds ``mass`` level (the one place it is computed;
    :attr:`QuadrotorParams.weight` and the action scaling's hover command read it)."""
    return mass * GRAVITY


@dataclass(frozen=True)
class QuadrotorParams:
    """Physical parameters of an X-configuration quadrotor (SI units)."""

    name: str = "matrice100"
    mass: float = 3.6
    inertia: tuple[float, float, float] = (0.054, 0.054, 0.103)
    arm_length: float = 0.325
    max_rotor_thrust: float = 20.0
    min_rotor_thrust: float = 0.0
    torque_coeff: float = 0.016          # rotor yaw torque per newton of rotor thrust [m]
    motor_time_constant: float = 0.04    # first-order rotor-thrust lag [s]
    rotor_drag: tuple[float, float, float] = (2.9, 2.9, 0.5)  # linear drag, body axes [N/(m/s)]
    body_drag_area: tuple[float, float, float] = (0.05, 0.05, 0.10)  # C_d * A per body axis [m^2]
    rotor_spin: tuple[int, int, int, int] = (1, -1, 1, -1)
    prop_radius: float = 0.165           # 13-inch propellers; sizes the collision box [m]
    frame_height: float = 0.20           # collision box height incl. landing gear [m]
    # Rotor thrust vs motor command u in [0, 1]: f / max_rotor_thrust = (1 - k) u + k u^2, PX4's
    # THR_MDL_FAC model. Used only where a command leaves the newton world (the PX4 bridge maps
    # the policy's thrust to PX4's normalised thrust, and its SITL motors through it); 0 = linear.
    thrust_curve: float = 0.0
    # Electrical power model (used by the evaluation harness to price a flight, never by the
    # physics): per rotor P = T^(3/2) / sqrt(2 rho A) / (figure_of_merit * drive_efficiency), the
    # ideal induced power of momentum theory over the rotor disk A = pi prop_radius^2, divided by
    # the propeller's figure of merit (ideal / actual shaft power in hover) and the motor + ESC
    # efficiency (shaft / electrical power). The defaults are typical published values for small
    # multirotor propellers and drives (see each preset's source), not measurements of one airframe.
    figure_of_merit: float = 0.65
    drive_efficiency: float = 0.75
    air_density: float = AIR_DENSITY     # of the power model only; the drag model uses AIR_DENSITY
    source: str = ""

    def __post_init__(self) -> None:
        check_field_types(self, "drone ")
        check_positive("mass", self.mass)
        if len(self.inertia) != 3:
            raise ValueError(f"inertia must have 3 entries, got {self.inertia!r}")
        for i, v in enumerate(self.inertia):
            check_positive(f"inertia[{i}]", v)
        check_positive("arm_length", self.arm_length)
        check_positive("max_rotor_thrust", self.max_rotor_thrust)
        check_positive("min_rotor_thrust", self.min_rotor_thrust, allow_zero=True)
        if self.min_rotor_thrust >= self.max_rotor_thrust:
            raise ValueError(
                f"min_rotor_thrust must be below max_rotor_thrust, got {self.min_rotor_thrust!r}")
        # A negative ratio would silently flip the spin convention; spin lives in rotor_spin.
        check_positive("torque_coeff", self.torque_coeff, allow_zero=True)
        if len(self.rotor_spin) != 4 or any(s not in (1, -1) for s in self.rotor_spin):
            raise ValueError(f"rotor_spin must be 4 entries of +1/-1, got {self.rotor_spin!r}")
        if sum(self.rotor_spin) != 0:
            raise ValueError(
                f"rotor_spin must have two rotors each way (else yaw is uncontrollable at hover), "
                f"got {self.rotor_spin!r}")
        check_positive("prop_radius", self.prop_radius)
        check_positive("frame_height", self.frame_height)
        check_positive("motor_time_constant", self.motor_time_constant, allow_zero=True)
        for fname in ("figure_of_merit", "drive_efficiency"):
            if not 0.0 < check_positive(fname, getattr(self, fname)) <= 1.0:
                raise ValueError(f"{fname} must lie in (0, 1], got {getattr(self, fname)!r}")
        check_positive("air_density", self.air_density)
        if not 0.0 <= check_positive("thrust_curve", self.thrust_curve, allow_zero=True) <= 1.0:
            raise ValueError(f"thrust_curve must lie in [0, 1] (PX4's THR_MDL_FAC), got {self.thrust_curve!r}")
        for fname in ("rotor_drag", "body_drag_area"):
            vals = getattr(self, fname)
            if len(vals) != 3:
                raise ValueError(f"{fname} must have 3 entries, got {vals!r}")
            for i, v in enumerate(vals):
                check_positive(f"{fname}[{i}]", v, allow_zero=True)
        if 4 * self.max_rotor_thrust < 2.0 * hover_thrust(self.mass):
            raise ValueError(
                f"max_rotor_thrust must allow 2 m g of total thrust, got {self.max_rotor_thrust!r}")

    @property
    def drag_coefficients(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(linear ``rotor_drag`` D [N/(m/s)], quadratic 1/2 rho C_d A [N/(m/s)^2]) per body axis,
        of the drag F = -(D + k |v_rel|) v_rel (:func:`drag_force`)."""
        lin = tuple(float(x) for x in self.rotor_drag)
        quad = tuple(0.5 * AIR_DENSITY * float(x) for x in self.body_drag_area)
        return lin, quad  # type: ignore[return-value]

    @property
    def weight(self) -> float:
        """m g [N]: the hover thrust."""
        return hover_thrust(self.mass)

    @property
    def rotor_disk_area(self) -> float:
        """pi prop_radius^2 [m^2]: the disk of one rotor (the power model's A)."""
        return float(np.pi * self.prop_radius ** 2)

    @property
    def hover_power(self) -> float:
        """Electrical power [W] of the power model in hover, each rotor at m g / 4
        (:func:`electrical_power`)."""
        return float(electrical_power(self, np.full(4, self.weight / 4.0)))

    @property
    def inertia_matrix(self) -> np.ndarray:
        """The (3, 3) inertia matrix [kg m^2] (diagonal)."""
        return np.diag(self.inertia)

    @property
    def rotor_positions(self) -> np.ndarray:
        """(4, 3) rotor positions in the body frame (X configuration)."""
        ang = np.deg2rad(45.0 + 90.0 * np.arange(4))
        L = self.arm_length
        return np.stack([L * np.cos(ang), L * np.sin(ang), np.zeros(4)], axis=1)

    @property
    def mixer(self) -> np.ndarray:
        """(4, 4) matrix A with [T, tau_x, tau_y, tau_z] = A @ rotor_thrusts."""
        pos = self.rotor_positions
        spin = np.asarray(self.rotor_spin, dtype=float)
        return np.stack([
            np.ones(4),
            pos[:, 1],                       # tau_x = y_i f_i
            -pos[:, 0],                      # tau_y = -x_i f_i
            -spin * self.torque_coeff,       # reaction torque of a CCW (+1) rotor is clockwise
        ])

    @property
    def collision_half_extents(self) -> tuple[float, float, float]:
        """Half sizes of the box that encloses frame and propeller disks (collision shape)."""
        half = self.arm_length * np.sqrt(0.5) + self.prop_radius
        return (float(half), float(half), 0.5 * self.frame_height)

    def replace(self, **changes) -> "QuadrotorParams":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


PRESETS: dict[str, QuadrotorParams] = {
    "matrice100": QuadrotorParams(
        source=(
            "DJI Matrice 100 with inspection payload: mass 3.6 kg = DJI's maximum take-off weight "
            "(the paper's model used 3.8 kg); 650 mm wheelbase -> 0.325 m arm; inertia estimated "
            "from 4 x 0.2 kg motors on the arms plus a 2.8 kg 0.2x0.2x0.1 m central box; 13-inch "
            "props with 20 N peak thrust each (thrust/weight 2.3, above the paper's 2 m g bound); "
            "torque/thrust ratio 0.016 m and motor time constant 0.04 s typical of 13-inch props; "
            "linear rotor drag 2.9 N/(m/s) horizontally = the authors' Gazebo model; "
            "C_d A of 0.05 m^2 frontal, 0.1 m^2 from above (estimated); collision box from the "
            "wheelbase plus 13-inch prop disks, 0.2 m tall (estimated). Power model: rotor disk of the "
            "13-inch (0.165 m radius) props; figure of merit 0.65, within the 0.5-0.7 typical of "
            "static tests of 10-14-inch multirotor propellers (e.g. the UIUC propeller data site; FM "
            "as defined in Leishman, Principles of Helicopter Aerodynamics); motor + ESC "
            "efficiency 0.75 (about 0.8 for a brushless motor at part load times 0.95 for the ESC); "
            "sea-level air 1.225 kg/m^3. Typical values, not measured on a Matrice 100."
        ),
    ),
    "lab250": QuadrotorParams(
        name="lab250",
        mass=1.09,
        inertia=(0.0031, 0.0031, 0.0053),
        arm_length=0.125,
        max_rotor_thrust=7.0,
        torque_coeff=0.011,
        motor_time_constant=0.02,
        rotor_drag=(0.55, 0.55, 0.1),
        body_drag_area=(0.01, 0.01, 0.02),
        prop_radius=0.0635,
        frame_height=0.08,
        figure_of_merit=0.55,
        drive_efficiency=0.70,
        source=(
            "The paper's lab quadrotor: 1.09 kg, 250 mm motor-to-motor diagonal -> 0.125 m arm "
            "(paper, Experimental Setup); inertia from 4 x 0.05 kg motors on the arms plus the other "
            "0.89 kg (Jetson TX2, battery, Pixhawk, frame) as a 0.12x0.12x0.08 m box (estimated); "
            "7 N per rotor (5-inch props, thrust/weight 2.6); torque/thrust 0.011 m, motor lag "
            "0.02 s (estimated); linear drag 0.5 N/(m/s) per kg horizontally (the M100 model has "
            "0.8), C_d A 0.01 m^2 frontal, 5-inch prop disks and 0.08 m frame height for the "
            "collision box (estimated). Power model: 5-inch (0.0635 m radius) rotor disks; figure of "
            "merit 0.55 (small propellers at low Reynolds number stay below the 0.6-0.7 of larger "
            "ones); motor + ESC efficiency 0.70 (small motors at part load, estimated); sea-level air "
            "1.225 kg/m^3. Typical values, not measured on the paper's airframe."
        ),
    ),
}


def get_preset(name: str) -> QuadrotorParams:
    """The named parameter preset; ``ValueError`` listing the valid names otherwise."""
    check_choice("drone preset", name, PRESETS)
    return PRESETS[name]


def electrical_power(params: QuadrotorParams, rotor_thrusts) -> np.ndarray:
    """Electrical power [W] drawn for the given rotor thrusts [N] (shape (..., 4); the sum over
    the last axis is returned, shape (...)).

    Per rotor, momentum theory's ideal induced power in hover, ``P_i = T^(3/2) / sqrt(2 rho A)``
    (A = :attr:`QuadrotorParams.rotor_disk_area`, rho = ``air_density``), divided by the
    propeller's ``figure_of_merit`` and the motor + ESC ``drive_efficiency``. Why this model: it
    needs nothing but the thrusts the simulator already computes and three published-typical
    constants, and it prices exactly what a controller changes - how much thrust it asks for and
    how unevenly the rotors share it (P grows as T^1.5, so uneven rotors cost more than even ones
    for the same total). What it leaves out: the change of induced power with inflow in forward
    flight and climb (translational lift), avionics and payload power, and the motors' idle
    draw. Negative thrusts (never produced by the simulator) count as zero."""
    f = np.maximum(np.asarray(rotor_thrusts, dtype=float), 0.0)
    if f.shape[-1:] != (4,):
        raise ValueError(f"rotor_thrusts must have shape (..., 4), got {f.shape}")
    k = 1.0 / (np.sqrt(2.0 * params.air_density * params.rotor_disk_area)
               * params.figure_of_merit * params.drive_efficiency)
    return k * (f * np.sqrt(f)).sum(axis=-1)


def drag_force(params: QuadrotorParams, v_rel_body) -> np.ndarray:
    """Aerodynamic force in body axes for the airspeed ``v_rel_body`` = R^T (v - v_wind):
    F = -D v_rel - 1/2 rho C_d A |v_rel| v_rel, with the linear rotor drag D = ``rotor_drag`` and
    the quadratic body drag ``body_drag_area`` per body axis (:attr:`QuadrotorParams.drag_coefficients`)
    - the simulator's drag model, which evaluates the same formula inline in its physics loop."""
    v = np.asarray(v_rel_body, dtype=float)
    lin, quad = params.drag_coefficients
    return -(np.asarray(lin) + np.asarray(quad) * float(np.linalg.norm(v))) * v
