"""A predictive safety filter: any policy's command, changed as little as needed to keep d_min.

Every MPC here keeps the clearance d_min from the turbine through its OCP's clearance constraint
(:func:`controllers.rti_policy.clearance_ocp`: one supporting half-space of the nearest mesh
points per stage, tightened by the distance needed to brake at ``clearance_brake`` from the
velocity towards it). A learned agent or a user's own controller has no such constraint. The filter
gives it one: each control step it solves, on the same real-time-iteration core and with the same
clearance geometry (the phase's mesh, following the mission's progress), the OCP

    min  |S (u_0 - u_policy)|^2  +  eps sum_{k >= 1} |S (u_k - u_hover)|^2
    s.t. the drone model, the input bounds, the clearance constraint at every stage,

with S the map to the normalised action (so "closest" is measured in the action space the policy
commands) and eps small. The inputs after the first are a *backup plan*: they are free to brake
and turn away, and cost almost nothing, so the first input equals the policy's own whenever a
backup plan exists that keeps the clearance from the state it leads to, and moves the least
otherwise. Stage 0 and the later stages are told apart by a stage-wise parameter (1 at stage 0,
0 after), not by a state: the RTI linearises at the shifted previous plan, whose states belong
to the step before.

The clearance constraint is the MPCs' with one addition (``clearance_reaction``, 0.3 s): a
policy may tilt hard towards the structure, and a tilted drone needs time to turn round before it
can brake, so for that time the constraint assumes the drone keeps its present acceleration (the
thrust along its body axis plus gravity) and only then brakes. Which half-space each stage keeps
differs from the MPCs', whose drone flies at the stand-off: the nearest surface is not always the
one a policy flies at. A policy flying along a nacelle towards the tower sees the nacelle nearest
until the tower is inside its stopping distance (a campaign flight reached 12 m/s along the
nacelle and hit the tower). So each looked-up stage keeps *three* half-spaces (the OCP's clearance
constraint with ``half_spaces=3``, all relaxed by the one slack):

1. the tighter of the supporting half-space at the stage's position and the ground's (z >= d_min);
   each is a supporting half-space of the nearest convex part of the mesh to a point outside it
   (or the ground), so it keeps the position d_min from that part.
2. the supporting half-space at a *look-ahead point* towards the stage's stopping point (along
   the velocity, by the distance the constraint says it needs to stop - reaction plus braking -
   but at most ``LOOKAHEAD_FRACTION`` of the stage's clearance: one sphere-tracing step, so the
   point is certainly outside the structure). (Taking the stopping point itself would be wrong
   where it lies inside the structure: its closest point's half-space faces the wrong way.)
   In a concave corner this is the surface the drone flies at while the first is the one beside
   it; with one slot for the tighter of the two (tried), a drone braking for the surface ahead
   drifted into the one beside it (a hub adversary to 2.69 m, no wind).
3. a *free-ray bound* along the stage's direction of flight: the balls around the position (radius
   d_0, its clearance) and around the look-ahead point (d_1) hold no structure, and both lie on
   the ray ahead, so the ray is free for at least L = max(d_0, step + d_1); the drone must be able
   to stop within L - d_min along it. The first half-space only sees the surface nearest to one
   point; a drone flying fast along one surface towards another (the nacelle towards the tower, a
   blade root towards the hub) is held by this bound until the second surface is the nearest.
   It is inactive at rest (no direction) and once the stage is inside d_min (the ball gives no
   room; the first half-space pushes out). Replacing the first half-space by it instead (tried)
   lets wind drift a slow drone into the nearest surface.

Wind and drag. Near a turbine the wind pushes the drone into the structure, and a model without it
brakes too late. The filter runs the disturbance observer of the MPC base (``disturbance_observer``,
on by default here: :meth:`~controllers.rti_policy.RTIPolicy.on_measurement`), feeds its world-frame
estimate a_ext to its model, and its clearance constraint takes the part of a_ext that pushes
towards each half-space's boundary off the braking deceleration (down to a quarter of
``clearance_brake``) and adds it to the acceleration of the reaction time
(:func:`controllers.rti_policy.clearance_ocp` with ``disturbance``). Two choices keep that estimate
the wind's and not the manoeuvre's: the model has the airframe's linear rotor drag (``model_drag``:
-D/m v_B, ground-relative; the wind's share D/m R^T w is then a steady push the observer sees), and
the observer compares the measured acceleration with the model's at the *measured* attitude
(``observer_model="attitude"``). Without them a policy flying hard at the structure made the
observer read the drag of the drone's own speed as a push of up to 0.4 g towards the structure, and
the filter, believing it, had its QP fail as it braked (the adversarial study's worst flights before
the change).

The drag also helps braking: the stopping distances credit it at half its initial deceleration
(:func:`controllers.rti_policy.clearance.stopping_distance`, an upper bound of the integrated stop);
without that credit a steady push towards the structure left the agent of the paper mission a
quarter of its braking deceleration, and the filter stepped in on a tenth of its steps in the 4 m/s
gust. The observer starts at its first residual (a wind present at the start is seen at once, not
after its time constant) and takes the thrust through the rotors' first-order lag (the filter's
own corrections swing the thrust command, which read as gusts when taken for the thrust).

Known limits (measured in ``results/safety_filter``): the half-spaces are linear pieces of the
structure around three points per stage, the observer lags turbulence by its time constant and the
model has no rate loop, so a drone pushed hard at the structure can still dip a little below the
back-off; the study reports every dip.

When the QP fails, the RTI core flies the shifted previous plan (its last feasible backup plan);
once that is used up, the filter levels the drone and brakes (:func:`brake_command`) where the
RTI core's generic last resort would hover with zero body rates - never the unfiltered command;
:class:`SafetyFilter` counts every intervention and every such fallback.

Pass-through (``pass_through``, on by default). Most steps of a policy that flies its mission at
the stand-off need no correction, and solving the QP to learn that is most of the filter's time.
So each step first rolls the *candidate* - the policy's command, then hover (the backup the cost
pulls towards) - through the same model with the same stage-wise half-spaces
(:class:`controllers.rti.rollout.Rollout`: the OCP's own dynamics and clearance constraint,
without slack). If every stage keeps the constraint with ``pass_through_margin`` to spare, the
candidate is a feasible point of the filter's problem at zero cost - the QP's own answer when no
constraint binds - so the policy's command is applied without the QP, and the candidate becomes
the plan: the next QP is linearised along it, and if that QP fails, the shifted candidate is the
backup that flies. Otherwise the QP runs as above. The check is the *nonlinear* model against
the constraint the QP keeps linearised, so a passed step is at least as safe as a solved one;
the statistics count the steps that passed.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, ClassVar, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import NU, NX, QuadrotorModel, quat_to_rotmat, quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import GRAVITY
from wt_inspect_env.policy import Policy

from .rti import OCP, RTISolver, SolveStats
from .rti.rollout import Rollout
from .rti_policy import LSQWeights, MPCConfig, RTIPolicy, config_ocp
from .rti_policy.clearance import stopping_distance

N_PARAMS = NU + 4   # the policy's command [p, q, r, T], the stage-0 flag, the disturbance a_ext (3)
A_EXT = slice(NU + 1, NU + 4)
#: a filtered action that differs from the policy's by more than this (normalised, any component)
#: counts as an intervention
INTERVENTION_TOL = 1e-3
#: the solve status of a step whose policy command passed the rollout check (no QP solved)
PASSED = "PASSED_THROUGH"
#: the last-resort brake (:func:`brake_command`): time constant [s] of the deceleration, attitude
#: gain [1/s] (the adversarial study's attitude loop uses the same gain), deceleration cap as a
#: multiple of ``clearance_brake``
BRAKE_TIME = 0.5
BRAKE_ATTITUDE_GAIN = 6.0
BRAKE_FACTOR = 2.0
#: the look-ahead point of a stage lies at most this fraction of the stage's clearance ahead
LOOKAHEAD_FRACTION = 0.9
#: below this speed [m/s] a stage has no direction of flight, so no free-ray bound; an inactive
#: bound is the half-space z >= -INACTIVE [m]
IDLE_SPEED = 1e-3
INACTIVE = 1e3


@dataclass(frozen=True)
class FilterWeights(LSQWeights):
    """Weights of the filter's OCP, on normalised actions: ``command`` the first input's distance
    to the policy's, ``backup`` the later inputs' distance to hover (small: the backup plan may
    brake freely), ``terminal_velocity`` the plan's final world velocity (0 by default)."""

    command: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    backup: tuple[float, ...] = (1e-2, 1e-2, 1e-2, 1e-2)
    terminal_velocity: float = 0.0
    terminal_factor: float = 1.0

    STAGE: ClassVar = (("command", 4), ("backup", 4))
    TERMINAL: ClassVar = (("terminal_velocity", 3),)
    INPUTS: ClassVar = "command"


