"""The policy base class of every MPC on the RTI core (:class:`RTIPolicy`).

Preparation and feedback. With ``prepare_ahead`` off (the default, and how every published result
was made) each :meth:`~RTIPolicy.act` linearises for the new observation and then solves the QP:
the command waits for both. With ``prepare_ahead`` on, ``act`` runs only the feedback QP for the
measured state on the linearisation prepared at the end of the previous call, and then - after the
command exists - shifts the plan and prepares the next step at the *predicted* state (the plan's
next state) with the parameters predicted for it: the inspection point moved on by its velocity
over one control period, the attitude of the predicted state. This is what acados' ``rti_phase``
1/2 does: everything that depends on the measurement enters the feedback only through the initial
state constraint dx_0 = x_measured - x_0, while parameters are set before the preparation (so they
lag by one step, as in acados; estimators fed by the measurement update at the next feedback and
reach the QP one step later). ``last_stats.latency_ms`` is observation to command either way.
"""
from __future__ import annotations

import time
from typing import Any, ClassVar, Mapping

import numpy as np

from wt_inspect_env.physics.dynamics import NX, quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import GRAVITY
from wt_inspect_env.policy import Policy, check_observation, state_from_observation
from wt_inspect_env.task.geometry import HorizontalNormal
from wt_inspect_env.task.spaces import ActionScaling

from ..rti import OCP, IpoptOCPSolver, RTISolver, SolveStats
from .clearance import N_CLEARANCE_PARAMS, check_obstacles, clearance_ocp
from .config import MPCConfig, resolve_config, warm_start_shifts


