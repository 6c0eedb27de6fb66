"""The PX4 bridge's frame conversions and thrust mapping, against values worked out by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

pytest.importorskip("pymavlink")

from wt_inspect_env.physics.quadrotor import get_preset  # noqa: E402
from wt_inspect_px4.frames import Site, geodetic_to_ned, ned_to_geodetic  # noqa: E402
from wt_inspect_px4.thrust import ThrustMap, curve, inverse_curve  # noqa: E402


def yaw_ned(deg: float) -> np.ndarray:
    """MAVLink quaternion (w, x, y, z) of a level vehicle heading ``deg`` (clockwise from north)."""
    h = math.radians(deg) / 2
    return np.array([math.cos(h), 0.0, 0.0, math.sin(h)])


@pytest.fixture
def north_frame():
    """Rotor axis (project +x) pointing north, tower base 10 m north / 5 m west of the origin, 2 m up."""
    return Site(heading_deg=0.0, base_ned=(10.0, -5.0, -2.0)).frame((3.0, 4.0), facing_deg=0.0)


def test_positions_map_north_to_the_rotor_axis_and_down_to_minus_z(north_frame):
    f = north_frame
    base_w = np.array([3.0, 4.0, 0.0])
    assert np.allclose(f.position_to_project([10.0, -5.0, -2.0]), base_w)            # the tower base
    assert np.allclose(f.position_to_project([11.0, -5.0, -2.0]), base_w + [1, 0, 0])  # north = rotor axis = +x
    assert np.allclose(f.position_to_project([10.0, -4.0, -2.0]), base_w + [0, -1, 0])  # east = right of +x = -y
    assert np.allclose(f.position_to_project([10.0, -5.0, -3.0]), base_w + [0, 0, 1])  # up = +z
    assert np.allclose(f.position_to_ned(base_w + [0, 0, 1]), [10.0, -5.0, -3.0])


def test_rotor_heading_east_with_the_default_turbine_facing():
    """The default turbine faces +y; with the rotor facing east, +y of the project is east."""
    f = Site(heading_deg=90.0, base_ned=(0.0, 0.0, 0.0)).frame((0.0, 0.0), facing_deg=90.0)
    assert np.allclose(f.vector_to_project([0, 1, 0]), [0, 1, 0])      # east -> +y (the rotor axis)
    assert np.allclose(f.vector_to_project([1, 0, 0]), [-1, 0, 0])     # north -> left of +y = -x
    assert np.allclose(f.vector_to_project([0, 0, 1]), [0, 0, -1])     # down -> -z


def test_attitudes_heading_pitch_and_roll(north_frame):
    f = north_frame
    # level, facing north (along the rotor axis): the project's identity
    assert np.allclose(np.abs(f.attitude_to_project(yaw_ned(0.0))), [0, 0, 0, 1])
    # facing east (heading 90, clockwise): body x = east = -y in the project: yaw -90 deg
    q = f.attitude_to_project(yaw_ned(90.0))
    assert np.allclose(Rotation.from_quat(q).apply([1, 0, 0]), [0, -1, 0], atol=1e-12)
    # nose up 10 deg (positive FRD pitch): body x climbs
    q_pitch = Rotation.from_euler("ZYX", [0.0, 10.0, 0.0], degrees=True).as_quat()    # FRD -> NED, (x, y, z, w)
    R = Rotation.from_quat(f.attitude_to_project(np.roll(q_pitch, 1))).as_matrix()
    assert R[2, 0] == pytest.approx(math.sin(math.radians(10)))
    # right wing down (positive FRD roll): the left wing (FLU +y) rises
    q_roll = Rotation.from_euler("ZYX", [0.0, 0.0, 15.0], degrees=True).as_quat()
    R = Rotation.from_quat(f.attitude_to_project(np.roll(q_roll, 1))).as_matrix()
    assert R[2, 1] == pytest.approx(math.sin(math.radians(15)))


def test_body_velocity_and_rates_of_a_vehicle_flying_north_facing_east(north_frame):
    """2 m/s north while heading east: body FRD (0, -2, 0) -> body FLU (0, 2, 0) (to its left);
    a clockwise yaw rate (FRD +r) is a negative FLU r."""
    from wt_inspect_px4.offboard import VehicleSim
    from wt_inspect_px4.vehicle import VehicleState
    vs = VehicleSim.__new__(VehicleSim)
    vs.frame, vs._q_prev = north_frame, None
    vs.convert(VehicleState(np.array([10.0, -5.0, -12.0]), np.array([2.0, 0.0, 0.0]), yaw_ned(90.0),
                            np.array([0.0, 0.0, 0.5]), 0, 0.0))
    assert np.allclose(vs._state[0:3], [3.0, 4.0, 10.0])
    assert np.allclose(vs._state[3:6], [0.0, 2.0, 0.0], atol=1e-12)
    assert np.allclose(vs._v_world, [2.0, 0.0, 0.0])          # north = +x
    assert np.allclose(vs._rates, [0.0, 0.0, -0.5])


@settings(max_examples=50)
@given(st.floats(-180, 180), st.floats(-180, 180), st.lists(st.floats(-1, 1), min_size=4, max_size=4),
       st.lists(st.floats(-500, 500), min_size=3, max_size=3))
def test_every_conversion_has_its_inverse(heading, facing, q, p):
    q = np.array(q)
    if np.linalg.norm(q) < 1e-3:
        q = np.array([0.0, 0.0, 0.0, 1.0])
    q = q / np.linalg.norm(q)
    f = Site(heading_deg=heading, base_ned=(1.0, 2.0, 3.0)).frame((4.0, -5.0), facing)
    assert np.allclose(f.position_to_ned(f.position_to_project(p)), p, atol=1e-9)
    back = f.attitude_to_project(f.attitude_to_ned(q))
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


def test_geodetic_projection_matches_the_sphere_and_inverts():
    origin = (47.397742, 8.545594, 488.0)
    north = 100.0 / 6371000.0
    ned = geodetic_to_ned(origin[0] + math.degrees(north), origin[1], 478.0, origin)
    assert np.allclose(ned, [100.0, 0.0, 10.0], atol=1e-6)
    east = geodetic_to_ned(origin[0], origin[1] + 0.001, origin[2], origin)
    assert east[1] == pytest.approx(6371000.0 * math.radians(0.001) * math.cos(math.radians(origin[0])), rel=1e-6)
    lat, lon, alt = ned_to_geodetic([120.0, -80.0, -5.0], origin)
    assert np.allclose(geodetic_to_ned(lat, lon, alt, origin), [120.0, -80.0, -5.0], atol=1e-6)
    # a site given geodetically places the base where its NED twin does
    lla = ned_to_geodetic([60.0, 10.0, 0.0], origin)
    a = Site(heading_deg=90, base_lla=lla).frame((0, 0), 90, origin=origin)
    b = Site(heading_deg=90, base_ned=(60.0, 10.0, 0.0)).frame((0, 0), 90)
    assert np.allclose(a.base_ned, b.base_ned, atol=1e-6)


@pytest.mark.parametrize("text, match", [
    ('{"base_ned": [0, 0, 0]}', "heading_deg"),
    ('{"heading_deg": 0}', "exactly one of base_ned"),
    ('{"heading_deg": 0, "base_ned": [0, 0, 0], "base_lla": [1, 2, 3]}', "exactly one"),
    ('{"heading_deg": 0, "base_ned": [0, 0]}', "base_ned"),
    ('{"heading_deg": 0, "base_lla": [95, 0, 0]}', "latitude"),
    ('{"heading_deg": "north", "base_ned": [0, 0, 0]}', "heading_deg"),
    ('{"heading_deg": 0, "base_ned": [0, 0, 0], "yaw": 3}', "yaw"),
    ('{"heading_deg": 0,', "not valid JSON"),
    ("/no/such/site.json", "neither a JSON object nor a readable file"),
])
def test_bad_site_descriptions_name_the_field(text, match):
    with pytest.raises(ValueError, match=match):
        Site.parse(text)


def test_a_geodetic_site_needs_the_origin():
    with pytest.raises(ValueError, match="GPS_GLOBAL_ORIGIN"):
        Site(heading_deg=0, base_lla=(47.0, 8.0, 400.0)).frame((0, 0), 0)


# ------------------------------------------------------------------------------------ thrust
def test_linear_thrust_map_is_force_over_full_thrust():
    p = get_preset("matrice100")
    m = ThrustMap.for_params(p)
    assert m.to_normalised(p.weight) == pytest.approx(3.6 * 9.81 / 80.0)
    assert m.to_normalised(1000.0) == 1.0 and m.to_normalised(-5.0) == 0.0
    assert m.to_newtons(0.5) == pytest.approx(40.0)


def test_thrust_curve_and_px4_model_factor():
    """Motors with f/f_max = 0.5 u + 0.5 u^2: with PX4's THR_MDL_FAC matching, the set-point is linear
    in force; with PX4 assuming linear motors, the set-point is the motor command itself."""
    m = ThrustMap(rotor_max=10.0, motor_curve=0.5, px4_curve=0.5)
    assert m.to_normalised(10.0) == pytest.approx(0.25)
    m0 = ThrustMap(rotor_max=10.0, motor_curve=0.5, px4_curve=0.0)
    u = m0.to_normalised(10.0)
    assert curve(0.5, u) == pytest.approx(0.25) and u == pytest.approx(inverse_curve(0.5, 0.25))
    for T in (0.0, 3.0, 17.5, 40.0):
        assert m0.to_newtons(m0.to_normalised(T)) == pytest.approx(T)
    assert m0.motor_thrust(1.0) == pytest.approx(10.0) and m0.motor_thrust(0.5) == pytest.approx(3.75)


def test_hover_check_against_mpc_thr_hover():
    p = get_preset("matrice100")
    m = ThrustMap.for_params(p)
    assert m.check_hover(p.mass, 0.45, 0.05) == pytest.approx(0.441, abs=1e-3)
    with pytest.raises(ValueError, match=r"MPC_THR_HOVER=0\.700.*predicts 0\.441"):
        m.check_hover(p.mass, 0.70, 0.05)


def test_thrust_curve_parameter_is_validated():
    with pytest.raises(ValueError, match="thrust_curve"):
        get_preset("lab250").replace(thrust_curve=-0.1)