@dataclass(frozen=True)
class SafetyFilterConfig(MPCConfig):
    """The filter's OCP (the common MPC fields, clearance on; see the module docstring). The
    weights act on normalised actions, so they are not rescaled with the stand-off."""

    WEIGHTS: ClassVar[type] = FilterWeights
    WEIGHT_SETS: ClassVar[Mapping[str, Any]] = {"default": FilterWeights()}

    weights: FilterWeights | str = "default"
    scale_weights: bool = False
    # a policy may tilt hard towards the structure: for 0.3 s (about the time to turn a tilted
    # drone round at the rate limit) the constraint lets it keep its acceleration before braking
    clearance_reaction: float = 0.3
    # skip the QP when the policy's command followed by hover keeps the clearance constraint at
    # every stage with this margin [m] to spare (see the module docstring)
    pass_through: bool = True
    pass_through_margin: float = 0.05
    # the wind a drone meets near a turbine pushes it into the structure: the filter's model and
    # its stopping distances take the observer's estimate into account (module docstring)
    disturbance_observer: bool = True
    # the observer compares the measurement with the model at the measured attitude: it needs no
    # plan, so it reads alike whether the QP solved, failed or was passed (RTIPolicy.on_measurement)
    observer_model: str = "attitude"
    # the airframe's linear rotor drag in the model: a drone flying at the structure is slowed by
    # it, and without it the observer takes the drag of the flight's own speed for a push that
    # changes as the drone brakes (module docstring)
    model_drag: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.model_drag, bool):
            raise ValueError(f"model_drag must be a bool, got {self.model_drag!r}")
        if not isinstance(self.pass_through, bool):
            raise ValueError(f"pass_through must be a bool, got {self.pass_through!r}")
        m = self.pass_through_margin
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not (0.0 <= m < float("inf")):
            raise ValueError(f"pass_through_margin must be a finite number >= 0 [m], got {m!r}")


