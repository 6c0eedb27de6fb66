"""First-principles checks of the shared CasADi quadrotor model."""
import numpy as np
import pytest

from wt_inspect_env.physics.dynamics import QuadrotorModel, hover_state, quat_to_rotmat_np, yaw_to_quat
from wt_inspect_env.physics.quadrotor import GRAVITY, PRESETS, QuadrotorParams, get_preset


def test_hover_is_equilibrium():
    m = QuadrotorModel()
    xdot = m.xdot(hover_state([1, 2, 3], yaw=0.7), [0, 0, 0, m.params.weight])
    np.testing.assert_allclose(xdot, 0, atol=1e-12)


def test_free_fall_and_climb():
    m = QuadrotorModel()
    xdot = m.xdot(hover_state([0, 0, 10]), [0, 0, 0, 0])
    np.testing.assert_allclose(xdot[3:6], [0, 0, -GRAVITY])
    xdot = m.xdot(hover_state([0, 0, 10]), [0, 0, 0, 2 * m.params.weight])
    np.testing.assert_allclose(xdot[3:6], [0, 0, GRAVITY])


def test_tilted_thrust_accelerates_sideways():
    """Pitching nose-down by theta at thrust m g / cos(theta) accelerates forward at g tan(theta)."""
    m = QuadrotorModel()
    th = 0.3
    q = np.array([0, np.sin(th / 2), 0, np.cos(th / 2)])  # rotation about +y: nose down
    x = np.zeros(10)
    x[6:10] = q
    xdot = m.xdot(x, [0, 0, 0, m.params.weight / np.cos(th)])
    a_world = quat_to_rotmat_np(q) @ xdot[3:6]  # with zero velocity, v_dot = R^T a_world
    np.testing.assert_allclose(a_world, [GRAVITY * np.tan(th), 0, 0], atol=1e-9)


def test_constant_yaw_rate_integrates_to_yaw():
    m = QuadrotorModel()
    xs = m.rollout(hover_state([0, 0, 0]), np.tile([0, 0, 0.5, m.params.weight], (100, 1)), 0.01)
    np.testing.assert_allclose(xs[-1][6:10], yaw_to_quat(0.5), atol=1e-9)


def test_body_velocity_rotates_into_world():
    m = QuadrotorModel()
    x = hover_state([0, 0, 0], yaw=np.pi / 2)
    x[3] = 2.0  # forward body speed; facing +y
    xdot = m.xdot(x, [0, 0, 0, m.params.weight])
    np.testing.assert_allclose(xdot[0:3], [0, 2, 0], atol=1e-12)


def test_quaternion_norm_preserved_by_continuous_dynamics():
    rng = np.random.default_rng(0)
    m = QuadrotorModel()
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        x = np.concatenate([rng.normal(size=6), q])
        xdot = m.xdot(x, rng.normal(size=4))
        assert abs(q @ xdot[6:10]) < 1e-12


def test_presets_and_an_unknown_preset():
    assert set(PRESETS) == {"matrice100", "lab250"}
    assert get_preset("lab250").mass == pytest.approx(1.09)
    with pytest.raises(ValueError, match="drone preset"):
        get_preset("nope")


# the physics parameters' validation (the simulator and the models all build on QuadrotorParams)
@pytest.mark.parametrize("field, value", [("mass", -1.0), ("motor_time_constant", -0.1),
                                          ("motor_time_constant", -0.01)])
def test_bad_params_raise_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        QuadrotorParams(**{field: value})


def test_mixer_maps_rotor_thrusts_to_wrench():
    p = get_preset("matrice100")
    A = p.mixer
    # Equal thrusts: pure collective, no torque
    np.testing.assert_allclose(A @ np.full(4, 5.0), [20, 0, 0, 0], atol=1e-12)
    assert np.linalg.matrix_rank(A) == 4


def test_one_quaternion_rotation_is_the_batched_one_bit_for_bit():
    """quat_to_rotmat_np's single-quaternion fast path (Python floats) gives the batched result."""
    rng = np.random.default_rng(0)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    np.testing.assert_array_equal(np.array([quat_to_rotmat_np(x) for x in q]), quat_to_rotmat_np(q))
