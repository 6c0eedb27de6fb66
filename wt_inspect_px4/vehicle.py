"""One PX4 vehicle over MAVLink: its state, its commands, and the set-point stream PX4's offboard mode needs.

PX4's offboard rules (PX4 user guide, "Offboard Mode"), which this class follows:

* the vehicle accepts OFFBOARD only while set-points arrive faster than 2 Hz, so the stream starts
  *before* the mode request (:meth:`Vehicle.start_stream`, then :meth:`Vehicle.set_mode`);
* once in OFFBOARD the stream must not stop: if set-points stop for ``COM_OF_LOSS_T`` PX4 falls
  back to its failsafe. A streamer thread re-sends the current set-point whenever the control loop
  has not sent one for 1.5 periods, so a slow policy step never starves the stream; and if the
  control loop has not produced a *new* command for ``command_timeout`` (a hung policy), the
  streamer replaces it by the hold set-point (level, current heading, hover thrust) and raises the
  abort - a stale body-rate command must not keep turning the vehicle;
* arming and mode switches go through COMMAND_LONG (MAV_CMD_COMPONENT_ARM_DISARM,
  MAV_CMD_DO_SET_MODE) and count only when the COMMAND_ACK says ACCEPTED (retried on silence);
* the way out is the hold mode (AUTO.LOITER), requested while the stream goes on, and the stream
  stops only once the HEARTBEAT shows the vehicle has left OFFBOARD.

State comes from ODOMETRY (pose in LOCAL_NED, velocity in BODY_FRD or LOCAL_NED as its
``child_frame_id`` says) or, for autopilots that do not stream it, from LOCAL_POSITION_NED +
ATTITUDE_QUATERNION (body rates from ATTITUDE_QUATERNION, or HIGHRES_IMU's gyro when that is newer).
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .frames import quat_wxyz_to_matrix
from .link import HOLD_MODE, OFFBOARD_MODE, LinkFaults, MavlinkLink, mavlink, px4_main_mode

ATTITUDE_IGNORED = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE            # rates + thrust used
RATES_IGNORED = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
                 | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
                 | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)      # attitude + thrust used


class VehicleError(RuntimeError):
    """The vehicle refused or did not answer (the message says which command and what came back)."""


@dataclass
class VehicleState:
    """The latest estimate, in PX4's frames: position / velocity NED [m, m/s], quaternion (w, x,
    y, z) FRD -> NED, body rates FRD [rad/s]; ``received`` = monotonic time it arrived."""

    position_ned: np.ndarray
    velocity_ned: np.ndarray
    q_wxyz: np.ndarray
    rates_frd: np.ndarray
    time_usec: int
    received: float

    @property
    def yaw(self) -> float:
        """Heading [rad] of the vehicle, from its quaternion (NED: 0 = north)."""
        w, x, y, z = self.q_wxyz
        return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@dataclass
class _Parts:
    """The separate messages' latest values (LOCAL_POSITION_NED + ATTITUDE_QUATERNION route)."""

    pos: tuple | None = None
    att: tuple | None = None
    gyro: tuple | None = None


@dataclass(frozen=True)
class Setpoint:
    """One SET_ATTITUDE_TARGET: body rates FRD [rad/s] + normalised thrust (attitude ignored), or
    an attitude (w, x, y, z) + thrust (rates ignored) for the hold set-point."""

    thrust: float
    rates_frd: tuple[float, float, float] = (0.0, 0.0, 0.0)
    q_wxyz: tuple[float, float, float, float] | None = None


@dataclass
class _Heartbeat:
    custom_mode: int = 0
    armed: bool = False
    received: float = 0.0


@dataclass
class StreamStats:
    """What the streamer did (reported in the flight summary)."""

    sent: int = 0
    keepalive: int = 0
    max_gap_s: float = 0.0
    last_sent: float = 0.0
    gaps: list[float] = field(default_factory=list)


