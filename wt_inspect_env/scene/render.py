"""Rendering: ``rgb_array`` frames (the onboard gimbal-camera image beside a chase view) and the
camera observations of the image ``obs_mode``s.

All come from PyBullet's software renderer (TinyRenderer, no display or GPU needed) on the
simulator's own client, so they show exactly the geometry the drone flies in (the turbine drawn
with :class:`~wt_inspect_env.scene.texture.SpanTexture`). The onboard view uses the camera's gimbal pose
and its vertical field of view (the image's aspect is the requested resolution's). Resolution is
small: ``render`` is for videos and debugging, observations are for learning; coverage is computed
geometrically, not from these images.
"""
from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np
import pybullet as p


class RenderedEnv(Protocol):
    """What :func:`render_views` reads of an environment (a
    :class:`~wt_inspect_env.env.WindTurbineInspectionEnv`): its simulator, gimbal camera and
    configuration. Named structurally so that rendering, which the environment calls, does not
    import the environment back."""

    sim: Any
    camera: Any
    config: Any

VIEW_W, VIEW_H = 320, 240


NEAR = 0.1   # near clipping plane [m]


def _render(client: int, eye, target, up, fov_deg: float, far: float, width: int, height: int,
            flags: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(rgba (h, w, 4) uint8, depth buffer (h, w) in [0, 1]) of one TinyRenderer view."""
    view = p.computeViewMatrix(list(map(float, eye)), list(map(float, target)), list(map(float, up)),
                               physicsClientId=client)
    proj = p.computeProjectionMatrixFOV(fov_deg, width / height, NEAR, far, physicsClientId=client)
    _, _, rgba, depth, _ = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                                            flags=flags, physicsClientId=client)
    return (np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4),
            np.asarray(depth, dtype=np.float32).reshape(height, width))


def _image(client: int, eye, target, up, fov_deg: float, far: float) -> np.ndarray:
    return _render(client, eye, target, up, fov_deg, far, VIEW_W, VIEW_H)[0][:, :, :3]


def metric_depth(buffer: np.ndarray, far: float, near: float = NEAR) -> np.ndarray:
    """Distance along the optical axis [m] from an OpenGL depth buffer in [0, 1] (``far`` where
    nothing was hit)."""
    b = np.asarray(buffer, dtype=np.float64)
    den = far - (far - near) * b
    ok = np.isfinite(den) & (den > 0)   # a rounded buffer value at or past the far plane: far
    d = np.where(ok, far * near / np.where(ok, den, 1.0), far)
    return np.clip(d, 0.0, far).astype(np.float32)   # inside the observation space's [0, far]


def in_frustum(centers: np.ndarray, radii: np.ndarray, origin: np.ndarray, R: np.ndarray, tan_x: float,
               tan_y: float, far: float) -> np.ndarray:
    """Which spheres (centres (K, 3), radii (K,)) may reach into a camera's view frustum (origin,
    ``R`` with the camera's x right, y down, z forward as columns, half-angle tangents, far plane);
    conservative: a sphere is dropped only when it lies wholly outside one of the planes."""
    c = (np.asarray(centers) - origin) @ R          # camera coordinates
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    r = np.asarray(radii)
    side_x = (np.abs(x) - tan_x * z) / np.hypot(1.0, tan_x)   # signed distance outside a side plane
    side_y = (np.abs(y) - tan_y * z) / np.hypot(1.0, tan_y)
    return (z > NEAR - r) & (z < far + r) & (side_x < r) & (side_y < r)


def camera_images(sim, camera, state: np.ndarray, resolution: tuple[int, int], far: float,
                  rgb: bool = True, depth: bool = True) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The gimbal camera's view from the drone state ``state`` [p, v_body, q]: ``rgb`` (h, w, 3)
    uint8 and ``depth`` (h, w) float32 [m, along the optical axis] (``None`` where not asked for).
    ``sim``: the world's simulator (drone 0's view; only the obstacle chunks in the
    frustum are drawn - the same image, a fraction of the triangles); ``camera``: the env's
    :class:`~wt_inspect_env.scene.camera.GimbalCamera`."""
    sim.sync_scene()                       # the drone's body where the drone is (the flight core flies it)
    origin, R = camera.pose(state[0:3], state[6:10])
    fwd, down = R[:, 2], R[:, 1]
    w, h = resolution
    fov_y = camera.config.fov_deg[1]
    chunks = sim.obstacle_chunks
    if chunks is not None:
        tan_y = math.tan(math.radians(fov_y) / 2.0)
        sim.show_obstacle_chunks(in_frustum(chunks[0], chunks[1], origin, R, tan_y * w / h, tan_y, far))
    # No segmentation mask: it is not used and costs a pass.
    rgba, buf = _render(sim.client, origin, origin + fwd, -down, fov_y, far, w, h,
                        flags=p.ER_NO_SEGMENTATION_MASK)
    return (np.ascontiguousarray(rgba[:, :, :3]) if rgb else None,
            metric_depth(buf, far) if depth else None)


def render_views(env: RenderedEnv) -> np.ndarray:
    """(240, 640, 3) uint8: onboard camera (left) and chase view (right)."""
    env.sim.show_obstacle_chunks(True)     # the chase view sees the whole turbine
    env.sim.sync_scene()                   # ... and the drone's body where the drone is
    state = env.sim.state[0]
    origin, R = env.camera.pose(state[0:3], state[6:10])
    fwd, down = R[:, 2], R[:, 1]
    fov_v = env.config.camera.fov_deg[1]
    onboard = _image(env.sim.client, origin, origin + fwd, -down, fov_v, 200.0)
    heading = np.array([fwd[0], fwd[1], 0.0])
    heading /= max(np.linalg.norm(heading), 1e-9)
    eye = state[0:3] - 12.0 * heading + np.array([0.0, 0.0, 4.0])
    chase = _image(env.sim.client, eye, state[0:3] + 3.0 * heading, (0, 0, 1), 60.0, 400.0)
    return np.concatenate([onboard, chase], axis=1)
