"""``rgb_array`` rendering: the onboard gimbal-camera image beside a chase view.

Both come from PyBullet's software renderer (TinyRenderer, no display or GPU needed) on the
simulator's own client, so they show exactly the collision geometry the drone flies in. The onboard
view uses the camera's real field of view and gimbal pose; the chase view looks at the drone from
behind and above. Resolution is small (it is for videos and debugging, not for coverage, which is
computed geometrically).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pybullet as p

if TYPE_CHECKING:  # pragma: no cover
    from .env import WindTurbineInspectionEnv

VIEW_W, VIEW_H = 320, 240


def _image(client: int, eye, target, up, fov_deg: float, far: float) -> np.ndarray:
    view = p.computeViewMatrix(list(map(float, eye)), list(map(float, target)), list(map(float, up)),
                               physicsClientId=client)
    proj = p.computeProjectionMatrixFOV(fov_deg, VIEW_W / VIEW_H, 0.1, far, physicsClientId=client)
    _, _, rgba, _, _ = p.getCameraImage(VIEW_W, VIEW_H, view, proj, renderer=p.ER_TINY_RENDERER,
                                        physicsClientId=client)
    return np.asarray(rgba, dtype=np.uint8).reshape(VIEW_H, VIEW_W, 4)[:, :, :3]


def render_views(env: "WindTurbineInspectionEnv") -> np.ndarray:
    """(240, 640, 3) uint8: onboard camera (left) and chase view (right)."""
    state = env.sim.state
    origin, R = env.camera.pose(state[0:3], state[6:10])
    fwd, down = R[:, 2], R[:, 1]
    fov_v = env.config.camera.fov_deg[1]
    onboard = _image(env.sim.client, origin, origin + fwd, -down, fov_v, 200.0)
    heading = np.array([fwd[0], fwd[1], 0.0])
    heading /= max(np.linalg.norm(heading), 1e-9)
    eye = state[0:3] - 12.0 * heading + np.array([0.0, 0.0, 4.0])
    chase = _image(env.sim.client, eye, state[0:3] + 3.0 * heading, (0, 0, 1), 60.0, 400.0)
    return np.concatenate([onboard, chase], axis=1)
