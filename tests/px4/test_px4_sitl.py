"""``wt-inspect sitl``: the HIL simulator side, driven by a scripted PX4 client over a real TCP socket."""
from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from wt_inspect_px4.frames import Site  # noqa: E402
from wt_inspect_px4.link import MavlinkLink  # noqa: E402
from wt_inspect_px4.offboard import _turbine_pose  # noqa: E402
from wt_inspect_px4.sitl import HilConfig, HilVehicle, SensorNoise, SitlServer, build_world, main, px4_parameters  # noqa: E402
from wt_inspect_px4.thrust import inverse_curve  # noqa: E402


@pytest.fixture(scope="module")
def world():
    params, mesh, wind, mission = build_world("surface", 0.0)
    frame = Site(heading_deg=90.0, base_ned=(60.0, 0.0, 0.0)).frame(*_turbine_pose(mission))
    return params, mesh, frame


def hover_u(params):
    return inverse_curve(params.thrust_curve, params.weight / 4 / params.max_rotor_thrust)


def free_tcp_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class ScriptedPX4:
    """PX4's side of the simulator interface: connects, answers every HIL_SENSOR with
    HIL_ACTUATOR_CONTROLS (``controls``), records what arrives; ``pause`` stops answering."""

    def __init__(self, port: int, controls) -> None:
        self.controls = list(controls) + [0.0] * (16 - len(controls))
        self.sensors: list[tuple[float, int]] = []
        self.gps, self.states = [], []
        self.pause = threading.Event()
        self.link = MavlinkLink(f"tcp://127.0.0.1:{port}", system_id=1, component_id=1, handler=self._on)

    def _on(self, msg) -> None:
        t = msg.get_type()
        if t == "HIL_SENSOR":
            self.sensors.append((time.monotonic(), msg.time_usec, msg))
            if not self.pause.is_set():
                self.link.send(self.link.mav.hil_actuator_controls_encode(msg.time_usec, self.controls, 0, 0))
        elif t == "HIL_GPS":
            self.gps.append(msg)
        elif t == "HIL_STATE_QUATERNION":
            self.states.append(msg)


def _drain(px4: ScriptedPX4, quiet_s: float = 0.2, limit_s: float = 3.0) -> None:
    """Wait until the client's reader has taken every message the server sent before it stopped
    (the last ones can still be in flight when the server's thread returns, more so on a loaded
    machine): until nothing new has arrived for ``quiet_s``."""
    last, quiet_since, end = -1, time.monotonic(), time.monotonic() + limit_s
    while time.monotonic() < end:
        n = len(px4.sensors) + len(px4.gps) + len(px4.states)
        if n != last:
            last, quiet_since = n, time.monotonic()
        elif time.monotonic() - quiet_since > quiet_s:
            return
        time.sleep(0.02)


def serve(world, controls, steps, *, cfg=None, start_ned=(0.0, 0.0, -20.0), during=None):
    params, mesh, frame = world
    port = free_tcp_port()
    vehicle = HilVehicle(params, frame, cfg or HilConfig(speed=0.0), obstacles=mesh, start_ned=start_ned)
    server = SitlServer(vehicle, f"tcp://:{port}", actuator_timeout=2.0, accept_timeout=5.0)
    out = {}
    th = threading.Thread(target=lambda: out.setdefault("steps", server.run(max_steps=steps)), daemon=True)
    th.start()
    time.sleep(0.05)
    px4 = ScriptedPX4(port, controls)
    try:
        if during is not None:
            during(px4, vehicle)
        th.join(timeout=30)
        _drain(px4)
    finally:
        px4.link.close()
        server.close()
    return out.get("steps"), px4, vehicle


def test_lockstep_sensor_timing_and_rates(world):
    params = world[0]
    steps, px4, vehicle = serve(world, [hover_u(params)] * 4, 500)
    assert steps == 500
    t = np.array([s[1] for s in px4.sensors])
    assert len(t) == 501 and np.all(np.diff(t) == 4000)       # 250 Hz on the simulator clock, monotonic
    assert len(px4.gps) == 21 and len(px4.states) == 101      # 10 Hz and 50 Hz of 2 s simulated
    assert all(np.diff([g.time_usec for g in px4.gps]) == 100000)
    z = px4.sensors[-1][2]
    assert z.zacc == pytest.approx(-9.81, abs=0.1) and abs(z.xacc) < 0.05        # hover: specific force -g
    assert z.fields_updated == 0x1FFF
    vehicle.close()


