"""``wt-inspect fly`` against a fake PX4 over real UDP sockets: the offboard rules and every safety path.

Each flight is a second or two of wall time: the fake vehicle (tests/px4_fake.py) starts at the
mission's start pose, integrates the paper's model from the runner's set-points, and follows
PX4's offboard state machine (refuses OFFBOARD without a prior set-point stream, fails safe when
the stream stops). Every test checks what the *vehicle* saw, not only what the runner says.
"""
from __future__ import annotations

import os
import signal
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymavlink")

from px4_fake import FakePX4  # noqa: E402

from wt_inspect.evaluation import load_run  # noqa: E402
from wt_inspect.evaluation.runner import make_env  # noqa: E402
from wt_inspect.evaluation.scenarios import env_options  # noqa: E402
from wt_inspect_px4.frames import Site  # noqa: E402
from wt_inspect_px4.link import HOLD_MODE, OFFBOARD_MODE, read_tlog  # noqa: E402
from wt_inspect_px4.offboard import FlightError, FlyConfig, _turbine_pose, main, run_flight  # noqa: E402
from wt_inspect_px4.safety import SafetyConfig  # noqa: E402
from wt_inspect_px4.vehicle import ATTITUDE_IGNORED, Vehicle, VehicleError  # noqa: E402

SITE = Site(heading_deg=30.0, base_ned=(10.0, -5.0, 0.0))


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.fixture(scope="module")
def world():
    """The surface mission's start state, airframe and the site frame (one env build)."""
    env = make_env(env_options("surface", 0.0))
    try:
        env.reset(seed=0)
        u = env.unwrapped
        return {"x0": u.sim.state[0].copy(), "params": u.params, "frame": SITE.frame(*_turbine_pose(u.mission)),
                "hover": u.scaling.hover_action()}
    finally:
        env.close()


class Scripted:
    """A policy from a function of the step index (and the observation)."""

    def __init__(self, env, fn):
        self.env, self.fn, self.k = env, fn, 0
        self.hover = env.scaling.hover_action()

    def reset(self, seed=None):
        self.k = 0

    def act(self, obs):
        self.k += 1
        return np.asarray(self.fn(self, obs), dtype=np.float32)


def fly(world, tmp_path, fn=None, *, fake_kw=None, during=None, policy=None, **cfg_kw):
    """One flight: the fake vehicle, the runner in this (the main) thread; ``during(fake)`` runs in
    a thread while it flies."""
    port = free_port()
    fake = FakePX4(f"udp://127.0.0.1:{port}", world["frame"], world["params"], world["x0"], **(fake_kw or {}))
    cfg = dict(connect=f"udp://:{port}", controller="scripted", site=SITE, max_time=1.0, out=str(tmp_path),
               warmup_s=0.3, hold_timeout=1.5, connect_timeout=5.0)
    cfg.update(cfg_kw)
    if policy is None:
        def policy(env):
            return Scripted(env, fn or (lambda p, obs: p.hover))
    t = None
    if during is not None:
        t = threading.Thread(target=during, args=(fake,), daemon=True)
        t.start()
    try:
        flight = run_flight(FlyConfig(**cfg), policy=policy, log=lambda m: None)
    finally:
        if t is not None:
            t.join(timeout=5)
        time.sleep(0.1)
        fake.close()
    return flight, fake


def _after(delay, action):
    def run(fake):
        while not fake.in_offboard:
            time.sleep(0.01)
        time.sleep(delay)
        action(fake)
    return run


def assert_left_offboard_with_stream(fake, flight, confirmed=True):
    """The vehicle ended in hold, entered through the runner (no PX4 failsafe), and never waited
    for a set-point in OFFBOARD longer than a tenth of a second."""
    assert fake.mode == HOLD_MODE, fake.mode_history
    assert OFFBOARD_MODE in [m for _, m in fake.mode_history]
    assert not fake.failsafe
    assert fake.max_gap_in_offboard < 0.1, fake.max_gap_in_offboard
    assert flight.hold_confirmed is confirmed
    assert fake.offboard_rejections == 0


