"""``wt-inspect sitl``: the simulator side of PX4's simulator MAVLink interface, in our world.

PX4 SITL (``make px4_sitl none_iris`` style builds, ``simulator_mavlink``) connects to its simulator
over TCP port 4560 and expects, per physics step, HIL_SENSOR (IMU, magnetometer, barometer),
HIL_GPS at the GPS rate and - for ground truth - HIL_STATE_QUATERNION; it answers every sensor
message with HIL_ACTUATOR_CONTROLS (normalised motor commands). In lock-step the simulator does
not advance until the answer has arrived, and PX4's clock is the simulator's ``time_usec``: this
module runs that loop with the project's turbine, wind and rigid-body physics, so PX4's own
estimator, rate controller and mixer fly against our world (the paper's Gazebo setup, our world).

Example (PX4 built on another machine; see docs/px4.md for the whole procedure)::

    wt-inspect sitl --px4 tcp://:4560 --scenario surface --wind 4 \\
        --site '{"base_ned": [60, 0, 0], "heading_deg": 90}' --print-params

Physics through the public simulator interface only: PX4's motor commands ``u`` become rotor
thrusts through the preset's thrust curve (:class:`~.thrust.ThrustMap`) and first-order motor lag;
the airframe's mixer matrix (``QuadrotorParams.mixer``) gives collective thrust and body torques;
the rotational dynamics ``J w' = tau - w x J w`` are integrated here, and the simulator
(:class:`~wt_inspect_env.world.sim.QuadrotorSim` with ``rate_loop=False``, one physics step per
lock-step) carries the body with those rates, the collective thrust, drag, wind, ground and
turbine contacts. The motor order is PX4's output order mapped onto the preset's rotors
(``motor_map``); ``--print-params`` prints the PX4 geometry parameters (CA_ROTORn_*) that make
PX4's control allocation match the preset, spin directions included.

Sensors (body FRD): specific force from the velocity change over the step, gyro = body rates,
magnetometer = an earth field rotated into the body, barometer from the ISA atmosphere, GPS from
PX4's map projection about ``origin``; Gaussian noise of configurable size on each (seeded).
"""
from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from wt_inspect.commands.args import json_object
from wt_inspect.evaluation.scenarios import SCENARIOS, WIND_TYPES, env_options
from wt_inspect_env.physics.quadrotor import GRAVITY, QuadrotorParams
from wt_inspect_env.physics.wind import make_wind
from wt_inspect_env.task.env_config import EnvConfig
from wt_inspect_env.task.mission import build_mission
from wt_inspect_env.util.validation import check_positive, check_unknown_options
from wt_inspect_env.world.sim import QuadrotorSim, SimConfig

from .frames import F_FRD_FLU, Site, SiteFrame, ned_to_geodetic, quat_wxyz_to_matrix
from .link import MavlinkLink, mavlink
from .thrust import ThrustMap

