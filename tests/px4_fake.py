"""A fake PX4 vehicle for the bridge's tests: pymavlink over a real UDP socket on localhost.

It follows the parts of PX4's offboard behaviour the runner depends on (PX4 user guide,
"Offboard Mode"): OFFBOARD is refused (MAV_RESULT_TEMPORARILY_REJECTED) unless set-points have
been arriving (at least 5, the last within 0.5 s); in OFFBOARD, set-points missing for
``offboard_loss_s`` (PX4's COM_OF_LOSS_T) trigger the failsafe into hold, which is recorded
(``mode_delay_s`` makes an accepted switch out
of OFFBOARD take effect late, as on a busy autopilot, so a runner that stops streaming on the ACK
rather than on the HEARTBEAT is caught);
COMMAND_LONG is acknowledged; PARAM_REQUEST_READ answers MPC_THR_HOVER and THR_MDL_FAC;
MAV_CMD_REQUEST_MESSAGE(GPS_GLOBAL_ORIGIN) is answered. It streams HEARTBEAT (10 Hz) and
ODOMETRY (pose LOCAL_NED, velocity BODY_FRD) - or LOCAL_POSITION_NED + ATTITUDE_QUATERNION - at
``rate_hz`` from either a rigid-body integrator of the paper's model or the project's simulator
(:class:`~wt_inspect_env.world.sim.QuadrotorSim` with the turbine and wind: then the runner's commands
fly the same physics ``evaluate`` flies). Outside OFFBOARD the vehicle holds still (PX4's
position controller, idealised).

Not PX4: no estimator, no rate controller of its own in the integrator, no RC, no parameters but
the two above.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from wt_inspect_env.physics.dynamics import quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import GRAVITY, QuadrotorParams
from wt_inspect_px4.frames import F_FRD_FLU, SiteFrame
from wt_inspect_px4.link import (
    HOLD_MODE,
    OFFBOARD_MODE,
    PX4_MAIN_OFFBOARD,
    PX4_MAIN_POSCTL,
    LinkFaults,
    MavlinkLink,
    mavlink,
    px4_mode,
)
from wt_inspect_px4.thrust import ThrustMap
from wt_inspect_px4.vehicle import ATTITUDE_IGNORED


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


class FakePX4:
    """See the module docstring. ``state``: the project-frame model state [p, v_body, q] it starts in."""

    def __init__(self, connect: str, frame: SiteFrame, params: QuadrotorParams, state: np.ndarray, *,
                 rate_hz: float = 100.0, physics: str = "integrator", sim: Any = None,
                 odometry: bool = True, hover_thrust: float | None = None, thr_mdl_fac: float | None = None,
                 offboard_loss_s: float = 0.5, armed: bool = True, faults: LinkFaults | None = None,
                 mode_delay_s: float = 0.0,
                 origin: tuple[float, float, float] = (47.397742, 8.545594, 488.0)) -> None:
        self.frame, self.params = frame, params
        self.thrust = ThrustMap.for_params(params, px4_curve=thr_mdl_fac)
        self.hover_thrust = self.thrust.to_normalised(params.weight) if hover_thrust is None else hover_thrust
        self.thr_mdl_fac = params.thrust_curve if thr_mdl_fac is None else thr_mdl_fac
        self.x = np.asarray(state, float).copy()
        self.w = np.zeros(3)
        self.dt = 1.0 / rate_hz
        self.physics = physics
        self.sim = sim
        if sim is not None:
            sim.reset(self.x)
        self.odometry = odometry
        self.offboard_loss_s = offboard_loss_s
        self.mode_delay_s = mode_delay_s          # an accepted switch out of OFFBOARD takes effect this late
        self._pending: tuple[float, int] | None = None
        self.origin = origin
        self.mode = px4_mode(PX4_MAIN_POSCTL)
        self.armed = armed
        self.mode_history: list[tuple[float, int]] = [(time.monotonic(), self.mode)]
        self.failsafe = False
        self.setpoints: list[float] = []
        self.max_gap_in_offboard = 0.0
        self.offboard_rejections = 0
        self.command: tuple[np.ndarray, float] = (np.zeros(3), self.hover_thrust)
        self.attitude_sp: np.ndarray | None = None
        self.silence_state = False     # stop the state stream (heartbeat goes on)
        self.silence_all = False       # stop sending anything
        self.max_distance_from_start = 0.0
        self._start = self.x[0:3].copy()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.link = MavlinkLink(connect, system_id=1, component_id=1, handler=self._on_message, faults=faults)
        self._thread = threading.Thread(target=self._loop, name="fake-px4", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ protocol
    def _set_mode(self, mode: int) -> None:
        if mode != self.mode:
            self.mode = mode
            self.mode_history.append((time.monotonic(), mode))

    @property
    def in_offboard(self) -> bool:
        return (self.mode >> 16) & 0xFF == PX4_MAIN_OFFBOARD

    def _send(self, msg: Any) -> None:
        if not self.silence_all:
            self.link.send(msg)

    def _ack(self, command: int, result: int) -> None:
        self._send(self.link.mav.command_ack_encode(command, result, 0, 0, 255, 0))

    def _on_message(self, msg: Any) -> None:
        t = msg.get_type()
        now = time.monotonic()
        with self._lock:
            if t == "SET_ATTITUDE_TARGET":
                if self.in_offboard and self.setpoints:
                    self.max_gap_in_offboard = max(self.max_gap_in_offboard, now - self.setpoints[-1])
                self.setpoints.append(now)
                if msg.type_mask & ATTITUDE_IGNORED:
                    self.command = (np.array([msg.body_roll_rate, msg.body_pitch_rate, msg.body_yaw_rate]),
                                    float(msg.thrust))
                    self.attitude_sp = None
                else:
                    self.attitude_sp = np.array(msg.q, float)
                    self.command = (np.zeros(3), float(msg.thrust))
            elif t == "COMMAND_LONG":
                self._on_command(msg, now)
            elif t == "PARAM_REQUEST_READ":
                name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
                value = {"MPC_THR_HOVER": self.hover_thrust, "THR_MDL_FAC": self.thr_mdl_fac}.get(name.rstrip("\x00"))
                if value is not None:
                    self._send(self.link.mav.param_value_encode(name.encode(), float(value),
                                                                    mavlink.MAV_PARAM_TYPE_REAL32, 2, 0))

    def _on_command(self, msg: Any, now: float) -> None:
        c = int(msg.command)
        if c == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.armed = msg.param1 > 0.5
            self._ack(c, mavlink.MAV_RESULT_ACCEPTED)
        elif c == mavlink.MAV_CMD_DO_SET_MODE:
            mode = px4_mode(int(msg.param2), int(msg.param3))
            if mode == OFFBOARD_MODE:
                recent = [s for s in self.setpoints if now - s < 0.5]
                if len(self.setpoints) < 5 or not recent:
                    self.offboard_rejections += 1
                    self._ack(c, mavlink.MAV_RESULT_TEMPORARILY_REJECTED)
                    return
            if self.mode_delay_s > 0 and self.in_offboard:
                self._pending = (now + self.mode_delay_s, mode)
            else:
                self._set_mode(mode)
            self._ack(c, mavlink.MAV_RESULT_ACCEPTED)
        elif c == mavlink.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            self._ack(c, mavlink.MAV_RESULT_ACCEPTED)
            lat, lon, alt = self.origin
            self._send(self.link.mav.gps_global_origin_encode(int(lat * 1e7), int(lon * 1e7), int(alt * 1e3),
                                                                  int(now * 1e6)))
        else:
            self._ack(c, mavlink.MAV_RESULT_UNSUPPORTED)

    # ------------------------------------------------------------------ physics and streams
    def _hold_still(self) -> None:
        yaw = Rotation.from_quat(self.x[6:10]).as_euler("ZYX")[0]
        self.x[3:6] = 0.0
        self.x[6:10] = [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]
        self.w[:] = 0.0
        if self.sim is not None:
            self.sim.reset(self.x)

    def _integrate(self, rates_flu: np.ndarray, thrust_n: float) -> None:
        """The paper's model (:mod:`wt_inspect_env.physics.dynamics`), Euler in 4 sub-steps."""
        h = self.dt / 4
        for _ in range(4):
            R = quat_to_rotmat_np(self.x[6:10])
            v = self.x[3:6]
            self.x[0:3] += h * (R @ v)
            self.x[3:6] += h * (-np.cross(rates_flu, v) + R.T @ np.array([0, 0, -GRAVITY])
                                + np.array([0, 0, thrust_n / self.params.mass]))
            q = self.x[6:10] + h * 0.5 * _quat_mul(self.x[6:10], np.append(rates_flu, 0.0))
            self.x[6:10] = q / np.linalg.norm(q)
        self.w = rates_flu

    def _step(self) -> None:
        with self._lock:
            if self._pending is not None and time.monotonic() >= self._pending[0]:
                self._set_mode(self._pending[1])
                self._pending = None
            if self.in_offboard and self.setpoints:     # the gap so far, also when no set-point follows it
                self.max_gap_in_offboard = max(self.max_gap_in_offboard, time.monotonic() - self.setpoints[-1])
            if self.in_offboard and self.setpoints and time.monotonic() - self.setpoints[-1] > self.offboard_loss_s:
                self.failsafe = True
                self._set_mode(HOLD_MODE)
            offboard = self.in_offboard and self.armed
            rates_frd, thrust_norm = self.command
            att = self.attitude_sp
        if not offboard:
            self._hold_still()
            return
        thrust_n = self.thrust.to_newtons(thrust_norm)
        if att is not None:                       # attitude set-point: tracked perfectly (idealised)
            self.x[6:10] = self.frame.attitude_to_project(att)
            rates = np.zeros(3)
        else:
            rates = F_FRD_FLU @ rates_frd
        if self.sim is not None:
            self.sim.step(np.append(rates, thrust_n))
            self.x, self.w = self.sim.state, self.sim.body_rates
        else:
            self._integrate(rates, thrust_n)
        self.max_distance_from_start = max(self.max_distance_from_start,
                                           float(np.linalg.norm(self.x[0:3] - self._start)))

    def _send_state(self, now: float) -> None:
        f = self.frame
        p = f.position_to_ned(self.x[0:3])
        q = f.attitude_to_ned(self.x[6:10])
        v_frd = F_FRD_FLU @ self.x[3:6]
        w_frd = F_FRD_FLU @ self.w
        t_us = int(now * 1e6)
        mav = self.link.mav
        if self.odometry:
            nan9 = [math.nan] + [0.0] * 20
            self._send(mav.odometry_encode(t_us, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                                               *p.tolist(), q.tolist(), *v_frd.tolist(), *w_frd.tolist(),
                                               nan9, nan9, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100))
        else:
            v_ned = f.vector_to_ned(quat_to_rotmat_np(self.x[6:10]) @ self.x[3:6])
            t_ms = int(now * 1e3) & 0xFFFFFFFF
            self._send(mav.local_position_ned_encode(t_ms, *p.tolist(), *v_ned.tolist()))
            self._send(mav.attitude_quaternion_encode(t_ms, *q.tolist(), *w_frd.tolist(), [0.0] * 4))

    def _loop(self) -> None:
        next_t = time.monotonic()
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now < next_t:
                time.sleep(next_t - now)
                continue
            next_t += self.dt
            if next_t < now - 0.1:
                next_t = now
            self._step()
            if self.silence_all:
                continue
            if now >= next_hb:
                base = (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                        | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0))
                self._send(self.link.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                                              base, self.mode, mavlink.MAV_STATE_ACTIVE))
                next_hb = now + 0.1
            if not self.silence_state:
                self._send_state(now)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        self.link.close()
