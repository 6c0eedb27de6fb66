"""The paper's visual-tracking NMPC (VT-NMPC) on the generic RTI core.

Residuals (section "Proposed VT-NMPC Formulation" of the paper, with the signs and definitions the
authors' code uses where the printed formulas are ambiguous; docs/controllers.md, "The paper, the
authors' code and this implementation"), with a = p - x_drone, a_xy its horizontal part, n = (n_x, n_y, 0) the
surface's outward unit normal and every norm guarded as sqrt(s^2 + eps) so that Gauss-Newton data
never turn NaN:

=============  ==============================================  ==========  =====================
residual       definition                                      reference   paper weight (default)
=============  ==============================================  ==========  =====================
heading h      (R e_x) . a_xy / ||a_xy||                        1           w_h = 80
distance d     ||a_xy||  (horizontal, not 3-D)                  d_ref = 7   w_d = 30
ROI r          a_xy . n  (outward normals: drone at -d_ref)     -d_ref      w_r = 25
orthogonal o   || a - (a . n) n ||  (includes the height gap)   0           w_o = 60
x*             [u, v, w, qx, qy]                                [v_pt_B, 0, 0]  diag(0.3, 0.3, 1, 80, 80)
u              [p, q, r, T]                                     [0, 0, 0, m g]  diag(1, 1, 0.25, 0.03)
terminal       x*_N                                             as x*       1.5 W_x*
=============  ==============================================  ==========  =====================

v_pt_B is the inspection point's velocity expressed in the body frame of the measured attitude
(once per solve, as in the paper). The heading is normalised by ||a_xy|| (as the authors' code does; the paper's
formula omits it but its reference 1 needs it) and by default uses the full attitude, as printed,
rather than the authors' yaw-only approximation (``heading_model="camera"`` selects the latter,
which is the heading of the environment's gimbal camera). The thrust reference is the hover thrust
m g of the one parameter set
(the authors' 44.6 N was a bug). Online parameters per solve: the point p, the normal n (n_z
forced to 0 and renormalised), v_pt_B and a world-frame disturbance acceleration a_ext of the
model (zero unless the optional disturbance observer is on):
``params = [p (3), n_x, n_y, v_pt_B (3), a_ext (3)]``.

Horizon N = 30 at 0.01 s, RK4 multiple shooting, |p|, |q|, |r| <= 100 deg/s and
0.3 m g <= T <= 2 m g (the environment's action bounds, from :class:`ActionScaling`).

Closed-loop behaviour measured with this implementation (tests/controllers/test_vtnmpc.py, bench harness):

* The 0.3 s horizon sees little of how attitude moves the drone, so position is weakly damped:
  on a drag-free plant the converged MPC (IPOPT or SQP alike, so not an RTI artefact) keeps a
  +-0.5 m oscillation, while N = 60 settles. With the rotor drag every real airframe (and the
  simulator) has, it settles to |d - d_ref| < 0.1 m, h > 0.99 within ~7 s of a 1 m offset.
* Without a disturbance model, the paper's 4 m/s gust blowing *along* the surface normal pushes
  the drone ~1 m off d_ref (SM with 1 m margin ~75-80 %); across the normal SM stays 100 %.
  ``disturbance_observer=True`` brings the error under 0.3 m (SM 100 %) in both cases.
* At 7 m/s the observer alone is not enough on the full mission (CM 99.6 %): the printed heading
  shrinks by cos(tilt) when the drone leans ~35 deg into the wind, so the h term fights the lean
  the wind needs; and the residual 1 - h is quadratic in the heading error (a quartic cost), so a
  steady 2-3 deg error in transitions costs almost nothing. :data:`VTNMPC_PLUS` (observer + camera
  heading + chord residual) measures SM 100 %, CM >= 99.99 % at 4 and 7 m/s.
* The later tuning set is less damped than the paper's weights on the same plant.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import NU, NX, QuadrotorModel, quat_to_rotmat, quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import GRAVITY
from wt_inspect_env.util.validation import check_choice, check_positive

from .rti import OCP
from .rti_policy import LSQWeights, MPCConfig, RTIPolicy, config_ocp

N_PARAMS = 11
HEADING_MODELS = ("body", "camera")
HEADING_RESIDUALS = ("paper", "chord")
STAGE_RESIDUAL_NAMES = ("h", "d", "r", "o", "u", "v", "w", "qx", "qy", "p", "q", "r_rate", "T")
TERMINAL_RESIDUAL_NAMES = ("u", "v", "w", "qx", "qy")


@dataclass(frozen=True)
class VTNMPCWeights(LSQWeights):
    """Diagonal least-squares weights of the VT-NMPC.

    Defaults are the paper's (tuned by its authors' active-exploration method):
    w_h 80, w_d 30, w_r 25, w_o 60, W_x* = diag(0.3, 0.3, 1, 80, 80),
    W_u = diag(1, 1, 0.25, 0.03), W_N = 1.5 W_x*. :meth:`later_tuning` is the set from the
    authors' later tuning file that matches their plotted results. Both are weights at the
    paper's stand-off and drone; the solver gets them scaled for the instance's
    (:meth:`~controllers.rti_policy.LSQWeights.scaled`: distance, ROI and orthogonality are
    lengths, u, v, w speeds, the attitude and heading dimensionless).
    """

    heading: float = 80.0
    distance: float = 30.0
    roi: float = 25.0
    orthogonality: float = 60.0
    x_star: tuple[float, ...] = (0.3, 0.3, 1.0, 80.0, 80.0)
    inputs: tuple[float, ...] = (1.0, 1.0, 0.25, 0.03)

    STAGE: ClassVar = (("heading", 1), ("distance", 1), ("roi", 1), ("orthogonality", 1), ("x_star", 5),
                       ("inputs", 4))
    TERMINAL: ClassVar = (("x_star", 5),)
    UNITS: ClassVar = {"heading": "1", "distance": "length", "roi": "length", "orthogonality": "length",
                       "x_star": ("speed", "speed", "speed", "1", "1"), "inputs": ("rate", "rate", "rate", "thrust")}

    @classmethod
    def paper(cls) -> "VTNMPCWeights":
        """The paper's weights (the defaults)."""
        return cls()

    @classmethod
    def later_tuning(cls) -> "VTNMPCWeights":
        """The authors' later tuning file: w_h 120, w_d 70, w_r 30, w_o 70, W_uvw (3, 3, 5),
        W_qxqy 60, W_u (10, 10, 1.7, 0.025) (terminal factor unchanged, 1.5)."""
        return cls(heading=120.0, distance=70.0, roi=30.0, orthogonality=70.0,
                   x_star=(3.0, 3.0, 5.0, 60.0, 60.0), inputs=(10.0, 10.0, 1.7, 0.025))