class RTIPolicy(Policy):
    """An MPC policy on the RTI core: observation in, normalised (p, q, r, T) action out.

    ``Policy(config=None, obstacles=None, **overrides)`` (``obstacles``: the turbine to keep
    ``d_min`` from, see the module docstring); :meth:`reset`, :meth:`act`, :meth:`predict`,
    :meth:`set_weights`; :attr:`last_stats` (:class:`~controllers.rti.SolveStats`) after every
    call; :attr:`last_command` the physical command. See the module docstring for what a subclass
    provides.
    """

    config_class: ClassVar[type] = MPCConfig
    #: half-spaces each stage keeps (:meth:`_half_spaces`); the MPCs keep the nearest surface's
    clearance_half_spaces: ClassVar[int] = 1
    #: where the OCP's parameters hold the disturbance estimate the clearance constraint accounts
    #: for (None: it does not; the MPCs)
    clearance_disturbance: ClassVar[slice | None] = None

    def __init__(self, config: MPCConfig | None = None, *, obstacles: Any = None, **overrides: Any) -> None:
        config = resolve_config(self.config_class, config, overrides)
        self.config = config
        self.obstacles = check_obstacles(obstacles)
        self.base_ocp = self.build_ocp(config)
        self.clearance_active = bool(config.clearance and self.obstacles is not None)
        self._drag = self.body_drag(config)   # the model's linear drag: clearance credit, observer
        self.ocp = (clearance_ocp(self.base_ocp, config, self.clearance_half_spaces, self.clearance_disturbance,
                                  self._drag)
                    if self.clearance_active else self.base_ocp)
        self._nu = self.base_ocp.nu
        if self.clearance_active:
            N = config.horizon
            q = min(config.clearance_queries, N + 1)
            self._query_stages = np.unique(np.round(np.linspace(0, N, q)).astype(int))
            # each stage takes the half-space of the nearest looked-up stage
            self._stage_query = np.abs(np.arange(N + 1)[:, None] - self._query_stages[None, :]).argmin(axis=1)
            self._stage_params = np.zeros((N + 1, self.base_ocp.np + N_CLEARANCE_PARAMS * self.clearance_half_spaces))
        self.last_clearance = float("nan")
        # (positions, rotor position, least distance, stage normals, stage offsets) of the last look-up
        self._lookup: tuple[Any, ...] | None = None
        self.solver: RTISolver | IpoptOCPSolver = self._make_solver(config.weights)
        self.scaling: ActionScaling = config.scaling
        self._action_map: tuple[ActionScaling, np.ndarray, np.ndarray] | None = None
        self.shifts_per_step = warm_start_shifts(config.control_dt, config.dt)
        self.normal = HorizontalNormal()
        self._last_q: np.ndarray | None = None
        self._ahead = False            # a QP for the next observation is prepared
        self.last_stats: SolveStats = SolveStats()
        self.last_command: np.ndarray | None = None
        self._last_solve: tuple[np.ndarray, np.ndarray] | None = None   # (model state, params) of the last command
        self._prepared_params: np.ndarray | None = None
        self._prediction_offset: np.ndarray | None = None   # shadow mode: see note_applied_action
        self._a_hat = np.zeros(3)         # the disturbance observer's estimate (see on_measurement)
        # the attitude observer's last (world velocity, body z, model acceleration)
        self._observed: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._observer_primed = False     # the attitude observer has taken its first residual
        self._rotor_thrust: float | None = None   # the attitude observer's lagged rotor thrust [N]

    # -- what a subclass provides -----------------------------------------------------------------
    def build_ocp(self, config: Any) -> OCP:
        """The controller's least-squares OCP."""
        raise NotImplementedError(f"{type(self).__name__} must define build_ocp(config)")

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                   normal_xy: np.ndarray) -> np.ndarray:
        """The OCP's online parameters for a checked observation, the drone's model state and the
        horizontal normal (with its fallback already applied)."""
        raise NotImplementedError(f"{type(self).__name__} must define parameters(obs, state, normal_xy)")

    def model_state(self, state: np.ndarray) -> np.ndarray:
        """The OCP's state for a drone state [p, v_B, q] (identity unless the OCP augments it)."""
        return state

    def body_drag(self, config: MPCConfig) -> np.ndarray | None:
        """The linear body drag per unit mass [1/s] per axis of the OCP's model (None here: the
        MPCs' models have none). Its clearance constraint credits it to braking, and the attitude
        observer counts it as explained (:meth:`model_acceleration`)."""
        return None

    def model_acceleration(self, state: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """World-frame acceleration the OCP's model adds to gravity and thrust at ``state`` (its
        body-to-world ``rotation`` given): the drag of :meth:`body_drag`, zero without one. The
        attitude observer counts it as explained."""
        if self._drag is None:
            return np.zeros(3)
        return rotation @ (-self._drag * state[3:6])

    @property
    def disturbance_estimate(self) -> np.ndarray:
        """The observer's world-frame disturbance acceleration (zero when it is off)."""
        return self._a_hat.copy()

    def on_measurement(self, state: np.ndarray) -> None:
        """Called once per measured state, before its command is computed (estimators). The
        disturbance observer (``disturbance_observer``; a subclass feeds :attr:`_a_hat` to its
        model): a first-order filter (time constant tau) of the acceleration the model misses,
        world frame, bounded by ``observer_max_accel`` (0.8 g by default: the 7 m/s gust peaks
        need ~0.7 g on the Matrice-100-like drone). What it compares the measurement with is
        ``observer_model``:

        - ``"prediction"``: the plan's state for this step (model with the current a_hat), so
          a_hat += (v_measured - v_predicted) / (tau + dt).
        - ``"attitude"``: the acceleration measured over the step (velocity difference) less the
          model's for the *measured* attitudes (the body z axis averaged over the step), the
          applied thrust and the model's own extra terms (:meth:`model_acceleration`, e.g. the
          safety filter's drag); a_hat moves towards it by dt / (tau + dt). It needs no plan, so
          it reads the same whether the QP solved, failed or was skipped; the safety filter uses
          it.
        """
        if not self.config.disturbance_observer:
            return
        dt, tau = self.config.control_dt, self.config.observer_time_constant
        if self.config.observer_model == "attitude":
            R = quat_to_rotmat_np(state[6:10])
            v, z, a_model = R @ state[3:6], R[:, 2], self.model_acceleration(state, R)
            last, self._observed = self._observed, (v, z, a_model)
            if last is None or self.last_command is None:
                return
            thrust = self._applied_thrust(float(self.last_command[3]), dt) / self.config.params.mass
            explained = 0.5 * (z + last[1]) * thrust + 0.5 * (a_model + last[2]) - np.array([0.0, 0.0, GRAVITY])
            residual = (v - last[0]) / dt - explained
            if self._observer_primed:
                self._a_hat += (residual - self._a_hat) * (dt / (tau + dt))
            else:       # the first residual is the estimate: no lag of tau on a wind present at the start
                self._a_hat = residual
                self._observer_primed = True
        else:
            predicted = self.predicted_state
            if predicted is None:
                return
            self._a_hat += (self.world_velocity(state) - self.world_velocity(predicted)) / (tau + dt)
        norm = float(np.linalg.norm(self._a_hat))
        cap = self.config.observer_max_accel
        if norm > cap:
            self._a_hat *= cap / norm

    def _applied_thrust(self, command: float, dt: float) -> float:
        """The mean rotor thrust [N] over a step of ``dt`` with ``command`` held, for a first-order
        rotor lag (``params.motor_time_constant``) from the thrust the last step ended at (hover
        at the start, where the simulator starts its rotors); advances that state."""
        t_m = self.config.params.motor_time_constant
        start = float(self.config.hover_input[3]) if self._rotor_thrust is None else self._rotor_thrust
        if t_m <= 0.0:
            self._rotor_thrust = command
            return command
        decay = float(np.exp(-dt / t_m))
        self._rotor_thrust = command + (start - command) * decay
        return command + (start - command) * (t_m / dt) * (1.0 - decay)

    # -- common -----------------------------------------------------------------------------------
    def _weight_vectors(self, weights: Any) -> tuple[np.ndarray, np.ndarray]:
        w = self.config.solver_weights(weights)
        W, WN = w.stage_vector(), w.terminal_vector()
        if self.clearance_active:
            W = np.append(W, self.config.clearance_prices[1])
        return W, WN

    def _make_solver(self, weights: Any) -> RTISolver | IpoptOCPSolver:
        W, WN = self._weight_vectors(weights)
        if self.config.backend == "ipopt":
            return IpoptOCPSolver(self.ocp, W, WN)
        return RTISolver(self.ocp, W, WN, self.config.solver)

    def reset(self, seed: int | None = None) -> None:
        """Drop the warm start and everything remembered from the episode (the controller is
        deterministic; ``seed`` is accepted for the common interface)."""
        self.solver.reset()
        self.normal.reset()
        if self.obstacles is not None:
            self.obstacles.reset()
        self.last_clearance = float("nan")
        self._lookup = None
        self._last_q = None
        self._ahead = False
        self.last_stats = SolveStats()
        self.last_command = None
        self._last_solve = None
        self._prepared_params = None
        self._prediction_offset = None
        self._a_hat = np.zeros(3)
        self._observed = None
        self._observer_primed = False
        self._rotor_thrust = None

    def set_weights(self, weights: Any) -> None:
        """Switch weights: a weight object of the config's class or a set name. The RTI solver
        takes them without recompiling (they are runtime inputs of the QP data); IPOPT's NLP has
        them built in, so it is rebuilt."""
        sets = self.config.WEIGHT_SETS
        w = sets.get(weights) if isinstance(weights, str) else weights
        wcls = self.config.WEIGHTS
        if not isinstance(w, wcls):
            raise ValueError(f"weights must be {wcls.__name__} or one of {list(sets)}, got {weights!r}")
        if isinstance(self.solver, IpoptOCPSolver):
            self.solver = self._make_solver(w)
        else:
            self.solver.set_weights(*self._weight_vectors(w))
        self._ahead = False   # the prepared QP has the old weights

    def _align(self, state: np.ndarray) -> np.ndarray:
        """``state`` with its quaternion in the hemisphere of the previous step's: q and -q are
        the same attitude, but the warm-started plan is linearised around one of them, and a
        simulator may return the other mid-flight."""
        if self._last_q is not None and float(np.dot(state[6:10], self._last_q)) < 0.0:
            state = np.concatenate([state[0:6], -state[6:10]])
        self._last_q = state[6:10].copy()
        return state

    def _solve(self, state: np.ndarray, params: np.ndarray) -> np.ndarray:
        """One full real-time iteration (prepare, feedback, shift) or one IPOPT solve for an
        aligned drone state."""
        xm = self.model_state(state)
        self._last_solve = (xm, params)
        solver = self.solver
        if isinstance(solver, RTISolver):
            if not solver.initialized:
                solver.initialize(xm)
            solver.prepare(self._with_clearance(params, xm))
            u = solver.feedback(xm)
        else:
            u = solver.solve(xm, self._with_clearance(params, xm))
        self._ahead = False
        return self._finish_step(u)

    def _finish_step(self, u: np.ndarray) -> np.ndarray:
        self._prediction_offset = None      # a new plan: its own prediction holds until told otherwise
        for _ in range(self.shifts_per_step):
            self.solver.shift()
        self.last_stats = self.solver.last_stats
        self.last_command = u[:self._nu] if self.clearance_active else u
        return self.last_command

    def _with_clearance(self, params: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """The solver's parameters: ``params``, or with the clearance on the (N+1, np + 4 H)
        stage-wise array of ``params`` and each stage's H half-spaces [n, b] from
        :meth:`_half_spaces` at the looked-up stages of the plan (stage 0: ``x0``), looked up
        afresh when the rotor moved, the plan came near the structure or moved by more than
        ``clearance_refresh``."""
        if not self.clearance_active:
            return params
        P = self._stage_params
        npar = self.base_ocp.np
        P[:, :npar] = params
        solver = self.solver
        nq = len(self._query_stages)
        if isinstance(solver, RTISolver) and solver.initialized:
            plan = solver.state_view[self._query_stages]      # (a copy: fancy indexing)
        else:
            try:
                plan = self.ocp.unpack(solver.iterate)[0][self._query_stages]
            except RuntimeError:          # no plan yet (IPOPT before its first solve)
                plan = np.tile(x0[:NX], (nq, 1))
        plan[self._query_stages == 0, :NX] = x0[:NX]
        pos = plan[:, 0:3]
        last = self._lookup
        cfg = self.config
        if (last is None or last[1] != self.obstacles.index or last[2] < 0.5 * (cfg.d_min + cfg.d_ref)
                or float(np.abs(pos - last[0]).max()) > cfg.clearance_refresh):
            normals, offsets, least = self._half_spaces(plan)
            k = self._stage_query
            # each stage's half-spaces, kept until the next look-up
            self._lookup = last = (pos, self.obstacles.index, least, normals[k], offsets[k])
        for j in range(self.clearance_half_spaces):
            o = npar + N_CLEARANCE_PARAMS * j
            P[:, o:o + 3] = last[3][:, j]
            P[:, o + 3] = last[4][:, j]
        return P

    def _half_spaces(self, plan: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """The half-spaces of the looked-up stages' states ``plan`` (q, nx): outward normals
        (q, H, 3), offsets b = n^T c + d_min + back-off (q, H), and the least distance to the
        structure seen (for the look-up's refresh rule); sets :attr:`last_clearance`. The MPCs
        keep the supporting half-space of each stage's nearest mesh point."""
        c, d, n = self.obstacles.closest(plan[:, 0:3])
        self.last_clearance = float(d[0]) if self._query_stages[0] == 0 else float("nan")
        cfg = self.config
        offsets = np.einsum("ij,ij->i", n, c) + (cfg.d_min + cfg.clearance_backoff)
        return n[:, None, :], offsets[:, None], float(d.min())

    @property
    def predicted_state(self) -> np.ndarray | None:
        """The plan's drone state at the next control step (its first stage after the shift);
        None before the first step and when the control period is shorter than a stage."""
        if self.last_command is None or not self.shifts_per_step:
            return None
        if self._prediction_offset is not None:
            return self.solver.iterate[:NX] + self._prediction_offset
        return self.solver.iterate[:NX]

    def note_applied_action(self, action: Any) -> None:
        """Tell the controller which normalised env action was applied after its last :meth:`act`.

        Why: in *shadow* mode (the controller labels the states another policy flies into, as in
        DAgger) the executed command is not the controller's own, but :attr:`predicted_state` - what
        the disturbance observer of :meth:`on_measurement` compares the next measurement with, and
        where ``prepare_ahead`` linearises - is the plan's, which assumes its own command. This
        shifts that prediction by the model's answer to the difference: ``F(x, applied) - F(x, own)``
        over the control period (``F`` the OCP's dynamics with the parameters of the last solve,
        ``x`` the measured model state, both commands as the env executes them, saturated at the
        bounds). So the observer keeps seeing only the unmodelled acceleration whatever flies.
        With ``action`` equal to the controller's own action the shift is exactly zero and nothing
        changes; call it after every :meth:`act` whose command may not have been applied (a
        prepared-ahead linearisation has already used the unshifted prediction)."""
        if self.last_command is None or self._last_solve is None or not self.shifts_per_step:
            return
        applied = self.scaling.to_command(np.asarray(action, dtype=np.float64))
        own = self.scaling.to_command(self.scaling.to_action(self.last_command))
        x, params = self._last_solve
        f = self.base_ocp.dynamics
        xa, xo = x, x
        for _ in range(self.shifts_per_step):
            xa = np.asarray(f(xa, applied, params), dtype=float).ravel()
            xo = np.asarray(f(xo, own, params), dtype=float).ravel()
        offset = (xa - xo)[:NX]
        self._prediction_offset = offset if np.any(offset) else None

    def command_for(self, state: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Physical command [p, q, r, T] for a drone state and the OCP's parameters directly
        (one full step; for tests and callers that build their own parameters)."""
        return self._solve(self._align(np.asarray(state, dtype=float)), params)

    def command(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Physical command [p, q, r, T] for an observation (see the module docstring for the
        schedule of preparation and feedback)."""
        t0 = time.perf_counter()
        o = check_observation(obs)
        x = self._align(state_from_observation(o))
        self.on_measurement(x)
        if self.obstacles is not None:
            self.obstacles.update(o["point"], float(o["progress"][0]) if "progress" in o else None)
        if self._ahead:                      # only the feedback QP stands between obs and command
            u = self.solver.feedback(self.model_state(x))
            self._last_solve = (self.model_state(x), self._prepared_params)
            self._ahead = False
            latency = (time.perf_counter() - t0) * 1e3
            u = self._finish_step(u)
        else:
            nxy = self.normal.update(o["normal"], x[0:3], o["point"])
            u = self._solve(x, self.parameters(o, x, nxy))
            latency = (time.perf_counter() - t0) * 1e3
        self.last_stats.latency_ms = latency
        if self.config.prepare_ahead and isinstance(self.solver, RTISolver) and self.solver.initialized:
            self._prepare_next(o, x)
        return u

    def _prepare_next(self, obs: Mapping[str, np.ndarray], state: np.ndarray) -> None:
        """Linearise for the next control step at the predicted state, with the parameters
        predicted for it (the point moved on by its velocity over one control period)."""
        predicted = self.predicted_state
        if predicted is None:
            predicted = state
        nxt = {**obs, "point": obs["point"] + obs["point_velocity"] * self.config.control_dt,
               "position": predicted[0:3], "velocity_body": predicted[3:6], "quaternion": predicted[6:10]}
        nxy = self.normal.update(nxt["normal"], predicted[0:3], nxt["point"])
        self._prepared_params = self.parameters(nxt, predicted, nxy)
        self.solver.prepare(self._with_clearance(self._prepared_params, self.model_state(predicted)))
        self._ahead = True

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Normalised env action in [-1, 1]^4 for one observation."""
        return self.action_of(self.command(obs))

    def action_of(self, c: np.ndarray) -> np.ndarray:
        """The normalised env action of a physical command this policy computed."""
        # ActionScaling.to_action without its input check (the command is the solver's own finite
        # (4,) float64): the same operations on the same numbers, so the same float32 action
        scaling = self.scaling
        if self._action_map is None or self._action_map[0] is not scaling:
            lo = scaling.lower
            self._action_map = (scaling, lo, scaling.upper - lo)
        _, lo, span = self._action_map
        return np.clip(2.0 * (c - lo) / span - 1.0, -1.0, 1.0).astype(np.float32)

    @property
    def predicted_states(self) -> np.ndarray:
        """The current plan's drone states (N+1, 10) (shifted after each act; an augmented OCP
        state is cut to the drone's)."""
        return self.ocp.unpack(self.solver.iterate)[0][:, :NX]

    @staticmethod
    def world_velocity(state: np.ndarray) -> np.ndarray:
        """R(q) v_B of a drone state."""
        return quat_to_rotmat_np(state[6:10]) @ state[3:6]
