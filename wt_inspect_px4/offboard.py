"""``wt-inspect fly``: fly any registered policy on a PX4 vehicle in OFFBOARD mode, scored like ``evaluate``.

Example (PX4 SITL's offboard port, VT-NMPC+, the surface task of a turbine whose tower base is 60 m
north of the vehicle's local origin and whose rotor faces east)::

    wt-inspect fly --connect udp://:14540 --controller vtnmpc-plus --scenario surface \\
        --site '{"base_ned": [60, 0, 0], "heading_deg": 90}' --out flights

How: the environment of the scenario is built as ``evaluate`` builds it, but its simulator is
replaced by the vehicle (:class:`VehicleSim`): a step sends the command and waits for the next
control tick, and the state is the vehicle's estimate converted to the project's frames
(:mod:`.frames`). Everything else is the environment's own code - the observation (planner,
moving reference, stand-off pose), coverage, metrics, terminations - and the flight loop is the
evaluation harness's (:func:`wt_inspect.evaluation.runner.fly`), so the run file is the harness's
format and a flight is scored with the same metrics (coverage, SM, CM). The raw MAVLink log (tlog)
and a flight summary (JSON) are written next to it.

Before OFFBOARD: the vehicle must be armed and near the mission's start pose (fly it there in
Position mode; ``--arm`` arms a vehicle that is not), inside the geofence, and the preset's thrust
must match PX4's hover thrust. The hold set-point (level, hover thrust) is streamed first, then
OFFBOARD is requested; the flight ends - mission complete, time cap, a safety limit
(:mod:`.safety`), stale state or link loss, a policy exception or an invalid command, a hung policy,
Ctrl-C - by leaving OFFBOARD into PX4's hold mode with the stream still running
(:meth:`~.vehicle.Vehicle.hold`).

Exit codes: 0 flight ended normally and the vehicle holds; 2 bad arguments or refused before
OFFBOARD (nothing flown); 3 the flight ended in a safety hold; 4 the vehicle did not confirm the hold.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from wt_inspect.commands.args import json_object
from wt_inspect.evaluation import prepare_out_dir, registry
from wt_inspect.evaluation.runner import RunResult, fly, make_spec, save_run
from wt_inspect.evaluation.scenarios import SCENARIOS, env_options
from wt_inspect_env.env import WindTurbineInspectionEnv
from wt_inspect_env.task.hooks import TaskHooks

from .frames import F_FRD_FLU, Site, SiteFrame, quat_wxyz_to_matrix
from .link import OFFBOARD_MODE, LinkFaults
from .safety import Geofence, SafetyConfig
from .thrust import ThrustMap
from .vehicle import Vehicle, VehicleError, VehicleState

NORMAL_ENDINGS = ("mission_complete", "time_limit", "max_time")


class FlightError(RuntimeError):
    """The flight was refused before OFFBOARD (the message says why and what to do)."""


@dataclass(frozen=True)
class FlyConfig:
    """One offboard flight (the options of ``wt-inspect fly``)."""

    connect: str
    controller: str
    site: Site
    scenario: str = "surface"
    turbine: Mapping[str, Any] = field(default_factory=dict)
    drone: str | None = None
    env: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    max_time: float | None = None
    out: str = "flights"
    target_system: int = 1
    target_component: int = 1
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    hover_tolerance: float = 0.08
    start_tolerance: float | None = None     # [m]; default a quarter of the stand-off distance
    arm: bool = False
    connect_timeout: float = 10.0
    warmup_s: float = 0.6                    # set-points streamed before OFFBOARD is requested
    hold_timeout: float = 5.0                # how long the hold request is retried (streaming) at the end
    trust_model: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.site, Site):
            raise ValueError(f"site must be a Site, got {self.site!r}")
        if self.scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {self.scenario!r}; valid: {', '.join(SCENARIOS)}")
        for name in ("hover_tolerance", "connect_timeout", "warmup_s", "hold_timeout"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if self.start_tolerance is not None and not (math.isfinite(self.start_tolerance) and self.start_tolerance > 0):
            raise ValueError(f"start_tolerance must be a positive number of metres, got {self.start_tolerance!r}")


class VehicleSim:
    """Stands in for the simulator of the environment's world (a world of one drone, so the arrays
    have one row): ``step`` sends the command to the vehicle and waits for the next control tick;
    ``state`` is the vehicle's estimate in the project's frames. What it does not replace (the
    turbine's PyBullet world used for the camera's occlusion rays, the geometry swap at the rotor
    turn) is the real simulator's.
    """

    def __init__(self, sim: Any, vehicle: Vehicle, frame: SiteFrame, thrust: ThrustMap, fence: Geofence,
                 safety: SafetyConfig, dt: float, collision_radius: float) -> None:
        self._sim = sim
        self.vehicle, self.frame, self.thrust, self.fence, self.safety = vehicle, frame, thrust, fence, safety
        self.dt = dt
        self.collision_radius = collision_radius
        self.wind: Any = None
        self.point: np.ndarray | None = None       # the inspection point the policy last saw
        self._steps = 0
        self._t0 = time.monotonic()
        self.overruns = 0
        self._state = np.zeros(10)
        self._state[9] = 1.0
        self._rates = np.zeros(3)
        self._v_world = np.zeros(3)
        self._q_prev: np.ndarray | None = None

    def __getattr__(self, name: str) -> Any:       # everything else: the real simulator's world
        return getattr(self._sim, name)

    def convert(self, s: VehicleState) -> None:
        """Adopt a vehicle state: NED / FRD -> the project's [p, v_body, q] and body rates."""
        q = self.frame.attitude_to_project(s.q_wxyz)
        if self._q_prev is not None and float(q @ self._q_prev) < 0:
            q = -q          # keep one hemisphere, as an integrated attitude would
        self._q_prev = q
        v_body_frd = quat_wxyz_to_matrix(s.q_wxyz).T @ s.velocity_ned
        x = np.empty(10)
        x[0:3] = self.frame.position_to_project(s.position_ned)
        x[3:6] = F_FRD_FLU @ v_body_frd
        x[6:10] = q
        self._state, self._rates = x, F_FRD_FLU @ s.rates_frd
        self._v_world = self.frame.vector_to_project(s.velocity_ned)

    # ---------------------------------------------------------------- the world's simulator interface
    @property
    def state(self) -> np.ndarray:
        """The vehicle's state in the simulator's layout, as a batch of one drone (a copy)."""
        return self._state[None].copy()

    @property
    def body_rates(self) -> np.ndarray:
        """The vehicle's body rates [rad/s], as a batch of one drone (a copy)."""
        return self._rates[None].copy()

    @property
    def world_velocity(self) -> np.ndarray:
        """The vehicle's velocity in the world frame [m/s] (a copy)."""
        return self._v_world.copy()

    @property
    def time(self) -> np.ndarray:
        """Flight time [s] since the start, as a batch of one drone."""
        return np.array([self._steps * self.dt])

    @property
    def last_wind(self) -> np.ndarray:
        """The wind: unknown on a vehicle (NaN)."""
        return np.full((1, 3), np.nan)          # not measured on a vehicle

    @property
    def in_collision(self) -> np.ndarray:
        """No contact sensing on a vehicle: the centre within the drone's radius of the mesh or the ground."""
        return np.array([self.fence.last_clearance < self.collision_radius
                         or bool(self._state[2] < self.collision_radius)])

    def reset_drone(self, i: int, state: Any = None) -> None:
        """Take the vehicle's current state (``state`` - the planned start - is where it should be)."""
        s = self.vehicle.state()
        if s is None:
            raise FlightError("no state estimate from the vehicle")
        self.convert(s)
        self.fence.reset()
        self._steps = 0
        self._t0 = time.monotonic()

    def step(self, commands: Any) -> None:
        """Send the one drone's command (a row ``[p, q, r, T]``) and wait for the next tick."""
        self._step(np.asarray(commands, dtype=float).reshape(-1))

    def _step(self, command: Any) -> None:
        v = self.vehicle
        cmd = np.asarray(command, dtype=float)
        if v.abort_reason is None:
            if cmd.shape != (4,) or not np.all(np.isfinite(cmd)):
                v.abort("non_finite_command")
            else:
                v.command_rates(F_FRD_FLU @ cmd[:3], self.thrust.to_normalised(cmd[3]))
        self._steps += 1
        deadline = self._t0 + self._steps * self.dt
        now = time.monotonic()
        if now < deadline:
            time.sleep(deadline - now)
        else:
            self.overruns += 1
            if now - deadline > 5 * self.dt:      # far behind: do not try to catch up in a burst
                self._t0 = now - self._steps * self.dt
        if v.abort_reason is not None:
            return
        s = v.state()
        now = time.monotonic()
        if s is None or now - s.received > self.safety.state_timeout:
            silent = now - v.link.last_rx > self.safety.state_timeout
            v.abort("link_lost" if silent else "stale_state")
            return
        if v.heartbeat_age() > self.safety.link_timeout:
            v.abort("link_lost")
            return
        self.convert(s)
        reason = self.fence.check(self._state[0:3], self._v_world, self.point)
        if reason is not None:
            v.abort(reason)