WEIGHT_SETS: dict[str, VTNMPCWeights] = {
    "paper": VTNMPCWeights.paper(),
    "later_tuning": VTNMPCWeights.later_tuning(),
}


#: VT-NMPC+ - the paper's weights and horizon with three changes for wind (not in the paper):
#: the disturbance observer, the gimbal camera's (yaw-only) heading, which a wind-induced tilt
#: does not change, and the chord heading residual, linear rather than quadratic in the heading
#: error. Measured on the paper's mission: SM 100 %, CM >= 99.99 % at 4 and 7 m/s (README).
VTNMPC_PLUS: dict[str, Any] = {"disturbance_observer": True, "heading_model": "camera",
                               "heading_residual": "chord"}


@dataclass(frozen=True)
class VTNMPCConfig(MPCConfig):
    """Everything that defines a VT-NMPC instance (the common fields: :class:`MPCConfig`).
    ``weights`` may be a :class:`VTNMPCWeights` or the name of a set in :data:`WEIGHT_SETS`;
    ``norm_eps`` is the guard (m^2) inside every norm. ``disturbance_observer`` (off in the
    paper) estimates a world-frame disturbance acceleration from the gap between measured and
    predicted velocity (first-order filter, ``observer_time_constant``) and feeds it to the
    prediction model - the "disturbance force estimate" input the authors' code had but did not
    use - and to the attitude reference (level with respect to the apparent gravity, see
    :func:`attitude_residual`); it removes most of the offset that wind drag otherwise causes.
    ``heading_model`` / ``heading_residual``: see :func:`visual_terms` and :data:`VTNMPC_PLUS`."""

    WEIGHTS: ClassVar[type] = VTNMPCWeights
    WEIGHT_SETS: ClassVar[Mapping[str, Any]] = WEIGHT_SETS

    weights: VTNMPCWeights | str = "paper"
    norm_eps: float = 1e-6
    heading_model: str = "body"
    heading_residual: str = "paper"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive("norm_eps", self.norm_eps)
        check_choice("heading_model", self.heading_model, HEADING_MODELS)
        check_choice("heading_residual", self.heading_residual, HEADING_RESIDUALS)


def visual_terms(x, params, eps: float, heading_model: str = "body"):
    """[h, d, r, o] for a state ``x`` and parameters [p, n_x, n_y, ...] (symbolic or numeric).

    ``heading_model`` ``"body"``: the paper's h = (R e_x)_xy . a_xy / ||a_xy||, which shrinks by
    cos(pitch) when the drone leans; ``"camera"``: the heading of the gimbal camera, i.e. the same
    with (R e_x)_xy normalised - the yaw-only h the authors' code used, independent of tilt.
    """
    point = params[0:3]
    n = ca.vertcat(params[3], params[4], 0)
    a = point - x[0:3]
    d = ca.sqrt(a[0] ** 2 + a[1] ** 2 + eps)
    R = quat_to_rotmat(x[6:10])
    heading = (R[0, 0] * a[0] + R[1, 0] * a[1]) / d
    if heading_model == "camera":
        heading = heading / ca.sqrt(R[0, 0] ** 2 + R[1, 0] ** 2 + eps)
    roi = a[0] * n[0] + a[1] * n[1]
    perp = a - ca.dot(a, n) * n
    orth = ca.sqrt(ca.dot(perp, perp) + eps)
    return ca.vertcat(heading, d, roi, orth)