PX4_DEFAULT_HOME = (47.397742, 8.545594, 488.0)   # PX4 SITL's default home (PX4_HOME_LAT/LON/ALT)
# PX4's quad-X output order is front-right, back-left, front-left, back-right; the preset's rotors
# sit at 45 + 90 i deg (FLU): 0 front-left, 1 back-left, 2 back-right, 3 front-right.
QUAD_X_MOTOR_MAP = (3, 1, 0, 2)
HIL_SENSOR_ALL = 0x1FFF          # accel, gyro, mag (bits 0-8), abs/diff pressure, altitude, temperature


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the white noise added to each sensor (0 = exact): ``accel`` [m/s^2],
    ``gyro`` [rad/s], ``mag`` [gauss], ``baro`` [hPa], ``gps_pos`` [m], ``gps_vel`` [m/s]; ``seed``."""

    accel: float = 0.0
    gyro: float = 0.0
    mag: float = 0.0
    baro: float = 0.0
    gps_pos: float = 0.0
    gps_vel: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("accel", "gyro", "mag", "baro", "gps_pos", "gps_vel"):
            check_positive(f"noise {name}", getattr(self, name), allow_zero=True)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "SensorNoise":
        """The noise settings from a JSON object (unknown keys are an error)."""
        check_unknown_options("noise", data.keys(), ("accel", "gyro", "mag", "baro", "gps_pos", "gps_vel", "seed"))
        return cls(**dict(data))


@dataclass(frozen=True)
class HilConfig:
    """The simulator side's options (see the module docstring). ``rate_hz``: physics / lock-step
    rate; ``gps_hz`` / ``state_hz``: HIL_GPS / HIL_STATE_QUATERNION rates in simulated time;
    ``motor_map[i]``: the preset rotor PX4 output ``i`` drives; ``mag_ned`` [gauss]; ``speed``:
    wall-clock pacing (1 = real time, 0 = as fast as PX4 answers)."""

    rate_hz: float = 250.0
    gps_hz: float = 10.0
    state_hz: float = 50.0
    motor_map: tuple[int, int, int, int] = QUAD_X_MOTOR_MAP
    origin: tuple[float, float, float] = PX4_DEFAULT_HOME
    mag_ned: tuple[float, float, float] = (0.21, 0.01, 0.43)
    noise: SensorNoise = field(default_factory=SensorNoise)
    speed: float = 1.0

    def __post_init__(self) -> None:
        for name in ("rate_hz", "gps_hz", "state_hz"):
            check_positive(name, getattr(self, name))
        check_positive("speed", self.speed, allow_zero=True)
        if sorted(self.motor_map) != [0, 1, 2, 3]:
            raise ValueError(f"motor_map must be a permutation of 0..3, got {self.motor_map!r}")


class HilVehicle:
    """The simulated vehicle: PX4 motor commands in, sensor messages out (no sockets: the lock-step
    server :class:`SitlServer` drives it, the tests drive it directly too)."""

    def __init__(self, params: QuadrotorParams, frame: SiteFrame, config: HilConfig, *, wind: Any = None,
                 obstacles: Any = None, start_ned: Sequence[float] = (0.0, 0.0, 0.0), yaw_ned: float = 0.0) -> None:
        self.params, self.frame, self.config = params, frame, config
        self.dt = 1.0 / config.rate_hz
        self.thrust = ThrustMap.for_params(params)
        # One physics step per lock-step, rates imposed (the rotational dynamics are integrated here).
        self.sim = QuadrotorSim(params, SimConfig(ctrl_hz=config.rate_hz, physics_hz=config.rate_hz, rate_loop=False,
                                                  motor_lag=False), wind=wind, obstacles=obstacles)
        self.A = np.asarray(params.mixer, float)
        self.J = np.asarray(params.inertia, float)
        tau = params.motor_time_constant
        self.alpha = 1.0 - math.exp(-self.dt / tau) if tau > 0 else 1.0
        self.rng = np.random.default_rng(config.noise.seed)
        self.f = np.zeros(4)
        self.f_cmd = np.zeros(4)
        self.omega = np.zeros(3)
        self.steps = 0
        p_w = frame.position_to_project(np.asarray(start_ned, float))
        p_w[2] = max(p_w[2], 0.5 * params.frame_height + 1e-3)      # resting on the ground
        q_w = frame.attitude_to_project([math.cos(yaw_ned / 2), 0.0, 0.0, math.sin(yaw_ned / 2)])
        self.sim.reset(np.concatenate([p_w, np.zeros(3), q_w]))
        self._v_prev = self.sim.world_velocity
        self.accel_w = np.zeros(3)

    @property
    def time_usec(self) -> int:
        """Simulated time [us] since the start, the timestamp of the HIL messages."""
        return int(round(self.steps * self.dt * 1e6))

    def apply(self, controls: Sequence[float]) -> None:
        """HIL_ACTUATOR_CONTROLS ``controls`` (PX4 outputs, motors in [0, 1]) -> rotor thrust commands."""
        for i, rotor in enumerate(self.config.motor_map):
            u = float(controls[i])
            self.f_cmd[rotor] = self.thrust.motor_thrust(u if math.isfinite(u) else 0.0)

    def step(self) -> None:
        """One physics step: motor lag, mixer wrench, rotational dynamics, then the simulator."""
        self.f += self.alpha * (self.f_cmd - self.f)
        wrench = self.A @ self.f
        T, tau = float(wrench[0]), wrench[1:4]
        w0 = self.omega
        wdot = (tau - np.cross(w0, self.J * w0)) / self.J
        w1 = w0 + self.dt * wdot
        self.omega = w1
        self.sim.step(np.append(0.5 * (w0 + w1), max(T, 0.0)))
        if self.sim.in_collision:          # on the ground or touching: contacts stop the spin
            self.omega = self.sim.body_rates
        v = self.sim.world_velocity
        self.accel_w = (v - self._v_prev) / self.dt
        self._v_prev = v
        self.steps += 1

    # ------------------------------------------------------------------ sensors
    def _ned(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x = self.sim.state
        p = self.frame.position_to_ned(x[0:3])
        q = self.frame.attitude_to_ned(x[6:10])
        v = self.frame.vector_to_ned(self.sim.world_velocity)
        return p, q, v, quat_wxyz_to_matrix(q)

    def sensor_message(self, mav: Any) -> Any:
        """HIL_SENSOR of the present state: IMU, magnetometer and barometer in PX4's frames, with noise."""
        n = self.config.noise
        rng = self.rng
        p, q, v, R = self._ned()
        acc_ned = self.frame.vector_to_ned(self.accel_w)
        specific = R.T @ (acc_ned - np.array([0.0, 0.0, GRAVITY]))        # FRD; at rest (0, 0, -g)
        gyro = F_FRD_FLU @ self.omega
        mag = R.T @ np.asarray(self.config.mag_ned, float)
        alt = self.config.origin[2] - p[2]
        pressure = 1013.25 * (1.0 - 2.25577e-5 * alt) ** 5.25588            # ISA [hPa]
        if n.accel:
            specific = specific + rng.normal(0, n.accel, 3)
        if n.gyro:
            gyro = gyro + rng.normal(0, n.gyro, 3)
        if n.mag:
            mag = mag + rng.normal(0, n.mag, 3)
        if n.baro:
            pressure += rng.normal(0, n.baro)
        return mav.hil_sensor_encode(self.time_usec, *specific.tolist(), *gyro.tolist(), *mag.tolist(),
                                     float(pressure), 0.0, float(alt), 15.0 - 0.0065 * alt, HIL_SENSOR_ALL, 0)

    def gps_message(self, mav: Any) -> Any:
        """HIL_GPS of the present state (position and velocity, with noise)."""
        n = self.config.noise
        p, _, v, _ = self._ned()
        if n.gps_pos:
            p = p + self.rng.normal(0, n.gps_pos, 3)
        if n.gps_vel:
            v = v + self.rng.normal(0, n.gps_vel, 3)
        lat, lon, alt = ned_to_geodetic(p, self.config.origin)
        speed = math.hypot(v[0], v[1])
        cog = (math.degrees(math.atan2(v[1], v[0])) % 360.0) if speed > 0.1 else 0.0
        return mav.hil_gps_encode(self.time_usec, 3, int(round(lat * 1e7)), int(round(lon * 1e7)),
                                  int(round(alt * 1e3)), 100, 100, int(speed * 100),
                                  *(int(round(c * 100)) for c in v), int(cog * 100), 10, 0, 0)

    def state_message(self, mav: Any) -> Any:
        """HIL_STATE_QUATERNION of the present state (the true state, for PX4's ground truth)."""
        p, q, v, R = self._ned()
        lat, lon, alt = ned_to_geodetic(p, self.config.origin)
        gyro = F_FRD_FLU @ self.omega
        acc = R.T @ (self.frame.vector_to_ned(self.accel_w) - np.array([0.0, 0.0, GRAVITY]))
        air = float(np.linalg.norm(self.sim.world_velocity - self.sim.wind_velocity))
        return mav.hil_state_quaternion_encode(
            self.time_usec, q.tolist(), *gyro.tolist(), int(round(lat * 1e7)), int(round(lon * 1e7)),
            int(round(alt * 1e3)), *(int(round(c * 100)) for c in v), int(air * 100), int(air * 100),
            *(int(round(a / GRAVITY * 1000)) for a in acc))

    def close(self) -> None:
        """Close the simulator."""
        self.sim.close()