def test_the_world_waits_for_px4(world):
    """Lock-step: while PX4 withholds its actuator controls, no new sensor step is simulated."""
    params = world[0]

    def pause(px4, vehicle):
        while len(px4.sensors) < 50:
            time.sleep(0.005)
        px4.pause.set()
        time.sleep(0.05)
        n = len(px4.sensors)
        k = vehicle.steps
        time.sleep(0.3)
        assert len(px4.sensors) == n and vehicle.steps == k
        px4.pause.clear()
        px4.link.send(px4.link.mav.hil_actuator_controls_encode(0, px4.controls, 0, 0))

    steps, px4, vehicle = serve(world, [hover_u(params)] * 4, 200, during=pause)
    assert steps == 200
    vehicle.close()


@pytest.mark.parametrize("output, roll, pitch, yaw", [
    (0, -1, +1, -1),     # PX4 output 0 = front right (preset rotor 3, CW): roll left, nose up, yaw left
    (1, +1, -1, -1),     # back left (rotor 1, CW)
    (2, +1, +1, +1),     # front left (rotor 0, CCW)
    (3, -1, -1, +1),     # back right (rotor 2, CCW)
])
def test_actuator_controls_drive_the_right_motor(world, output, roll, pitch, yaw):
    params, mesh, frame = world
    u = hover_u(params)
    controls = [u] * 4
    controls[output] = 1.15 * u
    steps, px4, vehicle = serve(world, controls, 25)
    g = px4.sensors[-1][2]
    assert np.sign(g.xgyro) == roll and np.sign(g.ygyro) == pitch and np.sign(g.zgyro) == yaw
    vehicle.close()


def test_motors_off_the_vehicle_rests_on_the_ground(world):
    steps, px4, vehicle = serve(world, [0.0] * 4, 250, start_ned=(0.0, 0.0, 0.0))
    g = px4.sensors[-1][2]
    assert g.zacc == pytest.approx(-9.81, abs=0.2)         # the ground holds it: specific force -g, no fall
    assert abs(px4.states[-1].vz) < 5                       # cm/s
    vehicle.close()


def test_sensor_noise_is_configurable_and_seeded(world):
    params, mesh, frame = world
    from pymavlink.dialects.v20 import common as mavlink
    mav = mavlink.MAVLink(None)

    def sample(noise):
        v = HilVehicle(params, frame, HilConfig(noise=noise), start_ned=(0, 0, 0))
        try:
            return np.array([[m.xgyro, m.zacc] for m in (v.sensor_message(mav) for _ in range(200))])
        finally:
            v.close()
    exact, a, b = sample(SensorNoise()), sample(SensorNoise(gyro=0.01, accel=0.1, seed=3)), \
        sample(SensorNoise(gyro=0.01, accel=0.1, seed=3))
    assert np.ptp(exact, axis=0).max() == 0
    assert np.std(a[:, 0]) == pytest.approx(0.01, rel=0.25) and np.std(a[:, 1]) == pytest.approx(0.1, rel=0.25)
    assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="noise gyro"):
        SensorNoise(gyro=-1.0)


def test_gps_is_the_local_position_through_the_projection(world):
    params, mesh, frame = world
    from pymavlink.dialects.v20 import common as mavlink
    v = HilVehicle(params, frame, HilConfig(), start_ned=(100.0, 0.0, -30.0))
    try:
        g = v.gps_message(mavlink.MAVLink(None))
        lat0 = HilConfig().origin[0]
        assert (g.lat / 1e7 - lat0) == pytest.approx(math.degrees(100.0 / 6371000.0), rel=1e-3)
        assert g.alt / 1e3 == pytest.approx(HilConfig().origin[2] + 30.0, abs=1e-3)
    finally:
        v.close()


def test_px4_parameters_match_the_preset_geometry(world):
    params = world[0]
    lines = dict(line.split()[2:4] for line in px4_parameters(params))
    assert float(lines["CA_ROTOR0_PX"]) > 0 and float(lines["CA_ROTOR0_PY"]) > 0   # output 0: front right (FRD)
    assert float(lines["CA_ROTOR0_KM"]) < 0                                         # preset rotor 3 spins CW
    assert float(lines["MPC_THR_HOVER"]) == pytest.approx(0.441, abs=1e-3)


def test_sitl_cli(capsys):
    assert main(["--site", '{"base_ned": [60, 0, 0], "heading_deg": 90}', "--print-params"]) == 0
    assert "CA_ROTOR3_KM" in capsys.readouterr().out
    assert main(["--site", '{"heading_deg": 90}']) == 2
    assert "exactly one of base_ned" in capsys.readouterr().err
    assert main(["--site", '{"base_ned": [60, 0, 0], "heading_deg": 90}', "--noise", '{"gyr": 1}']) == 2
    assert "gyr" in capsys.readouterr().err