class Vehicle:
    """A PX4 vehicle behind one :class:`~.link.MavlinkLink` (see the module docstring)."""

    def __init__(self, endpoint: str, *, target_system: int = 1, target_component: int = 1,
                 tlog: str | Path | None = None, rate_hz: float = 100.0, command_timeout: float = 0.1,
                 faults: LinkFaults | None = None) -> None:
        self.target = (int(target_system), int(target_component))
        self.rate_hz = float(rate_hz)
        self.command_timeout = float(command_timeout)
        self._lock = threading.Lock()
        self._state: VehicleState | None = None
        self._parts = _Parts()
        self._hb = _Heartbeat()
        self._acks: dict[int, int] = {}
        self._ack_cv = threading.Condition(self._lock)
        self._params: dict[str, float] = {}
        self.origin: tuple[float, float, float] | None = None
        self.status_texts: list[str] = []
        self._setpoint: Setpoint | None = None
        self._setpoint_fresh = 0.0          # when the control loop last gave a new command
        self._streaming = threading.Event()
        self._commanding = False            # the control loop has sent its first command
        self._abort_reason: str | None = None
        self._fallback: Setpoint | None = None
        self.stream = StreamStats()
        self._stop = threading.Event()
        self.link = MavlinkLink(endpoint, handler=self._on_message, tlog=tlog, faults=faults,
                                system_id=255, component_id=mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)
        self._streamer = threading.Thread(target=self._stream_loop, name="px4-setpoints", daemon=True)
        self._streamer.start()

    # ------------------------------------------------------------------ incoming
    def _on_message(self, msg: Any) -> None:
        t = msg.get_type()
        now = time.monotonic()
        if t == "HEARTBEAT":
            if msg.get_srcSystem() != self.target[0] or msg.type == mavlink.MAV_TYPE_GCS:
                return
            with self._lock:
                self._hb = _Heartbeat(int(msg.custom_mode),
                                      bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED), now)
        elif t == "ODOMETRY":
            self._on_odometry(msg, now)
        elif t == "LOCAL_POSITION_NED":
            with self._lock:
                self._parts.pos = ((msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz))
            self._assemble(now, msg.time_boot_ms * 1000)
        elif t == "ATTITUDE_QUATERNION":
            with self._lock:
                self._parts.att = ((msg.q1, msg.q2, msg.q3, msg.q4), (msg.rollspeed, msg.pitchspeed, msg.yawspeed),
                                   now)
            self._assemble(now, msg.time_boot_ms * 1000)
        elif t == "HIGHRES_IMU":
            with self._lock:
                self._parts.gyro = ((msg.xgyro, msg.ygyro, msg.zgyro), now)
        elif t == "COMMAND_ACK":
            with self._ack_cv:
                self._acks[int(msg.command)] = int(msg.result)
                self._ack_cv.notify_all()
        elif t == "PARAM_VALUE":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            with self._ack_cv:
                self._params[name.rstrip("\x00")] = float(msg.param_value)
                self._ack_cv.notify_all()
        elif t == "GPS_GLOBAL_ORIGIN":
            with self._ack_cv:
                self.origin = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1e3)
                self._ack_cv.notify_all()
        elif t == "STATUSTEXT":
            self.status_texts.append(str(msg.text))

    def _on_odometry(self, msg: Any, now: float) -> None:
        if msg.frame_id != mavlink.MAV_FRAME_LOCAL_NED:
            return    # only a north-aligned local frame can place the turbine
        q = np.array(msg.q, dtype=float)
        v = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
        if msg.child_frame_id == mavlink.MAV_FRAME_BODY_FRD:
            v = quat_wxyz_to_matrix(q) @ v
        elif msg.child_frame_id != mavlink.MAV_FRAME_LOCAL_NED:
            return
        s = VehicleState(np.array([msg.x, msg.y, msg.z], float), v, q,
                         np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed], float), int(msg.time_usec), now)
        with self._lock:
            self._state = s

    def _assemble(self, now: float, time_usec: int) -> None:
        with self._lock:
            p, a, g = self._parts.pos, self._parts.att, self._parts.gyro
            if p is None or a is None:
                return
            rates = a[1] if g is None or g[1] < a[2] else g[0]
            self._state = VehicleState(np.array(p[0], float), np.array(p[1], float), np.array(a[0], float),
                                       np.array(rates, float), time_usec, now)

    # ------------------------------------------------------------------ queries
    def state(self) -> VehicleState | None:
        """The latest state the vehicle reported, or None before the first."""
        with self._lock:
            return self._state

    @property
    def custom_mode(self) -> int:
        """PX4's custom mode from the latest HEARTBEAT."""
        return self._hb.custom_mode

    @property
    def in_offboard(self) -> bool:
        """Whether the latest HEARTBEAT shows OFFBOARD mode."""
        return px4_main_mode(self._hb.custom_mode) == px4_main_mode(OFFBOARD_MODE) and self._hb.received > 0

    @property
    def armed(self) -> bool:
        """Whether the latest HEARTBEAT shows the vehicle armed."""
        return self._hb.armed

    def heartbeat_age(self) -> float:
        """Seconds since the latest HEARTBEAT (infinite before the first)."""
        return math.inf if self._hb.received == 0 else time.monotonic() - self._hb.received

    def wait_for(self, what: str, predicate: Any, timeout: float) -> None:
        """Wait until ``predicate()`` holds; a VehicleError naming ``what`` after ``timeout`` [s]."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise VehicleError(f"no {what} from the vehicle within {timeout:g} s")
            time.sleep(0.01)

    def wait_connected(self, timeout: float) -> None:
        """Until a HEARTBEAT and a state estimate have arrived."""
        self.wait_for(f"HEARTBEAT of system {self.target[0]} on {self.link.endpoint.kind}:{self.link.endpoint.port}",
                      lambda: self._hb.received > 0, timeout)
        self.wait_for("ODOMETRY (or LOCAL_POSITION_NED + ATTITUDE_QUATERNION)", lambda: self._state is not None,
                      timeout)

    def param(self, name: str, timeout: float = 2.0, retries: int = 3) -> float:
        """A parameter's value (PARAM_REQUEST_READ, answered by PARAM_VALUE)."""
        for _ in range(retries):
            self.link.send(self.link.mav.param_request_read_encode(*self.target, name.encode(), -1))
            with self._ack_cv:
                if self._ack_cv.wait_for(lambda: name in self._params, timeout / retries):
                    return self._params[name]
        raise VehicleError(f"parameter {name} not answered by the vehicle within {timeout:g} s")

    def request_origin(self, timeout: float = 3.0) -> tuple[float, float, float]:
        """The local frame's geodetic origin (GPS_GLOBAL_ORIGIN, asked for by MAV_CMD_REQUEST_MESSAGE)."""
        if self.origin is None:
            self.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, timeout=timeout)
            with self._ack_cv:
                if not self._ack_cv.wait_for(lambda: self.origin is not None, timeout):
                    raise VehicleError(f"no GPS_GLOBAL_ORIGIN within {timeout:g} s (has the vehicle a position fix?)")
        return self.origin  # type: ignore[return-value]

    # ------------------------------------------------------------------ commands
    def command(self, command: int, *params: float, timeout: float = 1.0, retries: int = 3) -> None:
        """COMMAND_LONG until its COMMAND_ACK; VehicleError unless the result is ACCEPTED."""
        p = list(params) + [0.0] * (7 - len(params))
        name = mavlink.enums["MAV_CMD"][command].name if command in mavlink.enums["MAV_CMD"] else str(command)
        for attempt in range(retries):
            with self._ack_cv:
                self._acks.pop(command, None)
            self.link.send(self.link.mav.command_long_encode(*self.target, command, attempt, *p))
            with self._ack_cv:
                if self._ack_cv.wait_for(lambda: command in self._acks, timeout / retries):
                    result = self._acks.pop(command)
                    if result == mavlink.MAV_RESULT_ACCEPTED:
                        return
                    if result == mavlink.MAV_RESULT_IN_PROGRESS:
                        continue
                    results = mavlink.enums["MAV_RESULT"]
                    rname = results[result].name if result in results else result
                    raise VehicleError(f"{name} refused by the vehicle: {rname}")
        raise VehicleError(f"{name}: no COMMAND_ACK within {timeout:g} s")

    def arm(self, timeout: float = 2.0) -> None:
        """Arm the vehicle, then wait for the HEARTBEAT to show it armed."""
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=timeout)
        self.wait_for("armed HEARTBEAT", lambda: self.armed, timeout)

    def set_mode(self, custom_mode: int, timeout: float = 2.0) -> None:
        """MAV_CMD_DO_SET_MODE with PX4's main / sub mode, then wait for the HEARTBEAT to show it."""
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub,
                     timeout=timeout)
        self.wait_for(f"HEARTBEAT in mode {main}.{sub}", lambda: self.custom_mode == custom_mode, timeout)

    # ------------------------------------------------------------------ set-points
    def _send_setpoint(self, sp: Setpoint) -> None:
        if sp.q_wxyz is None:
            mask, q, rates = ATTITUDE_IGNORED, (1.0, 0.0, 0.0, 0.0), sp.rates_frd
        else:
            mask, q, rates = RATES_IGNORED, sp.q_wxyz, (0.0, 0.0, 0.0)
        t_ms = int(time.monotonic() * 1000) & 0xFFFFFFFF
        self.link.send(self.link.mav.set_attitude_target_encode(
            t_ms, *self.target, mask, [float(x) for x in q], *(float(r) for r in rates), float(sp.thrust)))
        now = time.monotonic()
        st = self.stream
        if st.last_sent and self.in_offboard:
            gap = now - st.last_sent
            st.max_gap_s = max(st.max_gap_s, gap)
        st.last_sent = now
        st.sent += 1

    def hold_setpoint(self, hover_thrust: float) -> Setpoint:
        """Level at the current heading with hover thrust: what is streamed while PX4 is asked to hold."""
        s = self.state()
        yaw = 0.0 if s is None else s.yaw
        return Setpoint(float(hover_thrust), q_wxyz=(math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)))

    def start_stream(self, setpoint: Setpoint) -> None:
        """Stream ``setpoint`` from now on (it is the fallback too until :meth:`set_fallback`)."""
        with self._lock:
            self._setpoint, self._setpoint_fresh = setpoint, time.monotonic()
            if self._fallback is None:
                self._fallback = setpoint
        self._streaming.set()

    def set_fallback(self, setpoint: Setpoint) -> None:
        """The set-point streamed once the flight is aborted (the hold set-point)."""
        with self._lock:
            self._fallback = setpoint

    def command_rates(self, rates_frd: Any, thrust: float) -> None:
        """A new command from the control loop: sent now and streamed until the next one. Ignored
        once an abort is raised (then only the hold set-point goes out)."""
        sp = Setpoint(float(thrust), tuple(float(r) for r in rates_frd))
        with self._lock:
            if self._abort_reason is not None:
                return
            self._setpoint, self._setpoint_fresh = sp, time.monotonic()
            self._commanding = True
        self._send_setpoint(sp)

    def abort(self, reason: str) -> None:
        """Raise the abort (the first reason wins): from now on the hold set-point is streamed."""
        with self._lock:
            if self._abort_reason is None:
                self._abort_reason = reason
            if self._fallback is not None:
                self._setpoint = self._fallback
            self._setpoint_fresh = time.monotonic()

    @property
    def abort_reason(self) -> str | None:
        """Why the safety layer aborted the flight, or None while it has not."""
        return self._abort_reason

    def hold(self, hover_thrust: float, timeout: float = 5.0) -> bool:
        """Leave OFFBOARD into PX4's hold mode without ever starving the stream: the hold set-point is
        streamed while MAV_CMD_DO_SET_MODE(AUTO.LOITER) is retried, and the stream stops only once
        the HEARTBEAT shows another mode. Returns whether the vehicle confirmed it."""
        self.set_fallback(self.hold_setpoint(hover_thrust))
        self.abort(self._abort_reason or "end_of_flight")
        if not self._streaming.is_set():
            self.start_stream(self._fallback)  # type: ignore[arg-type]
        deadline = time.monotonic() + timeout
        confirmed = not self.in_offboard and self.custom_mode == HOLD_MODE
        while not confirmed and time.monotonic() < deadline:
            try:
                self.set_mode(HOLD_MODE, timeout=min(1.0, max(0.05, deadline - time.monotonic())))
            except VehicleError:
                pass
            confirmed = not self.in_offboard
        if not self.in_offboard:
            self._streaming.clear()
        return confirmed

    def _stream_loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:   # PX4 watches the companion's heartbeat for its data-link-loss failsafe
                self.link.send(self.link.mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                                              mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                                              mavlink.MAV_STATE_ACTIVE))
                next_hb = now + 1.0
            if self._streaming.is_set():
                with self._lock:
                    sp, fresh = self._setpoint, self._setpoint_fresh
                    stale = (self._abort_reason is None and self._commanding
                             and now - fresh > self.command_timeout and self.in_offboard)
                if stale:
                    self.abort("policy_timeout")
                    with self._lock:
                        sp = self._setpoint
                if sp is not None and now - self.stream.last_sent >= 1.5 * period:
                    self.stream.keepalive += 1
                    self._send_setpoint(sp)
            time.sleep(period / 4)

    def close(self) -> None:
        """Stop the set-point stream and close the link."""
        self._stop.set()
        self._streamer.join(timeout=1.0)
        self.link.close()