class VehicleHooks(TaskHooks):
    """The inspection task flown on a vehicle: an abort raised on the vehicle ends the episode as
    ``hold:<reason>``; otherwise the task's own terminations."""

    def terminations(self, world: Any, state: np.ndarray, finite: np.ndarray, collision: np.ndarray) -> np.ndarray:
        """The task's terminations, plus a hold as soon as the vehicle's safety layer has aborted."""
        vehicle = getattr(world.sim, "vehicle", None)
        reason = vehicle is not None and vehicle.abort_reason
        if reason:
            return np.array([self.code_for(f"hold:{reason}")])
        return super().terminations(world, state, finite, collision)


class VehicleInspectionEnv(WindTurbineInspectionEnv):
    """The inspection environment flown on a vehicle: :meth:`attach` swaps in a :class:`VehicleSim`
    as its world's simulator (see :class:`VehicleHooks` for how an abort ends the episode)."""

    def __init__(self, **options: Any) -> None:
        super().__init__(hooks=VehicleHooks(), **options)

    def attach(self, vehicle_sim: VehicleSim) -> None:
        """Fly the env's episodes on ``vehicle_sim`` instead of the simulator."""
        self.world.sim = self.sim = vehicle_sim      # type: ignore[assignment]

    def close(self) -> None:
        """Give the env its own simulator back, then close it."""
        sim = self.sim
        if isinstance(sim, VehicleSim):
            self.world.sim = self.sim = sim._sim
        super().close()


