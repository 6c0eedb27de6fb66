"""The one home of the inspection geometry, hover thrust and drag (wt_inspect_env.task.geometry,
wt_inspect_env.physics.quadrotor), held to independent formulas."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.physics.dynamics import quat_to_rotmat_np, yaw_to_quat
from wt_inspect_env.physics.quadrotor import AIR_DENSITY, GRAVITY, drag_force, get_preset, hover_thrust
from wt_inspect_env.task.geometry import (
    HorizontalNormal,
    camera_heading,
    direction_to_drone,
    facing_yaw,
    heading_and_distance,
    horizontal_normal,
    standoff_position,
    standoff_state,
)
from wt_inspect_env.task.spaces import ActionScaling


def test_horizontal_normal_and_its_fallback():
    np.testing.assert_allclose(horizontal_normal([0.6, 0.0, 0.8]), [1.0, 0.0])
    assert horizontal_normal([0.0, 0.0, 1.0]) is None
    fb = np.array([0.0, 1.0])
    assert horizontal_normal([1e-9, 0.0, -1.0], fb) is fb
    tracker = HorizontalNormal()
    # first step, vertical normal: from the point towards the drone
    np.testing.assert_allclose(tracker.update([0, 0, 1.0], position=[3.0, 4.0, 0.0], point=[0, 0, 0]), [0.6, 0.8])
    # a horizontal normal is taken as it is, and then remembered through a vertical one
    np.testing.assert_allclose(tracker.update([0, -2.0, 0.0], [9, 9, 9], [0, 0, 0]), [0, -1.0])
    np.testing.assert_allclose(tracker.update([0, 0, -1.0], [9, 9, 9], [0, 0, 0]), [0, -1.0])
    tracker.reset()
    np.testing.assert_allclose(tracker.update([0, 0, 1.0], [0, 0, 5.0], [0, 0, 0]), [1.0, 0.0])
    np.testing.assert_allclose(direction_to_drone([0, 0, 1], [0, 0, 0]), [1.0, 0.0])


def test_standoff_pose_faces_the_point_at_d_ref():
    point, normal = np.array([1.0, 2.0, 30.0]), np.array([0.0, -1.0, 0.3])
    x = standoff_state(point, normal, 7.0)
    np.testing.assert_allclose(x[0:3], [1.0, -5.0, 30.0])
    np.testing.assert_allclose(x[6:10], yaw_to_quat(math.pi / 2))     # looking along +y, at the point
    h, d = heading_and_distance(x[0:3], x[6:10], point)
    assert d == pytest.approx(7.0) and h == pytest.approx(1.0)
    np.testing.assert_allclose(standoff_position(point, [0.0, -1.0], 7.0), x[0:3])
    assert abs(facing_yaw([1.0, 0.0])) == pytest.approx(math.pi)
    with pytest.raises(ValueError, match="normal"):
        standoff_state(point, [0, 0, 1.0], 7.0)
    with pytest.raises(ValueError, match="d_ref"):
        standoff_state(point, normal, float("nan"))


def test_heading_of_body_and_camera_under_tilt():
    point = np.array([10.0, 0.0, 0.0])
    pitch = math.radians(30.0)
    q = np.array([0.0, math.sin(pitch / 2), 0.0, math.cos(pitch / 2)])   # pitched 30 deg, yaw 0
    h_body, d = heading_and_distance([0, 0, 0], q, point)
    bx = quat_to_rotmat_np(q)[:, 0]
    assert d == pytest.approx(10.0)
    assert h_body == pytest.approx(bx[0]) == pytest.approx(math.cos(pitch))   # shrinks by cos(tilt)
    assert camera_heading([0, 0, 0], q, point) == pytest.approx(1.0)        # the gimbal's does not
    assert camera_heading(point, q, point) == 0.0 and heading_and_distance(point, q, point) == (0.0, 0.0)


def test_hover_thrust_and_drag_have_one_definition():
    p = get_preset("matrice100")
    assert hover_thrust(p.mass) == p.weight == pytest.approx(p.mass * GRAVITY)
    s = ActionScaling.from_params(p)
    assert s.hover_thrust == p.weight and s.to_command(s.hover_action())[3] == pytest.approx(p.weight, rel=1e-6)
    v = np.array([3.0, -4.0, 1.0])
    expected = -(np.array(p.rotor_drag) * v + 0.5 * AIR_DENSITY * np.array(p.body_drag_area) * np.linalg.norm(v) * v)
    np.testing.assert_allclose(drag_force(p, v), expected, rtol=1e-12)
    np.testing.assert_array_equal(drag_force(p, np.zeros(3)), np.zeros(3))


def test_the_simulator_integrates_the_same_drag_coefficients():
    """The simulator's per-sub-step drag constants are the parameters' drag coefficients (the
    one drag model, :func:`drag_force`), bit for bit."""
    from wt_inspect_env.physics.rate_control import Mixer
    from wt_inspect_env.physics.sim_config import SimConfig, SubstepConstants
    for name in ("matrice100", "lab250"):
        p = get_preset(name)
        k = SubstepConstants.of(p, SimConfig(), Mixer(p))
        assert (k.lin_drag, k.quad_drag) == p.drag_coefficients