class SitlServer:
    """The lock-step loop over a :class:`~.link.MavlinkLink` (see the module docstring).

    Until PX4's first HIL_ACTUATOR_CONTROLS the world free-runs at ``speed`` (PX4 is booting and
    needs sensors to start its clock); after it, each step waits for a new actuator message
    (``actuator_timeout`` of wall time; then the loop ends: PX4 has gone)."""

    def __init__(self, vehicle: HilVehicle, endpoint: str, *, actuator_timeout: float = 10.0,
                 accept_timeout: float = 60.0, tlog: Any = None) -> None:
        self.vehicle = vehicle
        self.actuator_timeout = actuator_timeout
        self.accept_timeout = accept_timeout
        self._cv = threading.Condition()
        self._controls: tuple[Any, int] | None = None     # (controls, sequence number)
        self._seq = 0
        self.received = 0
        self.sent = {"HIL_SENSOR": 0, "HIL_GPS": 0, "HIL_STATE_QUATERNION": 0}
        self.link = MavlinkLink(endpoint, system_id=1, component_id=mavlink.MAV_COMP_ID_USER1,
                                handler=self._on_message, tlog=tlog, accept_timeout=accept_timeout)
        self._stop = threading.Event()

    def _on_message(self, msg: Any) -> None:
        if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
            with self._cv:
                self._seq += 1
                self.received += 1
                self._controls = (list(msg.controls), self._seq)
                self._cv.notify_all()

    def stop(self) -> None:
        """Ask the loop to end (from another thread); it stops at its next step."""
        self._stop.set()

    def _send_sensors(self) -> None:
        v, mav = self.vehicle, self.link.mav
        cfg = v.config
        k = v.steps
        self.link.send(v.sensor_message(mav))
        self.sent["HIL_SENSOR"] += 1
        if k % max(1, int(round(cfg.rate_hz / cfg.gps_hz))) == 0:
            self.link.send(v.gps_message(mav))
            self.sent["HIL_GPS"] += 1
        if k % max(1, int(round(cfg.rate_hz / cfg.state_hz))) == 0:
            self.link.send(v.state_message(mav))
            self.sent["HIL_STATE_QUATERNION"] += 1
        if k % int(round(cfg.rate_hz)) == 0:
            self.link.send(mav.heartbeat_encode(mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))

    def run(self, max_steps: int | None = None) -> int:
        """Run until ``max_steps``, :meth:`stop` or PX4 going silent; returns the steps simulated."""
        deadline = time.monotonic() + self.accept_timeout
        while not self.link.connected:
            if self._stop.is_set() or time.monotonic() > deadline:
                return 0
            time.sleep(0.01)
        v = self.vehicle
        speed = v.config.speed
        t_wall0 = time.monotonic()
        last_seq = 0
        self._send_sensors()
        while not self._stop.is_set() and (max_steps is None or v.steps < max_steps):
            with self._cv:
                if self._controls is None:           # PX4 not answering yet: free-run
                    self._cv.wait(v.dt / max(speed, 1e-3) if speed else v.dt)
                else:
                    ok = self._cv.wait_for(lambda last_seq=last_seq: self._controls[1] != last_seq
                                           or self._stop.is_set(),
                                           self.actuator_timeout)
                    if not ok:
                        break                        # PX4 has gone
                current = self._controls
            if current is not None:
                if current[1] != last_seq:
                    v.apply(current[0])
                last_seq = current[1]
            v.step()
            if speed:
                lag = t_wall0 + v.steps * v.dt / speed - time.monotonic()
                if lag > 0:
                    time.sleep(lag)
            self._send_sensors()
        return v.steps

    def close(self) -> None:
        """Close the MAVLink link."""
        self.link.close()