# ------------------------------------------------------------------------------------ protocol
def test_fake_px4_refuses_offboard_without_a_setpoint_stream(world):
    port = free_port()
    fake = FakePX4(f"udp://127.0.0.1:{port}", world["frame"], world["params"], world["x0"])
    v = Vehicle(f"udp://:{port}")
    try:
        v.wait_connected(5.0)
        with pytest.raises(VehicleError, match="TEMPORARILY_REJECTED"):
            v.set_mode(OFFBOARD_MODE, timeout=1.0)
        assert fake.offboard_rejections >= 1 and not fake.in_offboard
        assert v.param("MPC_THR_HOVER") == pytest.approx(fake.hover_thrust)
    finally:
        v.close()
        fake.close()


@pytest.mark.slow
def test_a_normal_flight_streams_rates_and_thrust_then_holds(world, tmp_path):
    flight, fake = fly(world, tmp_path, fake_kw={"mode_delay_s": 0.4})
    assert flight.termination == "max_time"
    assert_left_offboard_with_stream(fake, flight)
    assert fake.max_distance_from_start < 1e-3          # hover thrust mapped exactly both ways
    res = load_run(flight.run_file)
    assert res.steps == 100 and res.arrays["position"].shape == (101, 3)
    assert res.metrics["coverage"] > 0 and res.metrics["safety_sm"] == 1.0
    msgs = [m for _, m in read_tlog(flight.tlog)]
    sat = [m for m in msgs if m.get_type() == "SET_ATTITUDE_TARGET" and m.type_mask == ATTITUDE_IGNORED]
    assert len(sat) >= 100 and all(abs(m.thrust - fake.hover_thrust) < 1e-6 for m in sat)
    assert sum(m.get_type() == "ODOMETRY" for m in msgs) > 50
    kinds = {m.get_type() for m in msgs}
    assert {"COMMAND_LONG", "COMMAND_ACK", "HEARTBEAT", "PARAM_VALUE"} <= kinds


@pytest.mark.slow
def test_state_from_local_position_and_attitude_quaternion(world, tmp_path):
    flight, fake = fly(world, tmp_path, fake_kw={"odometry": False}, max_time=0.5)
    assert flight.termination == "max_time"
    res = load_run(flight.run_file)
    assert np.allclose(res.arrays["position"][0], world["x0"][0:3], atol=1e-3)


@pytest.mark.slow
def test_body_rate_command_reaches_the_vehicle_in_frd(world, tmp_path):
    """A positive FLU yaw rate (counter-clockwise) must arrive as a negative FRD yaw rate."""
    def yaw_left(p, obs):
        a = p.hover.copy()
        a[2] = p.env.scaling.to_action([0, 0, 0.3, p.env.scaling.hover_thrust])[2]
        return a
    flight, fake = fly(world, tmp_path, yaw_left, max_time=0.5)
    msgs = [m for _, m in read_tlog(flight.tlog) if m.get_type() == "SET_ATTITUDE_TARGET"
            and m.type_mask == ATTITUDE_IGNORED]
    assert msgs and all(m.body_yaw_rate == pytest.approx(-0.3, abs=1e-3) for m in msgs)
    res = load_run(flight.run_file)
    assert res.arrays["quaternion"][-1][2] > 0.02       # the project's yaw grew (qz > 0)


# ------------------------------------------------------------------------------------ safety
@pytest.mark.slow
def test_geofence_box_floor(world, tmp_path):
    z0 = world["x0"][2]
    def sink(p, obs):
        return [p.hover[0], p.hover[1], p.hover[2], -1.0]                 # least thrust: it sinks
    flight, fake = fly(world, tmp_path, sink, max_time=2.0, safety=SafetyConfig(min_altitude=z0 - 0.3))
    assert flight.termination == "hold:geofence_box"
    assert_left_offboard_with_stream(fake, flight)


