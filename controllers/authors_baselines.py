"""The paper's two baselines as the authors ran them, bugs included - for the ``paper-faithful``
scenario only; :mod:`controllers.nmpc` and :mod:`controllers.pampc` are the fixed forms.

* :class:`AuthorsNMPCPolicy` (``nmpc-authors``) - the NMPC with the authors' quaternion yaw
  reference: instead of the sign-safe heading residual of :mod:`controllers.tracking` it tracks the
  quaternion's (q_z, q_w) against q_ref = (0, 0, sin(psi/2), cos(psi/2)) built from the yaw that faces
  the surface, psi = atan2(-n_y, -n_x) in (-pi, pi] (precomputed per surface, as the authors did),
  with their weights W_qz = W_qw = 30. The measured quaternion is continuous (the base aligns it with
  the previous step's), so each time the facing yaw crosses +-180 deg the reference jumps by 360 deg,
  q_ref changes sign while the drone's q does not, and the least-squares cost sees an error of
  |q - (-q)| = 2 in (q_z, q_w) for an attitude that is exactly right (docs/controllers.md). The
  drone then turns a full circle back, or hangs between - the suspected cause of the paper's NMPC
  coverage of 91.6 %.
* :class:`AuthorsPAMPCPolicy` (``pampc-authors``) - the PAMPC with the authors' camera axis: the
  projection's optical axis is the body *up* axis (z) instead of body x, so the perception residual
  measures the point's offset seen from a camera looking at the sky (the point, at the drone's
  height 7 m ahead, sits near the image plane; the depth guard keeps the residual finite - the
  authors' code had no guard). Their two image coordinates also had different denominators; the
  vertical coordinate's weight is 0 in their file (and here), so that bug has no effect and is not
  reproduced.

Both reuse the tracking OCP pieces unchanged (:func:`~controllers.tracking.tracking_terms`,
:func:`~controllers.tracking.augmented_dynamics`), so everything else - weights, horizon, clock state,
input bounds - is the fixed baselines'.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import NU, quat_to_rotmat
from wt_inspect_env.scene.camera import CameraConfig
from wt_inspect_env.task.geometry import facing_yaw

from .nmpc import NMPCConfig, NMPCWeights
from .pampc import PAMPCPolicy, smooth_depth
from .rti import OCP
from .rti_policy import config_ocp
from .tracking import (
    CLOCK,
    N_TRACKING_PARAMS,
    NX_AUG,
    TrackingMPCPolicy,
    augmented_dynamics,
    tracking_ocp,
    tracking_terms,
)


@dataclass(frozen=True)
class AuthorsNMPCWeights(NMPCWeights):
    """The NMPC weights with the authors' W_qz = W_qw = 30 on the quaternion yaw rows."""

    heading: float = 30.0


AUTHORS_NMPC_WEIGHTS: dict[str, AuthorsNMPCWeights] = {"authors": AuthorsNMPCWeights()}


@dataclass(frozen=True)
class AuthorsNMPCConfig(NMPCConfig):
    """:class:`~controllers.nmpc.NMPCConfig` with the authors' quaternion yaw weights."""

    WEIGHTS: ClassVar[type] = AuthorsNMPCWeights
    WEIGHT_SETS: ClassVar[Mapping[str, Any]] = AUTHORS_NMPC_WEIGHTS

    weights: AuthorsNMPCWeights | str = "authors"


def wrapped_yaw_quaternion(normal_xy: np.ndarray) -> tuple[float, float]:
    """(q_z, q_w) of the authors' yaw reference: the facing yaw wrapped into (-pi, pi], so q_w >= 0
    and the pair jumps sign where the yaw crosses +-pi."""
    psi = facing_yaw(normal_xy)
    return math.sin(0.5 * psi), math.cos(0.5 * psi)


def authors_nmpc_ocp(config: AuthorsNMPCConfig) -> OCP:
    """The NMPC OCP with the heading rows replaced by (q_z - q_z,ref, q_w - q_w,ref); the
    parameters' last two entries carry (q_z,ref, q_w,ref) instead of (cos psi, sin psi)."""
    x = ca.SX.sym("x", NX_AUG)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", N_TRACKING_PARAMS)
    t = tracking_terms(x, p)
    quat_yaw = ca.vertcat(x[8] - p[6], x[9] - p[7])
    state_res = ca.vertcat(t["position"], t["velocity"], t["tilt"], quat_yaw)
    stage = ca.Function("nmpc_authors_r", [x, u, p], [ca.vertcat(state_res, u - ca.DM(config.hover_input))],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function("nmpc_authors_rN", [x, p], [state_res], ["x", "p"], ["rN"])
    dynamics = augmented_dynamics("nmpc_authors", config.params, config.dt, config.rk4_steps, N_TRACKING_PARAMS)
    return config_ocp("nmpc_authors", config, dynamics, stage, terminal)


class AuthorsNMPCPolicy(TrackingMPCPolicy):
    """The NMPC baseline with the authors' quaternion yaw reference (see the module docstring)."""

    config_class = AuthorsNMPCConfig

    def build_ocp(self, config: AuthorsNMPCConfig) -> OCP:
        """The authors' NMPC OCP."""
        return authors_nmpc_ocp(config)

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                   normal_xy: np.ndarray) -> np.ndarray:
        """The tracking parameters with the reference yaw wrapped as the authors' code wraps it."""
        params = super().parameters(obs, state, normal_xy)
        params[6:8] = wrapped_yaw_quaternion(normal_xy)
        return params


def body_up_camera_rotation() -> np.ndarray:
    """R_CB of the authors' PAMPC: optical axis body z (up), right body -y, down = z x (-y) = body x."""
    forward = np.array([0.0, 0.0, 1.0])
    right = np.array([0.0, -1.0, 0.0])
    return np.vstack([right, np.cross(forward, right), forward])


def authors_image_coordinates(x, point, camera: CameraConfig, guard: float):
    """(s_x, s_y) of a world point through the authors' body-up camera (symbolic)."""
    R = quat_to_rotmat(x[6:10])
    S_C = ca.DM(body_up_camera_rotation()) @ (R.T @ (point - x[0:3]) - ca.DM(camera.mount_offset))
    z = smooth_depth(S_C[2], guard)
    return ca.vertcat(S_C[0] / z, S_C[1] / z)


class AuthorsPAMPCPolicy(PAMPCPolicy):
    """PAMPC with the authors' camera axis (body up; see the module docstring)."""

    def build_ocp(self, config: Any) -> OCP:
        """The authors' PAMPC OCP: the tracking terms plus their image-coordinate perception residual."""
        def perception(x, p):
            point = p[N_TRACKING_PARAMS:N_TRACKING_PARAMS + 3] + p[3:6] * x[CLOCK]
            return authors_image_coordinates(x, point, config.camera, config.image_plane_guard)
        return tracking_ocp("pampc_authors", config, N_TRACKING_PARAMS + 3, perception)