class GuardedPolicy:
    """The policy as the flight loop sees it: an exception, a non-finite or out-of-range action
    raises the abort (the vehicle holds) and the hover action stands in for it."""

    def __init__(self, policy: Any, vsim: VehicleSim, hover_action: np.ndarray) -> None:
        self.policy, self.vsim, self.hover = policy, vsim, np.asarray(hover_action, float)
        self.error: str | None = None

    @property
    def last_stats(self) -> Any:
        """The wrapped policy's solver statistics of its last step, if it keeps any."""
        return getattr(self.policy, "last_stats", None)

    def reset(self, seed: int | None = None) -> None:
        """Reset the wrapped policy; an exception in it aborts the flight into hold."""
        try:
            self.policy.reset(seed=seed)
        except Exception as exc:
            self._fail("policy_exception", exc)

    def _fail(self, reason: str, exc: BaseException | None = None) -> np.ndarray:
        if exc is not None and self.error is None:
            self.error = f"{type(exc).__name__}: {exc}"
        self.vsim.vehicle.abort(reason)
        return self.hover.copy()

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The wrapped policy's action, or hover once the flight is aborted (an exception aborts it)."""
        self.vsim.point = np.asarray(obs["point"], float)
        if self.vsim.vehicle.abort_reason is not None:
            return self.hover.copy()
        try:
            a = np.asarray(self.policy.act(obs), dtype=float)
        except Exception as exc:
            return self._fail("policy_exception", exc)
        if a.shape != (4,) or not np.all(np.isfinite(a)):
            self.error = f"action {a.tolist()}"
            return self._fail("non_finite_command")
        if np.any(np.abs(a) > 1.0 + 1e-6):
            self.error = f"action {a.tolist()}"
            return self._fail("command_out_of_range")
        return a