@pytest.mark.slow
def test_geofence_clearance_to_the_mesh(world, tmp_path):
    """Pitch towards the blade (the drone faces it): the clearance falls below the limit."""
    def forward(p, obs):
        a = p.hover.copy()
        if p.k < 40:
            a[1] = p.env.scaling.to_action([0, 0.8, 0, p.env.scaling.hover_thrust])[1]
        a[3] = p.env.scaling.to_action([0, 0, 0, 1.15 * p.env.scaling.hover_thrust])[3]
        return a
    flight, fake = fly(world, tmp_path, forward, max_time=3.0,
                       safety=SafetyConfig(min_clearance=6.8, max_speed=50.0))
    assert flight.termination == "hold:geofence_clearance"
    assert_left_offboard_with_stream(fake, flight)


def test_max_speed(world, tmp_path):
    def sink(p, obs):
        return [p.hover[0], p.hover[1], p.hover[2], -1.0]

    flight, fake = fly(world, tmp_path, sink, max_time=2.0, safety=SafetyConfig(max_speed=0.5, min_altitude=0.0))
    assert flight.termination == "hold:max_speed"
    res = load_run(flight.run_file)
    assert abs(res.arrays["velocity_body"][-1][2]) > 0.5
    assert_left_offboard_with_stream(fake, flight)


@pytest.mark.slow
def test_stale_state_holds(world, tmp_path):
    flight, fake = fly(world, tmp_path, during=_after(0.3, lambda f: setattr(f, "silence_state", True)),
                       max_time=3.0)
    assert flight.termination == "hold:stale_state"
    assert_left_offboard_with_stream(fake, flight)


@pytest.mark.slow
def test_link_loss_holds_and_keeps_streaming(world, tmp_path):
    """Nothing comes back: the runner holds; the hold request reaches the vehicle (its uplink still
    works) but cannot be confirmed, and the stream never starved it while in OFFBOARD."""
    flight, fake = fly(world, tmp_path, during=_after(0.3, lambda f: setattr(f, "silence_all", True)),
                       max_time=3.0)
    assert flight.termination == "hold:link_lost"
    assert_left_offboard_with_stream(fake, flight, confirmed=False)


def test_policy_exception_holds(world, tmp_path):
    def boom(p, obs):
        if p.k > 20:
            raise RuntimeError("solver blew up")
        return p.hover
    flight, fake = fly(world, tmp_path, boom, max_time=2.0)
    assert flight.termination == "hold:policy_exception"
    assert "solver blew up" in flight.summary["policy_error"]
    assert_left_offboard_with_stream(fake, flight)


@pytest.mark.slow
@pytest.mark.parametrize("bad, reason", [(np.nan, "non_finite_command"), (3.0, "command_out_of_range")])
def test_invalid_command_holds(world, tmp_path, bad, reason):
    flight, fake = fly(world, tmp_path, lambda p, obs: p.hover if p.k < 20 else [0, 0, bad, 0], max_time=2.0)
    assert flight.termination == f"hold:{reason}"
    sat = [m for _, m in read_tlog(flight.tlog) if m.get_type() == "SET_ATTITUDE_TARGET"]
    assert all(np.isfinite(m.thrust) and np.isfinite(m.body_yaw_rate) for m in sat)
    assert_left_offboard_with_stream(fake, flight)


@pytest.mark.slow
def test_hung_policy_is_covered_by_the_streamer(world, tmp_path):
    """A policy that stops for 0.5 s: set-points keep flowing (keep-alive), the streamer switches to
    the hold set-point by itself and the flight ends in hold."""
    def hang(p, obs):
        if p.k == 20:
            time.sleep(0.5)
        return p.hover
    flight, fake = fly(world, tmp_path, hang, max_time=2.0)
    assert flight.termination == "hold:policy_timeout"
    assert flight.summary["stream"]["keepalive"] > 10
    assert_left_offboard_with_stream(fake, flight)


@pytest.mark.slow
def test_sigint_leaves_offboard_into_hold(world, tmp_path):
    def interrupt(fake):
        while not fake.in_offboard:
            time.sleep(0.01)
        time.sleep(0.3)
        os.kill(os.getpid(), signal.SIGINT)
    before = signal.getsignal(signal.SIGINT)
    flight, fake = fly(world, tmp_path, during=interrupt, max_time=3.0)
    assert flight.termination == "hold:operator_abort"
    assert signal.getsignal(signal.SIGINT) is before        # the handler is the runner's only while flying
    assert_left_offboard_with_stream(fake, flight)


