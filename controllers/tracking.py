"""Position-tracking pieces shared by the two baselines of the paper (NMPC and PAMPC).

Both baselines track a *trajectory* - the stand-off waypoint p + d_ref n_xy at the inspection point's
height, moving with the point - rather than a surface as the VT-NMPC does. The RTI core
(:mod:`controllers.rti`) holds the online parameters constant over the horizon, so a moving
reference needs the time since the measurement inside the model: the tracking OCPs use the shared
quadrotor model augmented by a *clock* state tau (tau_0 = 0, tau_{k+1} = tau_k + dt), and the
reference at stage k is

    p_ref(tau) = p_wp + v_pt tau,        v_ref = v_pt      (world frame)

which is exactly the trajectory the authors' ACADO baselines received stage by stage. Without it the
3 s PAMPC horizon would pull the drone back to a waypoint that the point has long left (about 1 m
of lag at 0.7 m/s). The clock adds one state whose dynamics are known exactly; its rows in the QP
are trivial.

Residuals (all zero at the reference, all invariant under q -> -q, all smooth):

=================  =================================================  =========================
residual           definition                                         why this form
=================  =================================================  =========================
position (3)       p - p_ref(tau)                                     world frame
velocity (3)       R(q) v_B - v_pt                                    world frame: the reference
                                                                      moves in the world, and
                                                                      R is quadratic in q
tilt (2)           (q_x, q_y)                                         zero iff level (any yaw);
                                                                      reference 0 so the sign of
                                                                      q cancels in the square
heading (2)        (R e_x)_xy - (cos psi_ref, sin psi_ref)            sign-safe yaw error, see
                                                                      below
inputs (4)         [p, q, r, T] - [0, 0, 0, m g]                      hover thrust of the one
                                                                      parameter set
=================  =================================================  =========================

Yaw. The authors tracked a quaternion built from a precomputed yaw; their yaw references jumped by
multiples of 360 deg, which flips the quaternion's sign and turns a least-squares quaternion cost
into a large spurious error (authors-code-notes.md). Here the yaw reference enters only through
(cos psi_ref, sin psi_ref) and the attitude only through the rotation matrix R(q), so a 360 deg wrap
or a quaternion sign flip changes nothing. For a level drone with yaw error e the residual's squared
norm is 2 - 2 cos e ~ e^2, against 2 - 2 cos(e/2) ~ e^2 / 4 for the quaternion components
(q_z, q_w) the authors weighted: a heading weight of w_qz / 4 has the same curvature at zero error.

The policy also aligns the measured quaternion with the previous one (q and -q are the same
attitude; the warm-started plan is linearised around one of them), so a simulator that returns
-q mid-flight does not disturb the real-time iteration either.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.dynamics import NU, NX, QuadrotorModel, quat_to_rotmat
from wt_inspect_env.quadrotor import GRAVITY, QuadrotorParams
from wt_inspect_env.spaces import ActionScaling
from wt_inspect_env.validation import check_array, check_choice, check_finite, check_positive

from wt_inspect_env.policy import Policy, check_observation
from .rti import OCP, IpoptOCPSolver, RTIOptions, RTISolver, SolveStats
from .vtnmpc import horizontal_normal, state_from_obs

NX_AUG = NX + 1          # model state + clock
CLOCK = NX               # index of the clock state
N_TRACKING_PARAMS = 8    # [p_wp (3), v_pt (3), cos psi_ref, sin psi_ref]
BACKENDS = ("rti", "ipopt")


# ------------------------------------------------------------------------------------------------
# validation helpers
# ------------------------------------------------------------------------------------------------

def weight_tuple(name: str, values: Any, n: int) -> tuple[float, ...]:
    """``values`` as ``n`` finite non-negative floats; ValueError naming ``name`` otherwise."""
    try:
        vals = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} numbers, got {values!r}") from None
    if len(vals) != n:
        raise ValueError(f"{name} must have {n} entries, got {len(vals)}")
    for i, v in enumerate(vals):
        check_positive(f"{name}[{i}]", v, allow_zero=True)
    return vals


def check_input_weights(name: str, values: tuple[float, ...]) -> None:
    """Gauss-Newton needs a positive-definite input block (R + B^T P B > 0 in HPIPM's Riccati
    recursion): a zero input weight can leave the QP singular."""
    for i, v in enumerate(values):
        if v == 0:
            raise ValueError(f"{name}[{i}] must be positive (a zero input weight makes the QP "
                             f"singular), got {v!r}")


def check_positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def warm_start_shifts(control_dt: float, dt: float) -> int:
    """How many stages to shift the plan after each control step.

    A control period equal to (or a multiple of) the shooting interval shifts by that many stages.
    A control period *shorter* than the stage (PAMPC: 0.01 s control, 0.1 s stages) keeps the plan
    where it is: its first stage starts "now" either way, and shifting by a whole stage would
    start the warm start 0.1 s in the future. Periods that are not a multiple are refused.
    """
    ratio = control_dt / dt
    if ratio < 1.0 - 1e-9:
        return 0
    n = int(round(ratio))
    if abs(ratio - n) > 1e-6:
        raise ValueError(f"control_dt must be shorter than dt or a multiple of it, got "
                         f"control_dt={control_dt!r}, dt={dt!r}")
    return n


def validate_tracking_config(cfg: Any, weights_cls: type, weight_sets: Mapping[str, Any]) -> None:
    """Validation shared by :class:`~controllers.nmpc.NMPCConfig` and
    :class:`~controllers.pampc.PAMPCConfig` (frozen dataclasses; fields are normalised in place)."""
    put = lambda k, v: object.__setattr__(cfg, k, v)  # noqa: E731 - frozen dataclass setter
    if not isinstance(cfg.params, QuadrotorParams):
        raise ValueError(f"params must be QuadrotorParams, got {type(cfg.params).__name__}")
    if isinstance(cfg.weights, str):
        if cfg.weights not in weight_sets:
            raise ValueError(f"unknown weights {cfg.weights!r}; valid: {', '.join(weight_sets)}")
        put("weights", weight_sets[cfg.weights])
    elif not isinstance(cfg.weights, weights_cls):
        raise ValueError(f"weights must be {weights_cls.__name__} or a set name, got {cfg.weights!r}")
    put("horizon", check_positive_int("horizon", cfg.horizon))
    put("rk4_steps", check_positive_int("rk4_steps", cfg.rk4_steps))
    put("dt", check_positive("dt", cfg.dt))
    put("d_ref", check_positive("d_ref", cfg.d_ref))
    if cfg.control_dt is None:
        put("control_dt", cfg.dt)
    put("control_dt", check_positive("control_dt", cfg.control_dt))
    warm_start_shifts(cfg.control_dt, cfg.dt)
    if cfg.scaling is None:
        put("scaling", ActionScaling.from_params(cfg.params))
    elif not isinstance(cfg.scaling, ActionScaling):
        raise ValueError(f"scaling must be an ActionScaling, got {cfg.scaling!r}")
    if not isinstance(cfg.solver, RTIOptions):
        raise ValueError(f"solver must be RTIOptions, got {cfg.solver!r}")
    check_choice("backend", cfg.backend, BACKENDS)


# ------------------------------------------------------------------------------------------------
# symbolic pieces
# ------------------------------------------------------------------------------------------------

def augmented_dynamics(name: str, params: QuadrotorParams, dt: float, rk4_steps: int,
                       n_params: int) -> ca.Function:
    """F(x_aug, u, p) -> x_aug_next: RK4 of the shared model plus the clock tau += dt."""
    model = QuadrotorModel(params)
    xa = ca.SX.sym("x", NX_AUG)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", n_params)
    xn = model.rk4_expr(xa[:NX], u, dt, steps=rk4_steps)
    return ca.Function(f"{name}_F", [xa, u, p], [ca.vertcat(xn, xa[CLOCK] + dt)],
                       ["x", "u", "p"], ["x_next"])


def tracking_terms(xa, p) -> dict[str, Any]:
    """The residual blocks of the module docstring for an augmented state and parameters
    ``p[:8] = [p_wp, v_pt, cos psi_ref, sin psi_ref]`` (symbolic)."""
    pos, vel_b, q, tau = xa[0:3], xa[3:6], xa[6:10], xa[CLOCK]
    R = quat_to_rotmat(q)
    p_ref = p[0:3] + p[3:6] * tau
    return {
        "position": pos - p_ref,
        "velocity": R @ vel_b - p[3:6],
        "tilt": q[0:2],
        "heading": ca.vertcat(R[0, 0] - p[6], R[1, 0] - p[7]),
        "rotation": R,
    }


def hover_input(params: QuadrotorParams) -> np.ndarray:
    return np.array([0.0, 0.0, 0.0, params.mass * GRAVITY])


# ------------------------------------------------------------------------------------------------
# references
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TrackingReference:
    """A waypoint moving at constant world velocity and a yaw to hold (radians, any winding)."""

    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    yaw: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", tuple(check_array("reference position",
                                                               self.position, (3,))))
        object.__setattr__(self, "velocity", tuple(check_array("reference velocity",
                                                               self.velocity, (3,))))
        object.__setattr__(self, "yaw", check_finite("reference yaw", self.yaw))

    def parameters(self) -> np.ndarray:
        """[p_wp, v_pt, cos yaw, sin yaw]: the yaw enters only through its direction."""
        return np.array([*self.position, *self.velocity, math.cos(self.yaw), math.sin(self.yaw)])


def standoff_reference(point: np.ndarray, normal_xy: np.ndarray, point_velocity: np.ndarray,
                       d_ref: float) -> TrackingReference:
    """The paper's baseline reference: p + d_ref n_xy at the point's height, the point's velocity,
    and the yaw that faces the surface (along -n_xy)."""
    n = np.asarray(normal_xy, dtype=float)
    pos = np.asarray(point, dtype=float) + d_ref * np.array([n[0], n[1], 0.0])
    return TrackingReference(tuple(pos), tuple(np.asarray(point_velocity, dtype=float)),
                             math.atan2(-n[1], -n[0]))


def align_quaternion(q: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """``q`` or ``-q``, whichever lies in the hemisphere of ``previous`` (same attitude)."""
    if previous is not None and float(np.dot(q, previous)) < 0.0:
        return -q
    return q


# ------------------------------------------------------------------------------------------------
# the policy base class
# ------------------------------------------------------------------------------------------------

def resolve_config(config_cls: type, config: Any, overrides: Mapping[str, Any]) -> Any:
    """A config from ``config`` and/or keyword overrides (unknown options named in the error)."""
    if config is None:
        known = {f.name for f in fields(config_cls)}
        bad = sorted(set(overrides) - known)
        if bad:
            raise ValueError(f"unknown {config_cls.__name__} option(s) {bad}; valid: {sorted(known)}")
        return config_cls(**overrides)
    if not isinstance(config, config_cls):
        raise ValueError(f"config must be a {config_cls.__name__}, got {type(config).__name__}")
    if overrides:
        known = {f.name for f in fields(config_cls)}
        bad = sorted(set(overrides) - known)
        if bad:
            raise ValueError(f"unknown {config_cls.__name__} option(s) {bad}; valid: {sorted(known)}")
        config = dataclasses.replace(config, **overrides)
    return config


class TrackingMPCPolicy(Policy):
    """Common policy machinery of the tracking baselines (same interface as ``VTNMPCPolicy``).

    Subclasses define ``config_class``, ``weight_sets``, :meth:`build_ocp` and
    :meth:`parameters_for`. Each :meth:`act` runs one real-time iteration (prepare, feedback,
    warm-start shift - see :func:`warm_start_shifts`); :attr:`last_stats` holds its
    :class:`SolveStats`.
    """

    config_class: type = object
    weight_sets: Mapping[str, Any] = {}

    def __init__(self, config: Any = None, **overrides: Any) -> None:
        config = resolve_config(self.config_class, config, overrides)
        self.config = config
        self.ocp = self.build_ocp(config)
        W, WN = config.weights.stage_vector(), config.weights.terminal_vector()
        if config.backend == "ipopt":
            self.solver: RTISolver | IpoptOCPSolver = IpoptOCPSolver(self.ocp, W, WN)
        else:
            self.solver = RTISolver(self.ocp, W, WN, config.solver)
        self.scaling: ActionScaling = config.scaling
        self.shifts_per_step = warm_start_shifts(config.control_dt, config.dt)
        self._normal_xy: np.ndarray | None = None
        self._last_q: np.ndarray | None = None
        self.last_stats: SolveStats = SolveStats()
        self.last_command: np.ndarray | None = None

    # -- to be provided by the subclasses ---------------------------------------------------------
    def build_ocp(self, config: Any) -> OCP:  # pragma: no cover - abstract
        raise NotImplementedError

    def parameters_for(self, reference: TrackingReference, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Online parameter vector of the OCP for a reference (and the checked observation)."""
        return reference.parameters()

    # -- common -----------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> None:
        """Drop the warm start (the controller is deterministic; ``seed`` is accepted for the
        common interface)."""
        self.solver.reset()
        self._normal_xy = None
        self._last_q = None
        self.last_stats = SolveStats()
        self.last_command = None

    def set_weights(self, weights: Any) -> None:
        """Switch weights without recompiling (they are runtime inputs of the QP data)."""
        w = self.weight_sets.get(weights) if isinstance(weights, str) else weights
        wcls = type(self.config.weights)
        if not isinstance(w, wcls):
            raise ValueError(f"weights must be {wcls.__name__} or one of {list(self.weight_sets)}, "
                             f"got {weights!r}")
        self.solver.set_weights(w.stage_vector(), w.terminal_vector())

    def reference(self, obs: Mapping[str, np.ndarray], state: np.ndarray) -> TrackingReference:
        """Stand-off reference of a checked observation. A normal without horizontal part
        (top/bottom faces) keeps the previous horizontal normal, or - at the first step - points
        from the inspection point towards the drone (as the VT-NMPC does)."""
        fallback = self._normal_xy
        if fallback is None:
            away = state[:2] - obs["point"][:2]
            fallback = horizontal_normal(np.append(away, 0.0), np.array([1.0, 0.0]))
        nxy = horizontal_normal(obs["normal"], fallback)
        self._normal_xy = nxy
        return standoff_reference(obs["point"], nxy, obs["point_velocity"], self.config.d_ref)

    def augmented_state(self, state: np.ndarray) -> np.ndarray:
        """[x, tau = 0] with the quaternion in the hemisphere of the previous step's."""
        x = np.asarray(state, dtype=float)
        q = align_quaternion(x[6:10], self._last_q)
        self._last_q = q
        return np.concatenate([x[0:6], q, [0.0]])

    def command_for(self, state: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Physical command [p, q, r, T] for a model state and online parameters (one RTI step)."""
        xa = self.augmented_state(state)
        solver = self.solver
        if isinstance(solver, RTISolver):
            if not solver.initialized:
                solver.initialize(xa)
            solver.prepare(params)
            u = solver.feedback(xa)
        else:
            u = solver.solve(xa, params)
        for _ in range(self.shifts_per_step):
            solver.shift()
        self.last_stats = solver.last_stats
        self.last_command = u
        return u

    def command(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Physical command [p, q, r, T] for an observation."""
        o = check_observation(obs)
        x = state_from_obs(o)
        params = self.parameters_for(self.reference(o, x), o)
        return self.command_for(x, params)

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        return self.scaling.to_action(self.command(obs))

    @property
    def predicted_states(self) -> np.ndarray:
        """The current plan's model states (N+1, 10) (clock dropped)."""
        if isinstance(self.solver, RTISolver):
            xs = self.solver.states
        else:
            xs = self.ocp.unpack(self.solver.iterate)[0]
        return xs[:, :NX]