@contextlib.contextmanager
def sigint_holds(vehicle: Vehicle) -> Iterator[None]:
    """While flying, Ctrl-C raises the abort (the loop ends and the vehicle holds); a second
    Ctrl-C interrupts at once (the hold is still requested on the way out)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        if vehicle.abort_reason == "operator_abort":
            raise KeyboardInterrupt
        vehicle.abort("operator_abort")

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@dataclass
class Flight:
    """What a flight produced: the harness's :class:`RunResult` (saved at ``run_file``), the tlog,
    the summary (also saved as JSON) and whether the vehicle confirmed the hold."""

    result: RunResult | None
    run_file: Path | None
    tlog: Path
    summary_file: Path
    summary: dict[str, Any]
    hold_confirmed: bool

    @property
    def termination(self) -> str | None:
        """How the flight ended, or None while it has not."""
        return None if self.result is None else self.result.termination


def _turbine_pose(mission: Any) -> tuple[np.ndarray, float]:
    t0 = mission.turbines[0]
    spec = getattr(t0, "spec", None)
    pos = np.asarray(spec.position if spec is not None else (0.0, 0.0), float)
    axis = t0.rotor_axis
    return pos, math.degrees(math.atan2(axis[1], axis[0]))


def run_flight(cfg: FlyConfig, *, policy: Any = None, faults: LinkFaults | None = None,
               log: Any = None) -> Flight:
    """Fly ``cfg`` (see the module docstring). ``policy``: an object or factory ``env -> policy``
    to fly instead of the registered ``cfg.controller`` (which then is only its label);
    ``faults``: drop / delay our outgoing packets (tests). Raises :class:`FlightError`,
    :class:`~.vehicle.VehicleError` or ValueError if refused before OFFBOARD."""
    say = log or (lambda msg: print(msg, file=sys.stderr))
    opts = env_options(cfg.scenario, 0.0, turbine=cfg.turbine, drone=cfg.drone, overrides=cfg.env)
    spec = make_spec(cfg.scenario, cfg.controller, 0.0, cfg.seed, opts, cfg.max_time,
                     custom=policy is not None, trust_model=cfg.trust_model)
    out = prepare_out_dir(cfg.out)
    stem = f"flight-{time.strftime('%Y%m%d-%H%M%S')}-{int(time.time() * 1000) % 1000:03d}_{Path(spec.filename).stem}"
    tlog, summary_file = out / f"{stem}.tlog", out / f"{stem}.json"
    env = VehicleInspectionEnv(**opts)
    ctrl_hz = env.config.ctrl_hz
    safety = cfg.safety.resolved(env.config.standoff, env.config.working_margin)
    try:
        vehicle = Vehicle(cfg.connect, target_system=cfg.target_system, target_component=cfg.target_component,
                          tlog=tlog, rate_hz=ctrl_hz, command_timeout=safety.command_timeout, faults=faults)
    except BaseException:
        env.close()
        raise
    summary: dict[str, Any] = {"connect": cfg.connect, "controller": cfg.controller, "scenario": cfg.scenario,
                               "site": asdict(cfg.site), "safety": asdict(safety), "ctrl_hz": ctrl_hz}
    result: RunResult | None = None
    run_file: Path | None = None
    engaged = False
    hold_confirmed = False
    hover_n = 0.5
    try:
        say(f"waiting for the vehicle on {cfg.connect} ...")
        vehicle.wait_connected(cfg.connect_timeout)
        params = env.params
        try:
            px4_fac: float | None = vehicle.param("THR_MDL_FAC", timeout=1.0)
        except VehicleError:
            px4_fac = None
        thrust = ThrustMap.for_params(params, px4_curve=px4_fac)
        px4_hover = vehicle.param("MPC_THR_HOVER", timeout=2.0)
        predicted = thrust.check_hover(params.mass, px4_hover, cfg.hover_tolerance)
        hover_n = thrust.to_normalised(params.weight)
        summary["thrust"] = {"MPC_THR_HOVER": px4_hover, "predicted_hover": predicted, "THR_MDL_FAC": px4_fac,
                             "thrust_curve": params.thrust_curve}
        origin = vehicle.request_origin() if cfg.site.needs_origin else None
        pos_w, facing = _turbine_pose(env.mission)
        frame = cfg.site.frame(pos_w, facing, origin)
        summary["frame"] = {"yaw_deg": math.degrees(frame.yaw), "base_ned": frame.base_ned.tolist(),
                            "origin": origin}
        obs, info = env.reset(seed=cfg.seed)     # its own simulator still: where the mission starts
        start = np.asarray(info["ideal_position"], float)
        fence = Geofence(env.mission, safety, start, ground_height=0.0)
        radius = float(min(params.collision_half_extents))
        vsim = VehicleSim(env.sim, vehicle, frame, thrust, fence, safety, 1.0 / ctrl_hz, radius)
        env.attach(vsim)
        obs, info = env.reset(seed=cfg.seed)
        here = obs["position"].astype(float)
        tol = cfg.start_tolerance if cfg.start_tolerance is not None else 0.25 * env.config.standoff
        gap = float(np.linalg.norm(here - start))
        if gap > tol:
            raise FlightError(f"the vehicle is {gap:.2f} m from the mission's start pose (tolerance {tol:g} m): it is "
                              f"at {np.round(here, 2).tolist()}, the start is at {np.round(start, 2).tolist()} in the "
                              f"project frame (NED {np.round(frame.position_to_ned(start), 2).tolist()}); fly it "
                              "there first (Position mode), or check --site")
        reason = fence.check(here, vsim.world_velocity, obs["point"])
        if reason is not None:
            raise FlightError(f"the vehicle breaks the geofence ({reason}) before the flight; not engaging")
        if policy is None:
            policy = registry.resolve(cfg.controller, trust_model=cfg.trust_model)(env)
        elif not callable(getattr(policy, "act", None)) and callable(policy):
            policy = policy(env)
        guarded = GuardedPolicy(policy, vsim, env.scaling.hover_action())
        vehicle.start_stream(vehicle.hold_setpoint(hover_n))
        time.sleep(cfg.warmup_s)
        if not vehicle.armed:
            if not cfg.arm:
                raise FlightError("the vehicle is not armed: take off and fly it to the start pose first, or "
                                  "pass --arm")
            vehicle.arm()
        with sigint_holds(vehicle):
            engaged = True
            vehicle.set_mode(OFFBOARD_MODE)
            say(f"OFFBOARD: flying {cfg.controller} at {ctrl_hz:g} Hz (Ctrl-C holds)")
            result = fly(env, guarded, spec, record=True)
        summary["policy_error"] = guarded.error
        summary["overruns"] = vsim.overruns
    finally:
        if engaged or vehicle.in_offboard:
            hold_confirmed = vehicle.hold(hover_n, timeout=cfg.hold_timeout)
        summary["hold_confirmed"] = hold_confirmed
        summary["abort_reason"] = vehicle.abort_reason
        summary["stream"] = {"sent": vehicle.stream.sent, "keepalive": vehicle.stream.keepalive,
                             "max_gap_in_offboard_s": vehicle.stream.max_gap_s}
        summary["status_texts"] = vehicle.status_texts[-20:]
        vehicle.close()
        env.close()
        if result is not None:
            run_file = save_run(result, out / "runs" / f"{stem}.npz")
            summary.update(termination=result.termination, metrics=result.metrics, steps=result.steps,
                           run_file=str(run_file))
        summary["tlog"] = str(tlog)
        summary_file.write_text(json.dumps(summary, indent=2, default=_json_default))
    return Flight(result, run_file, tlog, summary_file, summary, hold_confirmed)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# ---------------------------------------------------------------------------------------- CLI
def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect fly`` (its epilog: the module's example)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[2:8]))
    ap.add_argument("--connect", required=True, metavar="URL",
                    help="vehicle endpoint: udp://:14540 (listen, PX4 SITL's offboard port), udp://HOST:PORT, "
                         "tcp://HOST:PORT")
    ap.add_argument("--controller", required=True, metavar="NAME",
                    help=f"a registered policy: {registry.valid_names()}")
    ap.add_argument("--site", required=True, metavar="JSON|FILE",
                    help='where the turbine stands: {"base_ned": [N, E, D], "heading_deg": H} or '
                         '{"base_lla": [LAT, LON, ALT], "heading_deg": H} (H: compass heading of the rotor axis)')
    ap.add_argument("--scenario", default="surface", choices=list(SCENARIOS), help="(default surface)")
    ap.add_argument("--turbine", type=json_object("--turbine"), default={}, metavar="JSON", help="TurbineSpec fields")
    ap.add_argument("--drone", metavar="PRESET", help="drone preset (its mass, rotor thrust and thrust_curve "
                    "must describe the vehicle: checked against MPC_THR_HOVER)")
    ap.add_argument("--env", type=json_object("--env"), default={}, metavar="JSON", help="other environment options")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-time", type=float, metavar="S", help="end the flight after S seconds")
    ap.add_argument("--out", default="flights", metavar="DIR", help="run files, tlogs, summaries (default flights)")
    ap.add_argument("--system-id", type=int, default=1, help="the vehicle's MAVLink system id (default 1)")
    ap.add_argument("--arm", action="store_true", help="arm the vehicle if it is not armed")
    ap.add_argument("--trust-model", action="store_true", help="as for evaluate: let a ppo: file run code")
    s = ap.add_argument_group("safety")
    s.add_argument("--fence-margin", type=float, metavar="M", help="geofence box margin around the mission (default: "
                   "the environment's working margin)")
    s.add_argument("--min-clearance", type=float, metavar="M", help="least distance to the turbine mesh "
                   "(default half the stand-off)")
    s.add_argument("--max-speed", type=float, default=5.0, metavar="M/S", help="(default 5)")
    s.add_argument("--min-altitude", type=float, default=1.0, metavar="M", help="(default 1)")
    s.add_argument("--state-timeout", type=float, default=0.25, metavar="S", help="hold without a fresh estimate for S")
    s.add_argument("--link-timeout", type=float, default=1.5, metavar="S", help="hold without a HEARTBEAT for S")
    s.add_argument("--hover-tolerance", type=float, default=0.08, metavar="X",
                   help="largest |predicted - MPC_THR_HOVER| accepted (default 0.08)")
    s.add_argument("--start-tolerance", type=float, metavar="M", help="largest distance from the start pose "
                   "(default a quarter of the stand-off)")
    return ap


def config_from_args(args: argparse.Namespace) -> FlyConfig:
    """The flight configuration from parsed arguments (the controller is checked first)."""
    registry.check_controller(args.controller, trust_model=args.trust_model)
    safety = SafetyConfig(box_margin=args.fence_margin, min_clearance=args.min_clearance, max_speed=args.max_speed,
                          min_altitude=args.min_altitude, state_timeout=args.state_timeout,
                          link_timeout=args.link_timeout)
    return FlyConfig(connect=args.connect, controller=args.controller, site=Site.parse(args.site),
                     scenario=args.scenario, turbine=args.turbine, drone=args.drone, env=args.env, seed=args.seed,
                     max_time=args.max_time, out=args.out, target_system=args.system_id, safety=safety,
                     hover_tolerance=args.hover_tolerance, start_tolerance=args.start_tolerance, arm=args.arm,
                     trust_model=args.trust_model)


def main(argv: list[str], prog: str = "wt-inspect fly") -> int:
    """``wt-inspect fly``: fly the mission given by ``argv`` through PX4; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    try:
        from .link import Endpoint
        Endpoint.parse(args.connect, "--connect")
        cfg = config_from_args(args)
        flight = run_flight(cfg)
    except (ValueError, FlightError, VehicleError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    term = flight.termination
    m = flight.result.metrics if flight.result is not None else {}
    print(f"flight ended: {term}; coverage {m.get('coverage', math.nan):.3f}, SM {m.get('safety_sm', math.nan):.3f}, "
          f"CM {m.get('centering_cm', math.nan):.3f}; "
          f"hold {'confirmed' if flight.hold_confirmed else 'NOT confirmed'}; "
          f"wrote {flight.run_file}, {flight.tlog}, {flight.summary_file}")
    if not flight.hold_confirmed:
        return 4
    return 0 if term in NORMAL_ENDINGS else 3