def test_px4_failsafe_is_what_happens_without_our_stream(world):
    """The fake's side of the rule the runner obeys: OFFBOARD without set-points fails safe."""
    port = free_port()
    fake = FakePX4(f"udp://127.0.0.1:{port}", world["frame"], world["params"], world["x0"], offboard_loss_s=0.2)
    v = Vehicle(f"udp://:{port}")
    try:
        v.wait_connected(5.0)
        v.start_stream(v.hold_setpoint(0.44))
        time.sleep(0.2)
        v.set_mode(OFFBOARD_MODE)
        v._streaming.clear()          # what the runner never does
        time.sleep(0.5)
        assert fake.failsafe and fake.mode == HOLD_MODE
    finally:
        v.close()
        fake.close()


# ------------------------------------------------------------------------------------ refusals
def test_refuses_a_vehicle_far_from_the_start(world, tmp_path):
    x0 = world["x0"].copy()
    x0[0] += 5.0
    w = dict(world, x0=x0)
    with pytest.raises(FlightError, match=r"5\.00 m from the mission's start pose"):
        fly(w, tmp_path)


def test_refuses_a_preset_that_disagrees_with_mpc_thr_hover(world, tmp_path):
    with pytest.raises(ValueError, match="MPC_THR_HOVER=0.650"):
        fly(world, tmp_path, fake_kw={"hover_thrust": 0.65})


@pytest.mark.slow
def test_refuses_a_disarmed_vehicle_unless_asked_to_arm(world, tmp_path):
    with pytest.raises(FlightError, match="not armed"):
        fly(world, tmp_path, fake_kw={"armed": False})
    flight, fake = fly(world, tmp_path, fake_kw={"armed": False}, arm=True, max_time=0.3)
    assert fake.armed and flight.termination == "max_time"


@pytest.mark.slow
def test_geodetic_site_uses_the_vehicle_origin(world, tmp_path):
    from wt_inspect_px4.frames import ned_to_geodetic
    origin = (47.397742, 8.545594, 488.0)
    site = Site(heading_deg=SITE.heading_deg, base_lla=ned_to_geodetic(SITE.base_ned, origin))
    flight, fake = fly(world, tmp_path, site=site, max_time=0.3)
    assert flight.termination == "max_time"
    assert np.allclose(flight.summary["frame"]["base_ned"], SITE.base_ned, atol=1e-4)


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["--connect", "udp:14540", "--controller", "vtnmpc", "--site", "{}"]) == 2
    assert "--connect must look like udp://:14540" in capsys.readouterr().err
    assert main(["--connect", "udp://:14540", "--controller", "nosuch", "--site", "{}"]) == 2
    assert "unknown controller 'nosuch'" in capsys.readouterr().err
    assert main(["--connect", "udp://:14540", "--controller", "vtnmpc", "--site", '{"heading_deg": 0}']) == 2
    assert "exactly one of base_ned" in capsys.readouterr().err


def test_fly_and_sitl_have_help():
    from wt_inspect.cli import main as cli
    for cmd in ("fly", "sitl"):
        with pytest.raises(SystemExit) as exc:
            cli([cmd, "--help"])
        assert exc.value.code == 0
    assert Path(__file__).name.startswith("test_px4")


@pytest.mark.slow
@pytest.mark.parametrize("cmd", ["fly", "sitl"])
def test_without_the_px4_extra_the_commands_say_what_to_install(cmd):
    import subprocess
    import sys
    code = ("import sys; sys.modules['pymavlink'] = None; from wt_inspect.cli import main; "
            "sys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", code, cmd, "--help"], capture_output=True, text=True, timeout=120)
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("pybullet build time")]
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "pymavlink" in lines[0] and "wt-inspect[px4]" in lines[0]
