"""Perception-aware MPC (PAMPC, after Falanga et al. 2018) as the paper's second baseline.

The same trajectory tracking as the NMPC baseline (:mod:`controllers.tracking`: the stand-off
waypoint moving with the inspection point, world velocity, level attitude, inputs), plus a
perception residual: the inspection point expressed in the camera frame,

    S_B = R(q)^T (p_pt(tau) - p) - t_BC,       S_C = R_CB S_B,
    s   = (S_C,x, S_C,y) / z~(S_C,z)           (normalised image coordinates, reference (0, 0))

with p_pt(tau) = p_pt + v_pt tau moving over the horizon like the waypoint.

Camera. PAMPC is about making the *attitude* serve perception, so - as in Falanga et al. - the camera
is rigidly mounted: it looks along body x (tilted up by the environment's ``mount_pitch_deg``) from
the environment's ``mount_offset`` t_BC, and R(q) is the full body attitude (roll and pitch move
the image). The environment's inspection camera sits on a roll/pitch gimbal instead (its optical
axis is body x rotated by yaw only), so for a level drone both coincide and otherwise PAMPC
predicts a worse image than the gimbal delivers - the baseline's own model, not the environment's.
The authors' implementation accidentally used the body *up* axis as optical axis and two different
denominators; both are fixed here (camera frame OpenCV-style: x right, y down, z optical axis).

Guard. The projection divides by the depth, which crosses zero when the point approaches the image
plane. The depth is replaced by a smooth maximum with ``image_plane_guard`` = z_m,

    z~(z) = ( z + z_m + sqrt((z - z_m)^2 + z_m^2) ) / 2,

which is z to within z_m^2 / (4 z) in front of the camera (0.14 % at 7 m for z_m = 0.5 m), z_m * 1.5
at z = z_m and tends to z_m behind the camera: the residual and its Jacobian stay finite
everywhere and grow (rather than flip sign or vanish, as |z| or sqrt(z^2 + eps) would mirror them)
as the point moves behind the camera. Limitation inherent to the projection residual: a point
*exactly* behind the camera on the optical axis also has s = 0; the position tracking and the tilt
terms do not move the drone there, but a yaw that starts facing away is not corrected unless the
``heading`` weight is non-zero.

Weights (:class:`PAMPCWeights`). Defaults are the authors' PAMPC file (Matrice 100 Gazebo airframe of
their ``PAMPC`` package; the notes are silent on them): position (30, 30, 40), velocity (3, 3, 3)
(world frame in their model, as here), q_x/q_y 60, q_z/q_w 0 (so heading 0: the yaw is left to the
perception term), perception (0.05, 0.0), rates (3, 3, 1), thrust 0.035, terminal 1.5 W. Their
vertical image coordinate was unweighted; it is kept at 0 by default because with a rigid camera
it competes with the level-attitude and height terms.

Horizon: the authors' 30 steps of 0.1 s (3 s), RK4 multiple shooting instead of their implicit
Gauss-Legendre integrator (same order). Alternatives were measured on the model plant (0.7 m/s
pass, 4 m/s mean wind along the normal, 20 s): 30 x 0.05 s and 60 x 0.05 s held the distance about
0.07 m better (mean |d - d_ref| 0.74 m against 0.81 m - none of the baselines has integral action),
15 x 0.2 s 0.16 m worse, with identical heading; no choice was clearly better, so the authors' stays.
The command period is the environment's 0.01 s
(``control_dt``), shorter than a stage, so the warm start is kept rather than shifted
(:func:`~controllers.tracking.warm_start_shifts`). Input bounds are the environment's action bounds
(|rates| <= 100 deg/s, 0.3 to 2 m g), tighter than the authors' 3 rad/s and 3 m g: a policy cannot
command outside the action space. Online parameters: ``[p_wp (3), v_pt (3), cos psi_ref,
sin psi_ref, p_pt (3)]``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import NX, quat_to_rotmat
from wt_inspect_env.scene.camera import CameraConfig
from wt_inspect_env.util.validation import check_positive

from .rti import OCP
from .rti_policy import LSQWeights, MPCConfig
from .tracking import CLOCK, N_TRACKING_PARAMS, TrackingMPCPolicy, tracking_ocp

N_PARAMS = N_TRACKING_PARAMS + 3
STAGE_RESIDUAL_NAMES = ("px", "py", "pz", "vx", "vy", "vz", "qx", "qy", "hx", "hy", "sx", "sy",
                        "p", "q", "r", "T")
TERMINAL_RESIDUAL_NAMES = STAGE_RESIDUAL_NAMES[:12]


@dataclass(frozen=True)
class PAMPCWeights(LSQWeights):
    """Diagonal least-squares weights of the PAMPC (defaults: the authors' file, see the module
    docstring). ``perception`` weighs the normalised image coordinates (x right, y down), which are
    dimensionless. Weights at the paper's stand-off and drone, scaled for the instance's
    (:meth:`~controllers.rti_policy.LSQWeights.scaled`)."""

    position: tuple[float, ...] = (30.0, 30.0, 40.0)
    velocity: tuple[float, ...] = (3.0, 3.0, 3.0)
    tilt: tuple[float, ...] = (60.0, 60.0)
    heading: float = 0.0
    perception: tuple[float, ...] = (0.05, 0.0)
    inputs: tuple[float, ...] = (3.0, 3.0, 1.0, 0.035)

    TERMINAL: ClassVar = (("position", 3), ("velocity", 3), ("tilt", 2), ("heading", 2), ("perception", 2))
    STAGE: ClassVar = TERMINAL + (("inputs", 4),)
    UNITS: ClassVar = {"position": "length", "velocity": "speed", "tilt": "1", "heading": "1",
                       "perception": "1", "inputs": ("rate", "rate", "rate", "thrust")}

    @classmethod
    def authors(cls) -> "PAMPCWeights":
        """The authors' weights (the defaults)."""
        return cls()


