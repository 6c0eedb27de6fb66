"""The baselines as the authors ran them (controllers/authors_baselines.py): their bugs are there,
measurably, and only where the notes put them."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from controllers.authors_baselines import (
    AuthorsNMPCPolicy,
    authors_image_coordinates,
    body_up_camera_rotation,
    wrapped_yaw_quaternion,
)
from controllers.nmpc import NMPCPolicy
from controllers.pampc import PAMPCConfig, image_coordinates
from wt_inspect_env.scene.camera import CameraConfig


def _yaw_state(yaw: float, *, flip: bool = False) -> np.ndarray:
    """Drone state [p, v_B, q, clock] hovering at the origin with a yaw (q continuous past pi)."""
    q = np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]) * (-1.0 if flip else 1.0)
    return np.concatenate([np.zeros(6), q, [0.0]])


def _normal_for_yaw(yaw: float) -> np.ndarray:
    """The horizontal normal whose facing yaw (along -n) is ``yaw``."""
    return -np.array([math.cos(yaw), math.sin(yaw)])


@pytest.fixture(scope="module")
def policies(params):
    return (AuthorsNMPCPolicy(params=params, d_ref=7.0, horizon=5),
            NMPCPolicy(params=params, d_ref=7.0, horizon=5))


def test_quaternion_yaw_reference_flips_sign_at_the_180_deg_wrap(policies):
    authors, fixed = policies
    before, after = math.radians(179.0), math.radians(181.0)      # 2 deg apart, across the wrap
    qa, qb = wrapped_yaw_quaternion(_normal_for_yaw(before)), wrapped_yaw_quaternion(_normal_for_yaw(after))
    # the reference yaw wraps to -179 deg: (q_z, q_w) jumps from (~1, ~0.009) to (~-1, ~0.009)
    assert qa[0] == pytest.approx(math.sin(math.radians(89.5))) and qb[0] == pytest.approx(-qa[0])
    assert qb[1] == pytest.approx(qa[1]) and qa[1] > 0.0
    obs = {"point": np.array([7.0, 0.0, 0.0]), "point_velocity": np.zeros(3)}
    # a drone that turned continuously to 181 deg, its reference from the wrapped yaw
    x = _yaw_state(after)
    stage_a = authors.ocp.terminal_residual
    stage_f = fixed.ocp.terminal_residual
    pa = authors.parameters(obs, x[:10], _normal_for_yaw(after))
    pf = fixed.parameters(obs, x[:10], _normal_for_yaw(after))
    ra = np.asarray(stage_a(x, pa)).ravel()
    rf = np.asarray(stage_f(x, pf)).ravel()
    # rows 8, 9: the authors' (q_z, q_w) error is 2 for an exactly right attitude; the fixed one 0
    assert np.linalg.norm(ra[8:10]) == pytest.approx(2.0, abs=1e-3)
    assert np.linalg.norm(rf[8:10]) < 1e-9
    # the same attitude with the quaternion's other sign: no error for the authors' either
    assert np.linalg.norm(np.asarray(stage_a(_yaw_state(after, flip=True), pa)).ravel()[8:10]) < 1e-3
    # away from the wrap the two agree that the attitude is right
    mid = _yaw_state(math.radians(90.0))
    pa = authors.parameters(obs, mid[:10], _normal_for_yaw(math.radians(90.0)))
    assert np.linalg.norm(np.asarray(stage_a(mid, pa)).ravel()[8:10]) < 1e-9


def test_authors_pampc_camera_looks_along_body_up():
    R = body_up_camera_rotation()
    assert np.allclose(R[2], [0, 0, 1]) and np.allclose(R[0], [0, -1, 0]) and np.allclose(R[1], [1, 0, 0])
    cam = CameraConfig(mount_offset=(0.0, 0.0, 0.0))
    guard = PAMPCConfig.image_plane_guard
    x = ca.DM(_yaw_state(0.0)[:10])
    ahead, left = ca.DM([7.0, 0.0, 0.0]), ca.DM([7.0, 1.0, 0.0])
    fixed = lambda pt: np.asarray(ca.evalf(image_coordinates(x, pt, cam, guard))).ravel()  # noqa: E731
    theirs = lambda pt: np.asarray(ca.evalf(authors_image_coordinates(x, pt, cam, guard))).ravel()  # noqa: E731
    # a point 7 m straight ahead is the image centre for the fixed camera ...
    assert np.allclose(fixed(ahead), 0.0)
    # ... and for the body-up camera it sits on the image plane (depth 0): s = (0, 7 / z~(0))
    z0 = 0.5 * (guard + math.sqrt(2.0) * guard)
    assert np.allclose(theirs(ahead), [0.0, 7.0 / z0])
    # one metre to the left moves the authors' s_x by -1 / z~(0) (the weighted coordinate)
    assert theirs(left)[0] == pytest.approx(-1.0 / z0)
