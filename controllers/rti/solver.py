"""The real-time-iteration solver (:class:`RTISolver`), its options and per-step statistics.

See the package docstring for the method.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from wt_inspect_env.util.validation import check_array, check_choice, check_field_types, check_positive

from ..codegen import CompiledFunction, compile_function, uncompiled
from .ocp import BOUND_INF, OCP
from .qp_data import build_qp_data_function, build_stage_qp_data_function, stage_parameter_matrix

QP_SOLVERS = ("casadi", "hpipm")

HPIPM_STATUS: dict[int, str] = {
    0: "SUCCESS", 1: "MAX_ITER", 2: "MIN_STEP", 3: "NAN_SOL", 4: "INCONSISTENT_EQ",
}


@dataclass(frozen=True)
class RTIOptions:
    """Solver options. ``qp_mode`` is HPIPM's preset (speed_abs, speed, balance, robust);
    ``regularization`` adds a Levenberg-Marquardt term to the Gauss-Newton Hessian (it only damps
    steps, the converged point is unchanged); ``compiled`` selects generated C for the QP data.
    ``qp_solver``: ``"casadi"`` calls HPIPM through CasADi's ``conic`` plugin; ``"hpipm"`` calls
    it directly (:mod:`controllers.hpipm_direct`: memory allocated once, only finite bounds, x_0
    eliminated, the QP loaded in the preparation phase; path constraints as HPIPM's general
    constraints); where the direct path cannot be built (no compiler, no libhpipm) it warns and uses CasADi's.
    ``qp_mu0``: HPIPM's initial barrier parameter (None: the ``qp_mode`` preset's, 10 for
    ``speed_abs``). 1.0 is acados' value: on the VT-NMPC it needs fewer interior-point
    iterations and lands closer to the converged QP solution when rate bounds are active
    (``wt-inspect bench solver``).
    ``tangential_predictor`` (with ``qp_solver="hpipm"``): the preparation also solves the QP for
    the state the plan predicts and the solution's gains with respect to x_0 with its active input
    bounds held (a Riccati recursion on the free inputs); the feedback is then that affine map of
    the measured state (a few microseconds) - the exact QP solution as long as the active set does
    not change, and the full QP is solved whenever a free input would leave its bounds. Pays off
    when the preparation runs ahead of the measurement (``prepare_ahead`` of the policies)."""

    compiled: bool = True
    cache_dir: str | None = None
    qp_mode: str = "speed"
    qp_iter_max: int = 50
    qp_tol: float = 1e-6
    regularization: float = 0.0
    qp_solver: str = "casadi"
    qp_mu0: float | None = None
    tangential_predictor: bool = False

    def __post_init__(self) -> None:
        check_field_types(self, "solver ")
        check_choice("qp_mode", self.qp_mode, ("speed_abs", "speed", "balance", "robust"))
        check_choice("qp_solver", self.qp_solver, QP_SOLVERS)
        if self.qp_mu0 is not None:
            check_positive("qp_mu0", self.qp_mu0)
        if not isinstance(self.tangential_predictor, bool):
            raise ValueError(f"tangential_predictor must be a bool, got {self.tangential_predictor!r}")
        if self.tangential_predictor and self.qp_solver != "hpipm":
            raise ValueError("tangential_predictor needs qp_solver='hpipm', got "
                             f"qp_solver={self.qp_solver!r}")
        if isinstance(self.qp_iter_max, bool) or not isinstance(self.qp_iter_max, int) \
                or self.qp_iter_max < 1:
            raise ValueError(f"qp_iter_max must be a positive integer, got {self.qp_iter_max!r}")
        check_positive("qp_tol", self.qp_tol)
        check_positive("regularization", self.regularization, allow_zero=True)


@dataclass
class SolveStats:
    """What one control step (or one SQP solve) cost and how it ended.

    ``solve_ms`` = preparation + feedback; ``feedback_ms`` is the QP alone; ``latency_ms`` is the
    time from measurement to command (the feedback, plus the preparation when it ran after the
    measurement arrived). ``status`` is HPIPM's flag name (``SUCCESS``, ``MAX_ITER``, ``MIN_STEP``,
    ``NAN_SOL``...) or ``NONFINITE`` when the step contained NaN/inf; ``fallback`` tells whether
    the command came from the shifted previous plan / hover instead of this QP; ``predicted`` that
    the feedback was the tangential predictor (its QP iterations were spent in the preparation).
    """

    solve_ms: float = 0.0
    prepare_ms: float = 0.0
    feedback_ms: float = 0.0
    latency_ms: float = 0.0
    qp_iterations: int = 0
    status: str = "NOT_SOLVED"
    fallback: bool = False
    fallback_source: str = ""
    predicted: bool = False
    cost: float = float("nan")
    sqp_iterations: int = 0
    step_norm: float = float("nan")

    def as_dict(self) -> dict[str, Any]:
        """The statistics as a plain dict (for logs and records)."""
        return dict(self.__dict__)


class RTISolver:
    """Real-time-iteration solver for an :class:`OCP` (see the module docstring for the method).

    Typical control loop::

        solver.initialize(x_meas)               # once
        solver.prepare(p); u = solver.feedback(x_meas); solver.shift()   # every step

    Speed: the QP-data function and HPIPM are evaluated through CasADi ``FunctionBuffer`` objects
    bound to preallocated NumPy arrays, so no Python<->CasADi conversion happens on the hot path
    (a single ``casadi.DM`` conversion of a 430-vector costs about as much as the whole compiled
    preparation; ``wt-inspect bench solver`` measures the step). The iterate, parameters,
    weights, QP data and bounds live in those arrays and are only ever modified in place.
    """

    def __init__(self, ocp: OCP, stage_weights, terminal_weights,
                 options: RTIOptions | None = None) -> None:
        if not isinstance(ocp, OCP):
            raise ValueError(f"ocp must be an OCP, got {type(ocp).__name__}")
        if options is not None and not isinstance(options, RTIOptions):
            raise ValueError(f"options must be RTIOptions, got {options!r}")
        self.ocp = ocp
        self.options = options or RTIOptions()
        W, WN = ocp.check_weights(stage_weights, terminal_weights)

        t0 = time.perf_counter()
        fun = build_qp_data_function(ocp, self.options.regularization)
        self.build_seconds = time.perf_counter() - t0
        if self.options.compiled:
            self.qp_data: CompiledFunction = compile_function(fun, cache_dir=self.options.cache_dir)
        else:
            self.qp_data = uncompiled(fun)
        self._qp_fun = self.qp_data.function

        N, nx, nu, nh = ocp.horizon, ocp.nx, ocp.nu, ocp.nh
        qp_struct = {"h": fun.sparsity_out("H"), "a": fun.sparsity_out("A")}
        for name in ("H", "A"):
            if self._qp_fun.sparsity_out(name).get_triplet() != fun.sparsity_out(name).get_triplet():
                raise RuntimeError(f"compiled QP data has a different sparsity of {name}; "
                                   "clear the cache directory")
        qp_opts = {
            "N": N, "nx": [nx] * (N + 1), "nu": [nu] * N + [0], "ng": [nh] * N + [0],
            "error_on_fail": False,
            "hpipm": {"mode": self.options.qp_mode, "iter_max": self.options.qp_iter_max,
                      "res_g_max": self.options.qp_tol, "res_b_max": self.options.qp_tol,
                      "res_d_max": self.options.qp_tol, "res_m_max": self.options.qp_tol},
        }
        if self.options.qp_mu0 is not None:
            qp_opts["hpipm"]["mu0"] = float(self.options.qp_mu0)
        self._qp = ca.conic(f"{ocp.name}_qp", "hpipm", qp_struct, qp_opts)

        # absolute variable bounds in stage order; x_0 is replaced by the measurement each step.
        # Infinite bounds become +-BOUND_INF here (HPIPM bounds every variable; CasADi's own
        # replacement of infinities does not cover every bound vector in all versions).
        self._lb_abs = np.clip(np.concatenate(
            [np.tile(np.concatenate([ocp.x_lower, ocp.u_lower]), N), ocp.x_lower]),
            -BOUND_INF, BOUND_INF)
        self._ub_abs = np.clip(np.concatenate(
            [np.tile(np.concatenate([ocp.x_upper, ocp.u_upper]), N), ocp.x_upper]),
            -BOUND_INF, BOUND_INF)

        # ---- preallocated arrays shared with the CasADi buffers (modify in place only) --------
        self._w = np.zeros(ocp.n_vars)
        # [x0 u0 x1 u1 ... xN]: the states are every (nx + nu)-th block of nx, x_N included
        self._state_view = np.lib.stride_tricks.as_strided(
            self._w, shape=(N + 1, nx), strides=((nx + nu) * self._w.itemsize, self._w.itemsize), writeable=False)
        self._p = np.zeros(ocp.np * (N + 1))           # stage-major: row k of (N+1, np) is stage k
        self._P = self._p.reshape(N + 1, ocp.np)
        self._W = W
        self._WN = WN
        qf = self._qp_fun
        self._data_out = [np.zeros(qf.sparsity_out(i).nnz()) for i in range(qf.n_out())]
        self._H, self._g, self._A, self._lba, self._uba, self._cost_buf = self._data_out
        self._lbx = np.zeros(ocp.n_vars)
        self._ubx = np.zeros(ocp.n_vars)
        self._data_buf, self._data_eval = qf.buffer()
        for i, arr in enumerate((self._w, self._p, self._W, self._WN)):
            self._data_buf.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._data_out):
            self._data_buf.set_res(i, memoryview(arr))

        qp = self._qp
        qp_in = {"h": self._H, "g": self._g, "a": self._A, "lba": self._lba, "uba": self._uba,
                 "lbx": self._lbx, "ubx": self._ubx}
        self._qp_in = [qp_in.get(qp.name_in(i), np.zeros(qp.sparsity_in(i).nnz()))
                       for i in range(qp.n_in())]
        self._qp_out = [np.zeros(qp.sparsity_out(i).nnz()) for i in range(qp.n_out())]
        self._dw = self._qp_out[0]
        self._qp_in_views = [memoryview(a) for a in self._qp_in]
        self._qp_out_views = [memoryview(a) for a in self._qp_out]

        self._direct = None
        if self.options.qp_solver == "hpipm":
            self._setup_direct(ocp)

        self._initialized = False
        self._prepared = False
        self._prepare_ms = 0.0
        self._since_success = 0
        self.last_stats = SolveStats()

    def _setup_direct(self, ocp: OCP) -> None:
        """The direct HPIPM path (:mod:`controllers.hpipm_direct`); warns and keeps CasADi's
        plugin where it cannot be built."""
        from ..hpipm_direct import HpipmQP
        finite = np.flatnonzero(np.isfinite(ocp.x_lower) | np.isfinite(ocp.x_upper))
        try:
            qp = HpipmQP(ocp.horizon, ocp.nx, ocp.nu, finite, mode=self.options.qp_mode,
                         iter_max=self.options.qp_iter_max, tol=self.options.qp_tol,
                         mu0=self.options.qp_mu0, cache_dir=self.options.cache_dir,
                         g_lower_open=~np.isfinite(ocp.h_lower) if ocp.nh else None,
                         g_upper_open=~np.isfinite(ocp.h_upper) if ocp.nh else None)
        except RuntimeError as exc:
            warnings.warn(f"qp_solver='hpipm' unavailable ({exc}); using CasADi's HPIPM plugin",
                          RuntimeWarning, stacklevel=3)
            return
        fun = build_stage_qp_data_function(ocp, self.options.regularization)
        data = compile_function(fun, cache_dir=self.options.cache_dir) if self.options.compiled else uncompiled(fun)
        f = data.function
        N, nx, nu = ocp.horizon, ocp.nx, ocp.nu
        outs = [np.zeros(f.sparsity_out(i).nnz()) for i in range(f.n_out())]
        buf, evaluate = f.buffer()
        for i, arr in enumerate((self._w, self._p, self._W, self._WN)):
            buf.set_arg(i, memoryview(arr))
        for i, arr in enumerate(outs):
            buf.set_res(i, memoryview(arr))
        nb = finite.size
        bounds = [np.zeros((N, nu)), np.zeros((N, nu)), np.zeros((N, max(nb, 1))), np.zeros((N, max(nb, 1)))]
        self._dx0 = np.zeros(nx)
        self._direct = {
            "qp": qp, "data": data, "buf": buf, "eval": evaluate, "outs": outs, "cost": outs[8],
            "bounds": bounds, "finite": finite,
            "u_lo": np.tile(ocp.u_lower, (N, 1)), "u_hi": np.tile(ocp.u_upper, (N, 1)),
            # a one-sided bound keeps +-BOUND_INF on its open side (only bounded states are passed)
            "x_lo": np.tile(np.clip(ocp.x_lower[finite], -BOUND_INF, BOUND_INF), (N, 1)),
            "x_hi": np.tile(np.clip(ocp.x_upper[finite], -BOUND_INF, BOUND_INF), (N, 1)),
            "ptrs": [a.ctypes.data for a in outs[:8]] + [a.ctypes.data for a in bounds]
                    + ([a.ctypes.data for a in outs[9:13]] if ocp.nh else [0, 0, 0, 0]),
            "dx0_ptr": self._dx0.ctypes.data, "dw_ptr": self._dw.ctypes.data,
        }

    @property
    def qp_solver(self) -> str:
        """The QP path in use: ``"hpipm"`` (direct) or ``"casadi"``."""
        return "hpipm" if self._direct is not None else "casadi"

    # ---- state of the iteration ---------------------------------------------------------------
    @property
    def initialized(self) -> bool:
        """Whether the solver has a plan to warm-start from (:meth:`initialize` or a solve)."""
        return self._initialized

    @property
    def iterate(self) -> np.ndarray:
        """The current guess/plan w = [x0 u0 ... xN] (a copy)."""
        if not self._initialized:
            raise RuntimeError("solver not initialized: call initialize(x0) first")
        return self._w.copy()

    @property
    def state_view(self) -> np.ndarray:
        """The plan's states (N+1, nx) as a read-only view of the iterate (no copy; it follows
        the iterate as it changes - copy it to keep it)."""
        return self._state_view

    @property
    def states(self) -> np.ndarray:
        """The planned states, (N+1, nx) (a copy)."""
        return self.ocp.unpack(self.iterate)[0]

    @property
    def inputs(self) -> np.ndarray:
        """The planned inputs, (N, nu) (a copy)."""
        return self.ocp.unpack(self.iterate)[1]

    @property
    def stage_weights(self) -> np.ndarray:
        """The stage residual's weights in use (a copy)."""
        return self._W.copy()

    @property
    def terminal_weights(self) -> np.ndarray:
        """The terminal residual's weights in use (a copy)."""
        return self._WN.copy()

    def set_weights(self, stage_weights, terminal_weights) -> None:
        """New weights, used from the next :meth:`prepare` (no recompilation: they are inputs)."""
        W, WN = self.ocp.check_weights(stage_weights, terminal_weights)
        self._W[:] = W
        self._WN[:] = WN
        self._prepared = False

    def initialize(self, x0, inputs=None, states=None) -> None:
        """Initial guess: given states/inputs, else x0 held over the horizon with the fallback
        input (hover). Resets the failure counter."""
        ocp = self.ocp
        x0 = check_array("x0", x0, (ocp.nx,))
        us = np.tile(ocp.fallback_input, (ocp.horizon, 1)) if inputs is None else \
            check_array("inputs", inputs, (ocp.horizon, ocp.nu))
        xs = np.tile(x0, (ocp.horizon + 1, 1)) if states is None else \
            check_array("states", states, (ocp.horizon + 1, ocp.nx))
        self._w[:] = ocp.pack(xs, us)
        self._initialized = True
        self._prepared = False
        self._since_success = 0

    def reset(self) -> None:
        """Forget the plan (the next :meth:`step` or :meth:`initialize` starts from scratch)."""
        self._initialized = False
        self._prepared = False
        self._since_success = 0
        self.last_stats = SolveStats()

    def shift(self) -> None:
        """Move the plan one stage forward (warm start of the next step); the last stage is
        repeated. The preparation must be redone afterwards."""
        if not self._initialized:
            return
        nz, nx = self.ocp.nx + self.ocp.nu, self.ocp.nx
        w = self._w
        n_body = self.ocp.horizon * nz
        w[:n_body - nz] = w[nz:n_body].copy()          # stages 1..N-1 -> 0..N-2
        w[n_body - nz:n_body - nz + nx] = w[n_body:]    # x_{N-1} <- old x_N, u_{N-1} kept
        self._prepared = False

    # ---- the two phases ------------------------------------------------------------------------
    def check_params(self, params) -> np.ndarray:
        """``params`` as the (N+1, np) stage-wise array (see :func:`stage_parameter_matrix`)."""
        return stage_parameter_matrix(self.ocp, params)

    def _param_arg(self, params) -> np.ndarray:
        """The QP-data function's parameter input (np x (N+1)) for ``params``."""
        return np.ascontiguousarray(self.check_params(params).T)

    def prepare(self, params) -> None:
        """Linearise at the current guess for parameters ``params`` (no measurement needed):
        ``(np,)`` for the same parameters at every stage, ``(N+1, np)`` for one row per stage."""
        if not self._initialized:
            raise RuntimeError("solver not initialized: call initialize(x0) first")
        P = self._P
        if type(params) is np.ndarray and params.dtype == np.float64 and params.shape[-1:] == P.shape[1:] \
                and params.ndim <= 2 and (params.ndim == 1 or params.shape[0] == P.shape[0]) \
                and math.isfinite(params.sum()):
            P[:] = params   # the policies' own float64 arrays: no conversion, the same values
        else:               # anything else is converted and checked (one-line errors)
            P[:] = self.check_params(params)
        t0 = time.perf_counter()
        if self._direct is not None:
            self._prepare_direct()
        else:
            self._data_eval()
            np.subtract(self._lb_abs, self._w, out=self._lbx)
            np.subtract(self._ub_abs, self._w, out=self._ubx)
        self._prepare_ms = (time.perf_counter() - t0) * 1e3
        self._prepared = True

    def _prepare_direct(self) -> None:
        """Stage-wise QP data and the step bounds, loaded into HPIPM (no measurement needed)."""
        d = self._direct
        d["eval"]()
        ocp = self.ocp
        N, nx, nu = ocp.horizon, ocp.nx, ocp.nu
        body = self._w[:N * (nx + nu)].reshape(N, nx + nu)
        lbu, ubu, lbx, ubx = d["bounds"]
        np.subtract(d["u_lo"], body[:, nx:], out=lbu)
        np.subtract(d["u_hi"], body[:, nx:], out=ubu)
        if d["finite"].size:
            xs = np.vstack([body[1:, :nx], self._w[N * (nx + nu):][None, :]])[:, d["finite"]]
            np.subtract(d["x_lo"], xs, out=lbx)
            np.subtract(d["x_hi"], xs, out=ubx)
        d["qp"].load(*d["ptrs"])
        if self.options.tangential_predictor:   # solve for the predicted x_0 (dx_0 = 0), then the gains
            self._dx0[:] = 0.0
            code, iterations = d["qp"].feedback(d["dx0_ptr"], d["dw_ptr"])
            d["base"] = (code, iterations) if d["qp"].sensitivities(d["dx0_ptr"], d["dw_ptr"], code) else None

    def _solve_qp(self) -> dict:
        """HPIPM on the arrays bound to the QP inputs/outputs; returns its statistics.

        A fresh ``FunctionBuffer`` (cheap beside the solve) is made per solve: CasADi 3.8's HPIPM plugin returns
        the *first* solution again when one buffer is re-evaluated after its inputs changed
        (tests/controllers/test_rti.py guards this against ``Function.call``).
        """
        buf, evaluate = self._qp.buffer()
        for i, view in enumerate(self._qp_in_views):
            buf.set_arg(i, view)
        for i, view in enumerate(self._qp_out_views):
            buf.set_res(i, view)
        evaluate()
        return buf.stats()

    def feedback(self, x0) -> np.ndarray:
        """Solve the prepared QP for the measured state ``x0``; returns the input to apply.

        Only the bounds of dx_0 change here. A QP that fails or returns NaN/inf is not applied:
        the command comes from the shifted previous plan (or hover) and ``last_stats`` says so.
        """
        if not self._prepared:
            raise RuntimeError("no prepared QP: call prepare(params) after initialize/shift")
        ocp = self.ocp
        nx, nu = ocp.nx, ocp.nu
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (nx,) or not (math.isfinite(x0.sum()) or np.isfinite(x0).all()):
            raise ValueError(f"x0 must be {nx} finite numbers, got {x0!r}")
        w, dw = self._w, self._dw
        t0 = time.perf_counter()
        predicted = False
        status = None
        # a finite sum means every entry is finite; an infinite one may still be an overflow
        if not (math.isfinite(w.sum()) or np.isfinite(w).all()):
            # A non-finite warm start (a diverged plan, a corrupted guess) makes ill-posed QP
            # bounds, which CasADi's plugin refuses by raising; it is a failed step like any other.
            code, iterations, cost, status = -1, 0, float("nan"), "NONFINITE_ITERATE"
            if self._direct is not None:
                self._direct["base"] = None
        elif self._direct is not None:
            d = self._direct
            np.subtract(x0, w[:nx], out=self._dx0)
            if d.get("base") is not None and d["qp"].predict(d["dx0_ptr"], d["dw_ptr"]):
                (code, iterations), predicted = d["base"], True
            else:
                code, iterations = d["qp"].feedback(d["dx0_ptr"], d["dw_ptr"])
            d["base"] = None
            cost = float(d["cost"][0])
        else:
            np.subtract(x0, w[:nx], out=self._lbx[:nx])
            self._ubx[:nx] = self._lbx[:nx]
            try:
                stats = self._solve_qp()
                code, iterations = int(stats.get("return_status", -1)), int(stats.get("iter_count", -1))
            except RuntimeError as exc:   # CasADi's checks of ill-posed QP data (NaN in a bound)
                code, iterations, status = -1, 0, "QP_ERROR: " + str(exc).strip().splitlines()[-1][:120]
            cost = float(self._cost_buf[0])
        elapsed = (time.perf_counter() - t0) * 1e3
        self._prepared = False
        if status is None:
            status = HPIPM_STATUS.get(code, f"HPIPM_{code}")
        ok = code == 0 and (math.isfinite(dw.sum()) or bool(np.isfinite(dw).all()))
        if code == 0 and not ok:
            status = "NONFINITE"
        st = SolveStats(prepare_ms=self._prepare_ms, feedback_ms=elapsed,
                        solve_ms=self._prepare_ms + elapsed, latency_ms=self._prepare_ms + elapsed,
                        qp_iterations=iterations, status=status, cost=cost, predicted=predicted)
        if ok:
            w += dw
            st.step_norm = float(max(dw.max(), -dw.min()))
            self._since_success = 0
            u0 = np.minimum(np.maximum(w[nx:nx + nu], ocp.u_lower), ocp.u_upper)
        else:
            st.fallback = True
            self._since_success += 1
            # w is the previous plan, shifted once per step since the last success
            if self._since_success < ocp.horizon and np.all(np.isfinite(w)):
                st.fallback_source = "shifted_plan"
                u0 = np.clip(w[nx:nx + nu], ocp.u_lower, ocp.u_upper)
            else:
                st.fallback_source = "hover"
                u0 = ocp.fallback_input.copy()
                w[:] = ocp.pack(np.tile(x0, (ocp.horizon + 1, 1)),
                                np.tile(ocp.fallback_input, (ocp.horizon, 1)))
        self.last_stats = st
        return u0

    def step(self, x0, params) -> np.ndarray:
        """One RTI control step: initialise if needed, prepare, feedback, shift."""
        if not self._initialized:
            self.initialize(x0)
        self.prepare(params)
        u = self.feedback(x0)
        self.shift()
        return u

    # ---- converged solution (tests, references) -----------------------------------------------
    def solve(self, x0, params, max_iter: int = 100, tol: float = 1e-9) -> np.ndarray:
        """Full Gauss-Newton SQP: repeat prepare/feedback (no shift) until the step is below
        ``tol`` (max-norm). Returns the first input; ``last_stats.sqp_iterations`` counts QPs.
        Raises RuntimeError when a QP fails (a converged answer was asked for)."""
        if not self._initialized:
            self.initialize(x0)
        total = SolveStats()
        for it in range(1, max_iter + 1):
            self.prepare(params)
            u0 = self.feedback(x0)
            st = self.last_stats
            if st.fallback:
                raise RuntimeError(f"QP failed in SQP iteration {it}: {st.status}")
            total.solve_ms += st.solve_ms
            total.prepare_ms += st.prepare_ms
            total.feedback_ms += st.feedback_ms
            total.qp_iterations += st.qp_iterations
            total.status, total.step_norm, total.sqp_iterations = st.status, st.step_norm, it
            if st.step_norm < tol:
                break
        else:
            total.status = "SQP_MAX_ITER"
        total.cost = self.cost(params)
        self.last_stats = total
        return u0

    def cost(self, params, w=None) -> float:
        """Objective value at ``w`` (default: the current iterate)."""
        w = self.iterate if w is None else check_array("w", w, (self.ocp.n_vars,))
        out = self._qp_fun.call([w, self._param_arg(params), self._W, self._WN])
        return float(out[5])

    def qp_matrices(self, params, w=None) -> dict[str, np.ndarray]:
        """Dense QP data at ``w`` (default: the current iterate): H, g, A, lba, uba (for tests
        and inspection; not used on the hot path)."""
        w = self.iterate if w is None else check_array("w", w, (self.ocp.n_vars,))
        out = self._qp_fun.call([w, self._param_arg(params), self._W, self._WN])
        names = ("H", "g", "A", "lba", "uba", "cost")
        return {n: np.asarray(ca.DM(v).full()) for n, v in zip(names, out)}