def attitude_residual(q, a_ext):
    """(qx, qy) residual: zero at a level attitude when ``a_ext`` = 0 (the paper's x* reference).

    With a disturbance acceleration ``a_ext`` (world) the hover attitude is tilted so that the
    body z axis points along z_d = (0, 0, g) - a_ext. That attitude with the drone's own yaw psi is
    q_t (x) q_psi, where q_t = normalise([e_z x z_d, 1 + e_z . z_d]) = (t_x, t_y, 0, t_w); its
    x/y components are (t_x qw + t_y qz, t_y qw - t_x qz) / t_w in terms of the state's own
    (qz, qw) = t_w (sin psi/2, cos psi/2). For a_ext = 0, t = (0, 0, 0, 1): exactly (qx, qy).
    """
    z = ca.vertcat(-a_ext[0], -a_ext[1], GRAVITY - a_ext[2])
    z = z / ca.norm_2(z)   # |z| >= g - |a_ext| > 0: the observer bounds |a_ext| below g
    t = ca.vertcat(-z[1], z[0], 1 + z[2])
    t = t / ca.norm_2(t)   # 1 + z_z > 0 for tilts below 90 deg
    tx, ty, tw = t[0], t[1], t[2]
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    return ca.vertcat(qx - (tx * qw + ty * qz) / tw, qy - (ty * qw - tx * qz) / tw)


def residual_functions(config: VTNMPCConfig) -> tuple[ca.Function, ca.Function]:
    """(stage_residual(x, u, params), terminal_residual(x, params)), zero at the references."""
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", N_PARAMS)
    vis = visual_terms(x, p, config.norm_eps, config.heading_model)
    vis_res = vis - ca.vertcat(1.0, config.d_ref, -config.d_ref, 0.0)
    if config.heading_residual == "chord":
        # |f - a_hat| = sqrt(2 (1 - h)) ~ |heading error| instead of the paper's 1 - h ~ err^2 / 2:
        # the paper's cost is quartic in the heading error, flat near zero, so a few degrees of
        # error cost almost nothing against the other terms. Guarded: smooth at h = 1.
        eps = config.norm_eps
        chord = ca.sqrt(2.0 * (1.0 - vis[0]) + eps) - np.sqrt(eps)
        vis_res = ca.vertcat(chord, vis_res[1:])
    x_star = ca.vertcat(x[3:6] - p[5:8], attitude_residual(x[6:10], p[8:11]))
    u_res = u - ca.DM(config.hover_input)
    stage = ca.Function("vtnmpc_r", [x, u, p], [ca.vertcat(vis_res, x_star, u_res)],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function("vtnmpc_rN", [x, p], [x_star], ["x", "p"], ["rN"])
    return stage, terminal


def build_ocp(config: VTNMPCConfig) -> OCP:
    """The VT-NMPC as a generic least-squares OCP (RK4 of the shared quadrotor model)."""
    model = QuadrotorModel(config.params)
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", N_PARAMS)
    F = ca.Function("vtnmpc_F", [x, u, p],
                    [model.rk4_expr(x, u, config.dt, a_ext=p[8:11], steps=config.rk4_steps)],
                    ["x", "u", "p"], ["x_next"])
    return config_ocp("vtnmpc", config, F, *residual_functions(config))


def vtnmpc_parameters(state: np.ndarray, point: np.ndarray, normal_xy: np.ndarray,
                      point_velocity_world: np.ndarray,
                      disturbance_accel: np.ndarray | None = None) -> np.ndarray:
    """Online parameter vector: point, horizontal normal, point velocity in the body frame of
    ``state``'s attitude, world-frame disturbance acceleration of the model (zero by default)."""
    R = quat_to_rotmat_np(state[6:10])
    v_body = R.T @ np.asarray(point_velocity_world, dtype=float)
    a = np.zeros(3) if disturbance_accel is None else np.asarray(disturbance_accel, dtype=float)
    return np.concatenate([point, normal_xy, v_body, a])


class VTNMPCPolicy(RTIPolicy):
    """VT-NMPC as a policy: observation in, normalised (p, q, r, T) action out.

    Each :meth:`act` runs one real-time iteration on the compiled QP data (schedule and
    interface: :class:`~controllers.rti_policy.RTIPolicy`); :attr:`last_stats` holds its
    :class:`~controllers.rti.SolveStats`.
    """

    config_class = VTNMPCConfig

    def build_ocp(self, config: VTNMPCConfig) -> OCP:
        """The VT-NMPC's OCP."""
        return build_ocp(config)

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                   normal_xy: np.ndarray) -> np.ndarray:
        """Online parameters (see :func:`vtnmpc_parameters`), with the observer's estimate."""
        return vtnmpc_parameters(state, obs["point"], normal_xy, obs["point_velocity"], self._a_hat)
