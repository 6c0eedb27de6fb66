"""The paper's conventional NMPC baseline: least-squares trajectory tracking on the RTI core.

The reference (section "Simulations" of the paper) is the stand-off waypoint p + d_ref n_xy at the
inspection point's height, moving with the point, its velocity, the yaw that faces the surface
(along -n_xy, "precomputed from the surface normal"), level attitude, zero rates and hover thrust.
Residuals and the clock state that moves the waypoint over the horizon are in
:mod:`controllers.tracking`:

=============  ============================================  ===========================  =========
residual       definition                                    authors' weight               default
=============  ============================================  ===========================  =========
position       p - (p_wp + v_pt tau)      (world)            W_x, W_y, W_z = 40, 40, 50    same
velocity       R v_B - v_pt               (world)            W_u, W_v, W_w = 3, 3, 5       same
tilt           (q_x, q_y)                                    W_qx, W_qy = 60, 60            same
heading        (R e_x)_xy - (cos psi, sin psi)  (2 rows)     W_qz = W_qw = 30 on q - q_ref  30/4
inputs         [p, q, r, T] - [0, 0, 0, m g]                 0.5, 0.5, 0.5, 0.025          same
terminal       position, velocity, tilt, heading             W_N = 1.5 W                   same
=============  ============================================  ===========================  =========

The authors' weights are those of their rate-command quaternion NMPC
(``posaware_ratecommand_quaternion_nmpc_pc_learning``, Matrice 100 Gazebo airframe file; its
perception-like term "s" had weight 0, so it is left out). The notes list what the baseline tracked
(position, body velocity, quaternion from a reference yaw, rates, thrust) but not these numbers;
they are taken from that file. Two changes, both documented in :mod:`controllers.tracking`:

* the quaternion-from-yaw residual is replaced by the sign-safe heading residual, weighted
  w_qz / 4 = 7.5 so that it has the same curvature at zero yaw error (the authors' q_z and q_w
  weights were equal, 30);
* the velocity is tracked in the world frame (for the point's constant world velocity the norm is
  the same as the authors' body-frame error when the body reference is the point's velocity
  rotated by the current attitude, and it stays right along the horizon).

The thrust reference is the hover thrust m g of the one parameter set (the authors used a constant
that did not match their model mass). Horizon N = 30 at 0.01 s, RK4 multiple shooting, the
environment's input bounds (|p|, |q|, |r| <= 100 deg/s, 0.3 m g <= T <= 2 m g) - all as the
authors' NMPC. Online parameters: ``[p_wp (3), v_pt (3), cos psi_ref, sin psi_ref]``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import casadi as ca

from .rti import OCP
from .rti_policy import LSQWeights, MPCConfig
from .tracking import N_TRACKING_PARAMS, TrackingMPCPolicy, tracking_ocp

N_PARAMS = N_TRACKING_PARAMS
STAGE_RESIDUAL_NAMES = ("px", "py", "pz", "vx", "vy", "vz", "qx", "qy", "hx", "hy",
                        "p", "q", "r", "T")
TERMINAL_RESIDUAL_NAMES = STAGE_RESIDUAL_NAMES[:10]


@dataclass(frozen=True)
class NMPCWeights(LSQWeights):
    """Diagonal least-squares weights of the NMPC baseline (defaults: the authors' file, see the
    module docstring). ``heading`` weighs both rows of the heading residual. Weights at the paper's
    stand-off and drone, scaled for the instance's (:meth:`~controllers.rti_policy.LSQWeights.scaled`)."""

    position: tuple[float, ...] = (40.0, 40.0, 50.0)
    velocity: tuple[float, ...] = (3.0, 3.0, 5.0)
    tilt: tuple[float, ...] = (60.0, 60.0)
    heading: float = 7.5
    inputs: tuple[float, ...] = (0.5, 0.5, 0.5, 0.025)

    TERMINAL: ClassVar = (("position", 3), ("velocity", 3), ("tilt", 2), ("heading", 2))
    STAGE: ClassVar = TERMINAL + (("inputs", 4),)
    UNITS: ClassVar = {"position": "length", "velocity": "speed", "tilt": "1", "heading": "1",
                       "inputs": ("rate", "rate", "rate", "thrust")}

    @classmethod
    def authors(cls) -> "NMPCWeights":
        """The authors' weights (the defaults)."""
        return cls()


WEIGHT_SETS: dict[str, NMPCWeights] = {"authors": NMPCWeights.authors()}


@dataclass(frozen=True)
class NMPCConfig(MPCConfig):
    """Everything that defines an NMPC instance (the common fields: :class:`MPCConfig`)."""

    WEIGHTS: ClassVar[type] = NMPCWeights
    WEIGHT_SETS: ClassVar[Mapping[str, Any]] = WEIGHT_SETS

    weights: NMPCWeights | str = "authors"


def residual_functions(config: NMPCConfig) -> tuple[ca.Function, ca.Function]:
    """(stage_residual(x_aug, u, p), terminal_residual(x_aug, p)), zero at the reference."""
    ocp = build_ocp(config)
    return ocp.stage_residual, ocp.terminal_residual


def build_ocp(config: NMPCConfig) -> OCP:
    """The NMPC as a generic least-squares OCP (RK4 of the shared model plus the clock state)."""
    return tracking_ocp("nmpc", config, N_PARAMS)


class NMPCPolicy(TrackingMPCPolicy):
    """The NMPC baseline as a policy (interface: :class:`~controllers.rti_policy.RTIPolicy`).
    :meth:`command_for` takes a model state and :meth:`TrackingReference.parameters` directly
    (used to check yaw wrapping)."""

    config_class = NMPCConfig

    def build_ocp(self, config: NMPCConfig) -> OCP:
        """The NMPC's OCP."""
        return build_ocp(config)
