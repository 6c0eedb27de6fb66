"""Position-tracking pieces shared by the two baselines of the paper (NMPC and PAMPC).

Both baselines track a *trajectory* - the stand-off waypoint p + d_ref n_xy at the inspection point's
height, moving with the point - rather than a surface as the VT-NMPC does. The RTI core
(:mod:`controllers.rti`) holds the online parameters constant over the horizon, so a moving
reference needs the time since the measurement inside the model: the tracking OCPs use the shared
quadrotor model augmented by a *clock* state tau (tau_0 = 0, tau_{k+1} = tau_k + dt), and the
reference at stage k is

    p_ref(tau) = p_wp + v_pt tau,        v_ref = v_pt      (world frame)

which is exactly the trajectory the authors' ACADO baselines received stage by stage. Without it the
3 s PAMPC horizon would pull the drone back to a waypoint that the point has long left (about 1 m
of lag at 0.7 m/s). The clock adds one state whose dynamics are known exactly; its rows in the QP
are trivial.

Residuals (all zero at the reference, all invariant under q -> -q, all smooth):

=================  =================================================  =========================
residual           definition                                         why this form
=================  =================================================  =========================
position (3)       p - p_ref(tau)                                     world frame
velocity (3)       R(q) v_B - v_pt                                    world frame: the reference
                                                                      moves in the world, and
                                                                      R is quadratic in q
tilt (2)           (q_x, q_y)                                         zero iff level (any yaw);
                                                                      reference 0 so the sign of
                                                                      q cancels in the square
heading (2)        (R e_x)_xy - (cos psi_ref, sin psi_ref)            sign-safe yaw error, see
                                                                      below
inputs (4)         [p, q, r, T] - [0, 0, 0, m g]                      hover thrust of the one
                                                                      parameter set
=================  =================================================  =========================

Yaw. The authors tracked a quaternion built from a precomputed yaw; their yaw references jumped by
multiples of 360 deg, which flips the quaternion's sign and turns a least-squares quaternion cost
into a large spurious error (docs/controllers.md, "The paper, the authors' code and this
implementation"). Here the yaw reference enters only through
(cos psi_ref, sin psi_ref) and the attitude only through the rotation matrix R(q), so a 360 deg wrap
or a quaternion sign flip changes nothing. For a level drone with yaw error e the residual's squared
norm is 2 - 2 cos e ~ e^2, against 2 - 2 cos(e/2) ~ e^2 / 4 for the quaternion components
(q_z, q_w) the authors weighted: a heading weight of w_qz / 4 has the same curvature at zero error.

The policy machinery (solver, reset, weights, normal fallback, quaternion sign alignment,
preparation/feedback) is :class:`~controllers.rti_policy.RTIPolicy`'s; this module adds only the
clock-augmented state and the stand-off reference as parameters.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import NU, NX, QuadrotorModel, quat_to_rotmat
from wt_inspect_env.physics.quadrotor import QuadrotorParams
from wt_inspect_env.task.geometry import facing_yaw, standoff_position
from wt_inspect_env.util.validation import check_array, check_finite

from .rti import OCP
from .rti_policy import MPCConfig, RTIPolicy, config_ocp

NX_AUG = NX + 1          # model state + clock
CLOCK = NX               # index of the clock state
N_TRACKING_PARAMS = 8    # [p_wp (3), v_pt (3), cos psi_ref, sin psi_ref]


# ------------------------------------------------------------------------------------------------
# symbolic pieces
# ------------------------------------------------------------------------------------------------

def augmented_dynamics(name: str, params: QuadrotorParams, dt: float, rk4_steps: int,
                       n_params: int) -> ca.Function:
    """F(x_aug, u, p) -> x_aug_next: RK4 of the shared model plus the clock tau += dt."""
    model = QuadrotorModel(params)
    xa = ca.SX.sym("x", NX_AUG)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", n_params)
    xn = model.rk4_expr(xa[:NX], u, dt, steps=rk4_steps)
    return ca.Function(f"{name}_F", [xa, u, p], [ca.vertcat(xn, xa[CLOCK] + dt)],
                       ["x", "u", "p"], ["x_next"])


def tracking_terms(xa, p) -> dict[str, Any]:
    """The residual blocks of the module docstring for an augmented state and parameters
    ``p[:8] = [p_wp, v_pt, cos psi_ref, sin psi_ref]`` (symbolic)."""
    pos, vel_b, q, tau = xa[0:3], xa[3:6], xa[6:10], xa[CLOCK]
    R = quat_to_rotmat(q)
    p_ref = p[0:3] + p[3:6] * tau
    return {
        "position": pos - p_ref,
        "velocity": R @ vel_b - p[3:6],
        "tilt": q[0:2],
        "heading": ca.vertcat(R[0, 0] - p[6], R[1, 0] - p[7]),
        "rotation": R,
    }


def tracking_ocp(name: str, config: MPCConfig, n_params: int,
                 extra_residual: Callable[[Any, Any], Any] | None = None) -> OCP:
    """The tracking OCP of a baseline: the clock-augmented dynamics, the stage residual
    [position, velocity, tilt, heading, extra, inputs - hover] and the same without the inputs at
    the terminal stage; ``extra_residual(x_aug, p)`` is a baseline's own block (PAMPC's image
    coordinates)."""
    x = ca.SX.sym("x", NX_AUG)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", n_params)
    t = tracking_terms(x, p)
    blocks = [t["position"], t["velocity"], t["tilt"], t["heading"]]
    if extra_residual is not None:
        blocks.append(extra_residual(x, p))
    state_res = ca.vertcat(*blocks)
    stage = ca.Function(f"{name}_r", [x, u, p], [ca.vertcat(state_res, u - ca.DM(config.hover_input))],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function(f"{name}_rN", [x, p], [state_res], ["x", "p"], ["rN"])
    dynamics = augmented_dynamics(name, config.params, config.dt, config.rk4_steps, n_params)
    return config_ocp(name, config, dynamics, stage, terminal)


# ------------------------------------------------------------------------------------------------
# references
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TrackingReference:
    """A waypoint moving at constant world velocity and a yaw to hold (radians, any winding)."""

    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    yaw: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", tuple(check_array("reference position",
                                                               self.position, (3,))))
        object.__setattr__(self, "velocity", tuple(check_array("reference velocity",
                                                               self.velocity, (3,))))
        object.__setattr__(self, "yaw", check_finite("reference yaw", self.yaw))

    def parameters(self) -> np.ndarray:
        """[p_wp, v_pt, cos yaw, sin yaw]: the yaw enters only through its direction."""
        return np.array([*self.position, *self.velocity, math.cos(self.yaw), math.sin(self.yaw)])


def standoff_reference(point: np.ndarray, normal_xy: np.ndarray, point_velocity: np.ndarray,
                       d_ref: float) -> TrackingReference:
    """The paper's baseline reference: the stand-off pose (:mod:`wt_inspect_env.task.geometry`), the
    point's velocity, and the yaw that faces the surface."""
    return TrackingReference(tuple(standoff_position(point, normal_xy, d_ref)),
                             tuple(np.asarray(point_velocity, dtype=float)), facing_yaw(normal_xy))


class TrackingMPCPolicy(RTIPolicy):
    """What the tracking baselines add to :class:`~controllers.rti_policy.RTIPolicy`: the clock
    state (tau_0 = 0 at each measurement) and the moving stand-off reference as parameters."""

    def model_state(self, state: np.ndarray) -> np.ndarray:
        """[x, tau = 0]."""
        return np.append(state, 0.0)

    def reference(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                  normal_xy: np.ndarray) -> TrackingReference:
        """The stand-off reference of a checked observation."""
        return standoff_reference(obs["point"], normal_xy, obs["point_velocity"], self.config.d_ref)

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                   normal_xy: np.ndarray) -> np.ndarray:
        """The OCP's online parameters: the tracking reference for this observation."""
        return self.reference(obs, state, normal_xy).parameters()