def build_world(scenario: str, wind: float, wind_type: str = "gust", turbine: Mapping[str, Any] | None = None,
                drone: str | None = None, overrides: Mapping[str, Any] | None = None
                ) -> tuple[QuadrotorParams, Any, Any, Any]:
    """(airframe, phase-1 turbine mesh, wind field, mission) of a scenario, as the environment builds them."""
    opts = env_options(scenario, wind, wind_type=wind_type, turbine=turbine, drone=drone, overrides=overrides)
    cfg = EnvConfig.from_kwargs(**opts)
    mission = build_mission(cfg)
    wind_field = make_wind(cfg.wind)
    wind_field.reset(0)
    return cfg.drone, mission.turbines[0].mesh, wind_field, mission


def px4_parameters(params: QuadrotorParams, motor_map: Sequence[int] = QUAD_X_MOTOR_MAP) -> list[str]:
    """PX4 parameter lines (``param set NAME VALUE``) that make PX4's control allocation and thrust
    model match the preset: rotor positions in FRD, moment coefficients (positive = CCW seen from
    above, as PX4 documents CA_ROTORn_KM), THR_MDL_FAC, and the hover thrust."""
    pos = params.rotor_positions
    lines = ["param set CA_AIRFRAME 0", "param set CA_ROTOR_COUNT 4"]
    for i, rotor in enumerate(motor_map):
        x, y, _ = F_FRD_FLU @ pos[rotor]
        lines += [f"param set CA_ROTOR{i}_PX {x:.4f}", f"param set CA_ROTOR{i}_PY {y:.4f}",
                  f"param set CA_ROTOR{i}_KM {params.rotor_spin[rotor] * params.torque_coeff:.4f}"]
    thrust = ThrustMap.for_params(params)
    lines += [f"param set THR_MDL_FAC {params.thrust_curve:.3f}",
              f"param set MPC_THR_HOVER {thrust.to_normalised(params.weight):.3f}"]
    return lines