def brake_command(state: np.ndarray, config: SafetyFilterConfig) -> np.ndarray:
    """The physical command [p, q, r, T] that levels a drone towards braking: the body z axis
    turned (at ``BRAKE_ATTITUDE_GAIN`` rad/s per rad) onto the thrust direction of the
    deceleration -v / ``BRAKE_TIME`` (capped at ``BRAKE_FACTOR`` times the braking acceleration
    the clearance constraint assumes, so it stops within what the constraint allowed for) plus
    gravity, no yaw rate, the thrust of that force along the present body axis, all within
    the command bounds. What the filter flies when its QP has failed for a whole horizon: the RTI
    core's generic last resort (hover: zero rates) holds a tilted drone's tilt, and a drone that
    a policy had tilted hard then accelerates away."""
    R = quat_to_rotmat_np(state[6:10])
    v = R @ state[3:6]
    a = -v / BRAKE_TIME
    n = float(np.linalg.norm(a))
    if n > BRAKE_FACTOR * config.clearance_brake:
        a *= BRAKE_FACTOR * config.clearance_brake / n
    f = config.params.mass * (a + np.array([0.0, 0.0, GRAVITY]))
    z_des = f / float(np.linalg.norm(f))
    rates = BRAKE_ATTITUDE_GAIN * (R.T @ np.cross(R[:, 2], z_des))
    return np.clip(np.array([rates[0], rates[1], 0.0, float(f @ R[:, 2])]),
                   config.scaling.lower, config.scaling.upper)