WEIGHT_SETS: dict[str, PAMPCWeights] = {"authors": PAMPCWeights.authors()}


@dataclass(frozen=True)
class PAMPCConfig(MPCConfig):
    """Everything that defines a PAMPC instance (the common fields: :class:`MPCConfig`), plus the
    camera mounting and the projection guard ``image_plane_guard`` [m]; stages of 0.1 s and the
    environment's 0.01 s ``control_dt`` by default."""

    WEIGHTS: ClassVar[type] = PAMPCWeights
    WEIGHT_SETS: ClassVar[Mapping[str, Any]] = WEIGHT_SETS

    weights: PAMPCWeights | str = "authors"
    dt: float = 0.1
    control_dt: float | None = 0.01
    camera: CameraConfig = field(default_factory=CameraConfig)
    image_plane_guard: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.camera, CameraConfig):
            raise ValueError(f"camera must be a CameraConfig, got {self.camera!r}")
        check_positive("image_plane_guard", self.image_plane_guard)


def camera_rotation(camera: CameraConfig) -> np.ndarray:
    """R_CB: rows are the camera's right, down and optical axes in body coordinates (optical axis
    = body x tilted up by ``mount_pitch_deg``, right = body -y)."""
    t = math.radians(camera.mount_pitch_deg)
    forward = np.array([math.cos(t), 0.0, math.sin(t)])
    right = np.array([0.0, -1.0, 0.0])
    down = np.cross(forward, right)
    return np.vstack([right, down, forward])


def smooth_depth(z, guard: float):
    """Smooth maximum of the depth and ``guard`` (see the module docstring)."""
    return 0.5 * (z + guard + ca.sqrt((z - guard) ** 2 + guard ** 2))


def image_coordinates(x, point, camera: CameraConfig, guard: float):
    """Normalised image coordinates (s_x, s_y) of a world point for a drone state (symbolic)."""
    R = quat_to_rotmat(x[6:10])
    S_B = R.T @ (point - x[0:3]) - ca.DM(camera.mount_offset)
    S_C = ca.DM(camera_rotation(camera)) @ S_B
    z = smooth_depth(S_C[2], guard)
    return ca.vertcat(S_C[0] / z, S_C[1] / z)


def projection_function(config: PAMPCConfig) -> ca.Function:
    """``s(x, point)``: the perception residual for a model state (10) and a world point (tests,
    plots)."""
    x = ca.SX.sym("x", NX)
    pt = ca.SX.sym("point", 3)
    return ca.Function("pampc_s", [x, pt],
                       [image_coordinates(x, pt, config.camera, config.image_plane_guard)],
                       ["x", "point"], ["s"])


def build_ocp(config: PAMPCConfig) -> OCP:
    """The PAMPC as a generic least-squares OCP (RK4 of the shared model plus the clock state):
    the tracking residuals plus the image coordinates of the point, which moves with its
    velocity over the horizon like the waypoint."""
    def perception(x, p):
        point = p[N_TRACKING_PARAMS:N_TRACKING_PARAMS + 3] + p[3:6] * x[CLOCK]
        return image_coordinates(x, point, config.camera, config.image_plane_guard)
    return tracking_ocp("pampc", config, N_PARAMS, perception)


def residual_functions(config: PAMPCConfig) -> tuple[ca.Function, ca.Function]:
    """(stage_residual(x_aug, u, p), terminal_residual(x_aug, p)), zero at the reference."""
    ocp = build_ocp(config)
    return ocp.stage_residual, ocp.terminal_residual


class PAMPCPolicy(TrackingMPCPolicy):
    """PAMPC as a policy (interface: :class:`~controllers.rti_policy.RTIPolicy`)."""

    config_class = PAMPCConfig

    def build_ocp(self, config: PAMPCConfig) -> OCP:
        """The PAMPC's OCP."""
        return build_ocp(config)

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                   normal_xy: np.ndarray) -> np.ndarray:
        """The tracking parameters and the inspection point (for the projection)."""
        return np.concatenate([super().parameters(obs, state, normal_xy), obs["point"]])