def main(argv: list[str], prog: str = "wt-inspect sitl") -> int:
    """``wt-inspect sitl``: be the simulator side of PX4's SITL with the options in ``argv``."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[9:13]))
    ap.add_argument("--px4", default="tcp://:4560", metavar="URL", help="PX4's simulator port (default tcp://:4560: "
                    "listen, PX4 SITL connects)")
    ap.add_argument("--site", required=True, metavar="JSON|FILE", help="where the turbine stands (as for fly)")
    ap.add_argument("--scenario", default="surface", choices=list(SCENARIOS))
    ap.add_argument("--wind", type=float, default=0.0, metavar="M/S", help="mean wind speed (default 0)")
    ap.add_argument("--wind-type", default="gust", choices=WIND_TYPES)
    ap.add_argument("--turbine", type=json_object("--turbine"), default={}, metavar="JSON")
    ap.add_argument("--drone", metavar="PRESET")
    ap.add_argument("--rate", type=float, default=250.0, metavar="HZ", help="lock-step physics rate (default 250)")
    ap.add_argument("--speed", type=float, default=1.0, help="wall-clock pacing, 0 = as fast as PX4 runs (default 1)")
    ap.add_argument("--noise", type=json_object("--noise"), default={}, metavar="JSON",
                    help='sensor noise std: {"accel": 0.05, "gyro": 0.005, "mag": 0.001, "baro": 0.01, '
                         '"gps_pos": 0.3, "gps_vel": 0.05, "seed": 0}')
    ap.add_argument("--home", type=float, nargs=3, metavar=("LAT", "LON", "ALT"), default=list(PX4_DEFAULT_HOME),
                    help="geodetic origin of PX4's local frame (default PX4 SITL's home)")
    ap.add_argument("--start-ned", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar=("N", "E", "D"),
                    help="where the vehicle stands at the start, local NED (default the origin)")
    ap.add_argument("--max-time", type=float, metavar="S", help="stop after S simulated seconds")
    ap.add_argument("--tlog", metavar="FILE", help="write the raw MAVLink log here")
    ap.add_argument("--print-params", action="store_true", help="print the PX4 parameters matching the preset and exit")
    args = ap.parse_args(argv)
    try:
        site = Site.parse(args.site)
        params, mesh, wind, mission = build_world(args.scenario, args.wind, args.wind_type, args.turbine, args.drone)
        if args.print_params:
            print("\n".join(px4_parameters(params)))
            return 0
        cfg = HilConfig(rate_hz=args.rate, speed=args.speed, origin=tuple(args.home),
                        noise=SensorNoise.from_mapping(args.noise))
        from .offboard import _turbine_pose
        frame = site.frame(*_turbine_pose(mission), origin=cfg.origin)
        vehicle = HilVehicle(params, frame, cfg, wind=wind, obstacles=mesh, start_ned=args.start_ned)
        server = SitlServer(vehicle, args.px4, tlog=args.tlog)
    except (ValueError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"{prog}: waiting for PX4 on {args.px4} (lock-step at {args.rate:g} Hz) ...", file=sys.stderr)
    try:
        steps = server.run(None if args.max_time is None else int(round(args.max_time * args.rate)))
    except KeyboardInterrupt:
        steps = vehicle.steps
    finally:
        server.close()
        vehicle.close()
    print(f"{prog}: {steps} steps ({steps / args.rate:.1f} s simulated), {server.received} actuator messages, "
          f"sent {server.sent}")
    return 0