def linear_drag(config: SafetyFilterConfig) -> np.ndarray | None:
    """The model's linear body drag per unit mass [1/s] per body axis (None with ``model_drag`` off)."""
    if not config.model_drag:
        return None
    return np.asarray(config.params.drag_coefficients[0], dtype=np.float64) / config.params.mass


def build_ocp(config: SafetyFilterConfig) -> OCP:
    """The filter's least-squares OCP (see the module docstring); parameters [u_policy (4), first,
    a_ext (3)] with ``first`` 1 at stage 0 and 0 after and a_ext the observer's disturbance
    acceleration (world frame)."""
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", N_PARAMS)
    s = ca.DM(2.0 / (config.scaling.upper - config.scaling.lower))     # physical -> normalised
    first = p[NU]
    stage = ca.Function("safety_filter_r", [x, u, p],
                        [ca.vertcat(first * s * (u - p[:NU]), (1.0 - first) * s * (u - ca.DM(config.hover_input)))],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function("safety_filter_rN", [x, p], [quat_to_rotmat(x[6:10]) @ x[3:6]], ["x", "p"], ["rN"])
    model = QuadrotorModel(config.params)
    dynamics = ca.Function("safety_filter_F", [x, u, p],
                           [model.rk4_expr(x, u, config.dt, a_ext=p[A_EXT], steps=config.rk4_steps,
                                           drag=linear_drag(config))],
                           ["x", "u", "p"], ["x_next"])
    return config_ocp("safety_filter", config, dynamics, stage, terminal)


class FilterMPC(RTIPolicy):
    """The filter's OCP as an RTI policy: :meth:`filter_command` takes the policy's physical
    command and an observation and returns the filtered one."""

    config_class = SafetyFilterConfig
    clearance_half_spaces = 3
    clearance_disturbance = A_EXT

    def __init__(self, config: SafetyFilterConfig | None = None, *, obstacles: Any = None, **overrides: Any) -> None:
        if obstacles is None:
            raise ValueError("a safety filter needs obstacles: the turbine to keep d_min from "
                             "(a TurbineProximity or env.mission)")
        super().__init__(config, obstacles=obstacles, **overrides)
        cfg = self.config
        self._params = np.zeros((cfg.horizon + 1, N_PARAMS))
        self._params[:, :NU] = cfg.hover_input
        self._params[0, NU] = 1.0
        self._rollout: Rollout | None = None
        if cfg.pass_through and self.clearance_active and isinstance(self.solver, RTISolver):
            opts = self.solver.options
            self._rollout = Rollout(self.ocp, compiled=opts.compiled, cache_dir=opts.cache_dir)
            # the candidate: the policy's command (row 0, set per step), then hover; slack 0
            self._candidate = np.zeros((cfg.horizon, self.ocp.nu))
            self._candidate[:, :NU] = cfg.hover_input

    def build_ocp(self, config: SafetyFilterConfig) -> OCP:
        """The filter's OCP."""
        return build_ocp(config)

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray, normal_xy: np.ndarray) -> np.ndarray:
        """The parameters of the present filter step (the command it keeps close to, set per
        step, and the observer's disturbance estimate)."""
        self._params[:, A_EXT] = self._a_hat
        return self._params

    def body_drag(self, config: SafetyFilterConfig) -> np.ndarray | None:
        """The model's linear drag (:func:`linear_drag`), which its clearance constraint credits."""
        return linear_drag(config)

    def _half_spaces(self, plan: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Three half-spaces per looked-up stage (see the module docstring): the tighter of the
        supporting half-spaces at the stage's position and the ground's; the one at its
        look-ahead point; and the free-ray bound along the stage's velocity."""
        cfg = self.config
        keep = cfg.d_min + cfg.clearance_backoff
        pos = plan[:, 0:3]
        vel = np.einsum("qij,qj->qi", quat_to_rotmat_np(plan[:, 6:10]), plan[:, 3:6])
        speed = np.linalg.norm(vel, axis=1)
        reach = speed * cfg.clearance_reaction + stopping_distance(speed, cfg.clearance_brake)
        q = len(pos)
        c0, d0, n0 = self.obstacles.closest(pos)
        # one sphere-tracing step towards the stopping point: within LOOKAHEAD_FRACTION of the
        # free ball around the position, so the point is outside the structure and its closest
        # point gives a supporting half-space
        ahead = vel / np.maximum(speed, 1e-9)[:, None]
        step = np.minimum(reach, LOOKAHEAD_FRACTION * d0)
        c1, d1, n1 = self.obstacles.closest(pos + ahead * step[:, None])
        self.last_clearance = float(d0[0]) if self._query_stages[0] == 0 else float("nan")
        normals = np.empty((q, 3, 3))
        offsets = np.empty((q, 3))
        # first: of [at the position, the ground] the one that leaves the least margin
        cn = np.stack([n0, np.broadcast_to((0.0, 0.0, 1.0), (q, 3))], axis=1)
        off = np.stack([np.einsum("ij,ij->i", n0, c0), np.zeros(q)], axis=1) + keep
        approach = np.maximum(0.0, -np.einsum("qij,qj->qi", cn, vel))
        margin = (np.einsum("qij,qj->qi", cn, pos) - off - approach * cfg.clearance_reaction
                  - stopping_distance(approach, cfg.clearance_brake))
        rows = np.arange(q)
        pick = margin.argmin(axis=1)
        normals[:, 0], offsets[:, 0] = cn[rows, pick], off[rows, pick]
        # second: the surface ahead, at the look-ahead point
        normals[:, 1], offsets[:, 1] = n1, np.einsum("ij,ij->i", n1, c1) + keep
        # third: the free ray ahead. The balls around the position (radius d0) and the
        # look-ahead point (d1, on the ray) hold no structure, so the ray is free for at least
        # L = max(d0, step + d1); the drone must stop within L - d_min along it:
        # ahead^T (p - pos) + stop <= L - keep, i.e. n = -ahead, b = -ahead^T pos - L + keep.
        free = np.maximum(d0, step + d1)
        normals[:, 2] = -ahead
        offsets[:, 2] = -np.einsum("ij,ij->i", ahead, pos) - free + keep
        # no direction at rest, and no room to bound once inside d_min (the first half-space
        # pushes out): an inactive bound (z >= -INACTIVE)
        idle = (speed < IDLE_SPEED) | (d0 <= keep)
        normals[idle, 2] = (0.0, 0.0, 1.0)
        offsets[idle, 2] = -INACTIVE
        return normals, offsets, float(min(d0.min(), d1.min(), pos[:, 2].min()))

    def _solve(self, state: np.ndarray, params: np.ndarray) -> np.ndarray:
        """One filter step: the policy's command when the candidate passes the rollout check
        (module docstring), else the QP's answer."""
        if self._rollout is None:
            return super()._solve(state, params)
        t0 = time.perf_counter()
        xm = self.model_state(state)
        self._last_solve = (xm, params)
        self._ahead = False
        solver = self.solver
        if not solver.initialized:
            solver.initialize(xm)
        P = self._with_clearance(params, xm)
        U = self._candidate
        U[0, :NU] = params[0, :NU]
        states, margin = self._rollout(xm, U, P)
        if float(margin.min()) >= self.config.pass_through_margin:   # NaN fails too
            solver.initialize(xm, inputs=U, states=states)
            u = self._finish_step(U[0].copy())
            ms = (time.perf_counter() - t0) * 1e3
            self.last_stats = SolveStats(solve_ms=ms, latency_ms=ms, status=PASSED, cost=0.0)
            return u
        solver.prepare(P)
        u = solver.feedback(xm)
        if solver.last_stats.fallback_source == "hover":      # no backup plan left: brake instead
            u = u.copy()
            u[:NU] = brake_command(xm, self.config)
            solver.last_stats.fallback_source = "brake"
        return self._finish_step(u)

    def filter_command(self, command: np.ndarray, obs: Mapping[str, Any]) -> np.ndarray:
        """The filtered physical command for the policy's physical ``command``."""
        self._params[:, :NU] = np.asarray(command, dtype=np.float64).reshape(NU)
        return self.command(obs)


def _policy_action(policy: Any, obs: Mapping[str, Any]) -> np.ndarray:
    """The wrapped policy's normalised action: ``act(obs)``, or an SB3-style ``predict``."""
    if callable(getattr(policy, "act", None)):
        return np.asarray(policy.act(obs), dtype=np.float64).reshape(-1)[:NU]
    action, _ = policy.predict(obs, deterministic=True)
    return np.asarray(action, dtype=np.float64).reshape(-1)[:NU]


@dataclass
class FilterStats:
    """What the filter did since the last reset: steps, interventions (the action changed by more
    than :data:`INTERVENTION_TOL`), the summed |correction| (max-norm, normalised action),
    fallbacks (QP failed: the backup plan flew), steps passed through without a QP and the
    filter's own time per step [ms]."""

    steps: int = 0
    interventions: int = 0
    correction_sum: float = 0.0
    fallbacks: int = 0
    passed: int = 0
    times_ms: list[float] = field(default_factory=list)

    def as_dict(self) -> dict[str, float]:
        """The counts and times as plain numbers, named ``filter_*`` (for results tables)."""
        t = np.asarray(self.times_ms or [np.nan])
        n = max(self.steps, 1)
        return {"filter_steps": float(self.steps), "filter_interventions": float(self.interventions),
                "filter_intervention_fraction": self.interventions / n,
                "filter_mean_correction": self.correction_sum / n, "filter_fallbacks": float(self.fallbacks),
                "filter_passed_fraction": self.passed / n,
                "filter_median_ms": float(np.nanmedian(t)), "filter_p99_ms": float(np.nanpercentile(t, 99))}


class SafetyFilter(Policy):
    """Wraps any policy (``act(obs)`` or SB3 ``predict``) so that its flight keeps d_min from the
    turbine of ``env`` (see the module docstring): ``SafetyFilter(policy, env)``, then
    :meth:`reset`, :meth:`act` / :meth:`predict` as for any policy; :attr:`stats` counts what it
    changed. ``overrides``: :class:`SafetyFilterConfig` fields."""

    def __init__(self, policy: Any, env: Any, **overrides: Any) -> None:
        if not (callable(getattr(policy, "act", None)) or callable(getattr(policy, "predict", None))):
            raise ValueError(f"the filtered policy must have act(obs) or predict(obs), got {type(policy).__name__}")
        from wt_inspect_env.planner.proximity import TurbineProximity
        u = getattr(env, "unwrapped", env)
        self.policy = policy
        self.mpc = FilterMPC(params=u.params, d_ref=u.config.standoff, control_dt=u.dt,
                             d_min=overrides.pop("d_min", u.config.d_min),
                             obstacles=TurbineProximity.from_env(u), **overrides)
        self.scaling = self.mpc.scaling
        self.stats = FilterStats()
        self.last_policy_action: np.ndarray | None = None

    @property
    def last_stats(self) -> Any:
        """The wrapped policy's own statistics (its solve time), for the harness."""
        return getattr(self.policy, "last_stats", None)

    def reset(self, seed: int | None = None) -> None:
        """Reset the wrapped policy, the filter's MPC and the statistics for a new episode."""
        if callable(getattr(self.policy, "reset", None)):
            self.policy.reset(seed=seed)
        self.mpc.reset(seed)
        self.stats = FilterStats()
        self.last_policy_action = None

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The wrapped policy's action, corrected by the filter where needed to keep d_min."""
        a_pol = np.clip(_policy_action(self.policy, obs), -1.0, 1.0)
        self.last_policy_action = a_pol
        t0 = time.perf_counter()
        out = self.mpc.action_of(self.mpc.filter_command(self.scaling.to_command(a_pol), obs))
        st = self.stats
        st.times_ms.append((time.perf_counter() - t0) * 1e3)
        st.steps += 1
        corr = float(np.abs(out - a_pol).max())
        st.correction_sum += corr
        st.interventions += corr > INTERVENTION_TOL
        st.fallbacks += bool(getattr(self.mpc.last_stats, "fallback", False))
        st.passed += getattr(self.mpc.last_stats, "status", "") == PASSED
        return out

    def predict(self, obs: Mapping[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """The SB3 interface: ``(action, None)``."""
        return self.act(obs), None
