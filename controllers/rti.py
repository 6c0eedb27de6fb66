"""A generic real-time-iteration (RTI) NMPC core for nonlinear-least-squares optimal control.

Problem (one instance per control step; parameters ``p`` constant over the horizon, or one column
``p_k`` per stage k = 0..N when the caller has stage-wise data, e.g. the clearance constraint's
nearest mesh points along the predicted trajectory)::

    min   1/2 sum_k r(x_k, u_k, p)^T W r(x_k, u_k, p) + 1/2 r_N(x_N, p)^T W_N r_N(x_N, p)
    s.t.  x_0 = x_measured
          x_{k+1} = F(x_k, u_k, p)                     (multiple shooting, e.g. RK4)
          u_lower <= u_k <= u_upper
          x_lower <= x_k <= x_upper,   k = 1..N          (optional)
          h_lower <= h(x_k, u_k, p) <= h_upper            (optional path constraints)

Residuals are written so that their reference value is zero; W and W_N are diagonal (vectors).

Method (Diehl's real-time iteration): Gauss-Newton Hessian J^T W J from the residual Jacobians,
one structured QP per control step in the *step* dw around the current (shifted) guess w:

* preparation (:meth:`RTISolver.prepare`): linearise at w for the new parameters - evaluate the
  compiled QP-data function (stage Hessians, gradients, dynamics Jacobians, defects), needs no
  measurement;
* feedback (:meth:`RTISolver.feedback`): fix dx_0 = x_measured - x_0 through the variable bounds
  and call HPIPM; nothing else, so the latency from measurement to command is the QP alone;
* :meth:`RTISolver.shift` moves the plan one stage forward as the next warm start.

HPIPM (through CasADi) receives the variables in stage order [x0 u0 x1 u1 ... xN], the
constraints as [dyn_0 path_0 dyn_1 path_1 ...] with dynamics rows A_k dx_k + B_k du_k - dx_{k+1}
and the stage sizes N, nx, nu, ng given explicitly (no structure detection).

A failed or non-finite QP is never applied: the solver falls back to the shifted previous plan,
then - after N consecutive failures - to ``fallback_input`` (hover), and reports the status.
:meth:`RTISolver.solve` iterates the same QPs to convergence (full Gauss-Newton SQP), which tests
compare with IPOPT (:class:`IpoptOCPSolver`, also the converged baseline of the benchmark).
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

from .codegen import CompiledFunction, compile_function, uncompiled

BOUND_INF = 1e8  # stands for an infinite bound in the QP
QP_SOLVERS = ("casadi", "hpipm")

HPIPM_STATUS: dict[int, str] = {
    0: "SUCCESS", 1: "MAX_ITER", 2: "MIN_STEP", 3: "NAN_SOL", 4: "INCONSISTENT_EQ",
}


def _fun_sizes(name: str, fun: ca.Function, n_in: int) -> list[int]:
    """Input sizes of a CasADi function, checking that every input and output is a vector."""
    if not isinstance(fun, ca.Function):
        raise ValueError(f"{name} must be a casadi.Function, got {type(fun).__name__}")
    if fun.n_in() != n_in or fun.n_out() != 1:
        raise ValueError(f"{name} must have {n_in} inputs and 1 output, "
                         f"got {fun.n_in()} inputs and {fun.n_out()} outputs")
    sizes = []
    for i in range(n_in):
        sp = fun.sparsity_in(i)
        if sp.size2() != 1:
            raise ValueError(f"{name} input {i} must be a column vector, got shape {sp.shape}")
        sizes.append(sp.size1())
    if fun.sparsity_out(0).size2() != 1:
        raise ValueError(f"{name} output must be a column vector, got {fun.sparsity_out(0).shape}")
    return sizes


@dataclass(frozen=True)
class OCP:
    """A nonlinear-least-squares OCP with constant parameters (see the module docstring).

    ``dynamics(x, u, p) -> x_next`` (the discrete model over ``dt``), ``stage_residual(x, u, p)``
    and ``terminal_residual(x, p)`` are CasADi functions whose residuals are zero at the
    reference. ``fallback_input`` is applied when no usable plan is left (hover for a drone).
    The optional state bounds apply to x_1..x_N (x_0 is the measurement); entries may be +-inf.
    """

    name: str
    dynamics: ca.Function
    stage_residual: ca.Function
    terminal_residual: ca.Function
    horizon: int
    dt: float
    u_lower: np.ndarray
    u_upper: np.ndarray
    fallback_input: np.ndarray
    x_lower: np.ndarray | None = None
    x_upper: np.ndarray | None = None
    path_constraint: ca.Function | None = None
    h_lower: np.ndarray | None = None
    h_upper: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"name must be a C identifier, got {self.name!r}")
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, (int, np.integer)) \
                or self.horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {self.horizon!r}")
        check_positive("dt", self.dt)
        nx, nu, npar = _fun_sizes("dynamics", self.dynamics, 3)
        if self.dynamics.sparsity_out(0).size1() != nx:
            raise ValueError(f"dynamics must map x ({nx}) to x_next of the same size, got "
                             f"{self.dynamics.sparsity_out(0).size1()}")
        if _fun_sizes("stage_residual", self.stage_residual, 3) != [nx, nu, npar]:
            raise ValueError(f"stage_residual inputs must have sizes (nx, nu, np) = "
                             f"({nx}, {nu}, {npar})")
        if _fun_sizes("terminal_residual", self.terminal_residual, 2) != [nx, npar]:
            raise ValueError(f"terminal_residual inputs must have sizes (nx, np) = ({nx}, {npar})")
        lo = check_array("u_lower", self.u_lower, (nu,))
        hi = check_array("u_upper", self.u_upper, (nu,))
        if np.any(lo > hi):
            raise ValueError(f"u_lower must not exceed u_upper, got {lo} > {hi}")
        fb = check_array("fallback_input", self.fallback_input, (nu,))
        if np.any(fb < lo) or np.any(fb > hi):
            raise ValueError(f"fallback_input must lie within the input bounds, got {fb}")
        object.__setattr__(self, "u_lower", lo)
        object.__setattr__(self, "u_upper", hi)
        object.__setattr__(self, "fallback_input", fb)
        for fname, default in (("x_lower", -np.inf), ("x_upper", np.inf)):
            val = getattr(self, fname)
            arr = np.full(nx, default) if val is None else np.asarray(val, dtype=float)
            if arr.shape != (nx,) or np.any(np.isnan(arr)):
                raise ValueError(f"{fname} must be {nx} numbers (+-inf allowed), got {val!r}")
            object.__setattr__(self, fname, arr)
        if np.any(self.x_lower > self.x_upper):
            raise ValueError("x_lower must not exceed x_upper")
        if self.path_constraint is not None:
            if _fun_sizes("path_constraint", self.path_constraint, 3) != [nx, nu, npar]:
                raise ValueError("path_constraint inputs must have sizes (nx, nu, np)")
            nh = self.path_constraint.sparsity_out(0).size1()
            for fname in ("h_lower", "h_upper"):
                val = getattr(self, fname)
                arr = np.asarray(val, dtype=float) if val is not None else None
                if arr is None or arr.shape != (nh,) or np.any(np.isnan(arr)):
                    raise ValueError(f"{fname} must be {nh} numbers (+-inf allowed), got {val!r}")
                object.__setattr__(self, fname, arr)
            if np.any(self.h_lower > self.h_upper):
                raise ValueError("h_lower must not exceed h_upper")
        # sizes as plain ints: the properties below are on the hot path
        nh = 0 if self.path_constraint is None else self.path_constraint.sparsity_out(0).size1()
        object.__setattr__(self, "_dims", (
            nx, nu, npar, self.stage_residual.sparsity_out(0).size1(),
            self.terminal_residual.sparsity_out(0).size1(), nh))

    # ---- sizes -------------------------------------------------------------------------------
    @property
    def nx(self) -> int:
        """Number of states."""
        return self._dims[0]

    @property
    def nu(self) -> int:
        """Number of inputs."""
        return self._dims[1]

    @property
    def np(self) -> int:
        """Number of online parameters per solve."""
        return self._dims[2]

    @property
    def ny(self) -> int:
        """Length of the stage residual."""
        return self._dims[3]

    @property
    def ny_terminal(self) -> int:
        """Length of the terminal residual."""
        return self._dims[4]

    @property
    def nh(self) -> int:
        """Number of path constraints per stage."""
        return self._dims[5]

    @property
    def n_vars(self) -> int:
        """Length of the stage-ordered decision vector [x0 u0 ... xN]."""
        return self.horizon * (self.nx + self.nu) + self.nx

    @property
    def n_cons(self) -> int:
        """Number of constraints: the dynamics and the path constraints of every stage."""
        return self.horizon * (self.nx + self.nh)

    # ---- layout helpers ----------------------------------------------------------------------
    def pack(self, xs: np.ndarray, us: np.ndarray) -> np.ndarray:
        """Stage-ordered vector [x0 u0 x1 u1 ... xN] from (N+1, nx) states and (N, nu) inputs."""
        N, nx, nu = self.horizon, self.nx, self.nu
        w = np.empty(self.n_vars)
        body = w[:N * (nx + nu)].reshape(N, nx + nu)
        body[:, :nx] = xs[:N]
        body[:, nx:] = us
        w[N * (nx + nu):] = xs[N]
        return w

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(states (N+1, nx), inputs (N, nu)) views of a stage-ordered vector."""
        N, nx, nu = self.horizon, self.nx, self.nu
        body = w[:N * (nx + nu)].reshape(N, nx + nu)
        xs = np.vstack([body[:, :nx], w[N * (nx + nu):][None, :]])
        return xs, body[:, nx:].copy()

    def check_weights(self, stage_weights, terminal_weights) -> tuple[np.ndarray, np.ndarray]:
        """Validated copies of the diagonal weights: finite, non-negative, right length."""
        out = []
        for fname, val, n in (("stage_weights", stage_weights, self.ny),
                              ("terminal_weights", terminal_weights, self.ny_terminal)):
            arr = check_array(fname, val, (n,))
            bad = np.flatnonzero(arr < 0)
            if bad.size:
                raise ValueError(f"{fname}[{bad[0]}] must be non-negative, got {arr[bad[0]]!r}")
            out.append(arr.copy())
        return out[0], out[1]


@dataclass(frozen=True)
class RTIOptions:
    """Solver options. ``qp_mode`` is HPIPM's preset (speed_abs, speed, balance, robust);
    ``regularization`` adds a Levenberg-Marquardt term to the Gauss-Newton Hessian (it only damps
    steps, the converged point is unchanged); ``compiled`` selects generated C for the QP data.
    ``qp_solver``: ``"casadi"`` calls HPIPM through CasADi's ``conic`` plugin; ``"hpipm"`` calls
    it directly (:mod:`controllers.hpipm_direct`: memory allocated once, only finite bounds, x_0
    eliminated, the QP loaded in the preparation phase) - OCPs without path constraints only;
    where the direct path cannot be built (no compiler, no libhpipm) it warns and uses CasADi's.
    ``qp_mu0``: HPIPM's initial barrier parameter (None: the ``qp_mode`` preset's, 10 for
    ``speed_abs``). 1.0 is acados' value; measured on the VT-NMPC it needs 2
    interior-point iterations instead of 3 and lands closer to the converged QP solution when
    rate bounds are active (1.4e-4 against 2.3e-3 from a tight solve).
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


def _gauss_newton_stage(ocp: OCP, regularization: float) -> dict[str, Any]:
    """Symbols and Gauss-Newton data of one stage (shared by both QP-data layouts): Hessian
    H = J^T W J (+ regularization I), gradient g = J^T W r, dynamics Jacobian AB = d F / d[x, u],
    the multiple-shooting gap x_next - F and the stage cost, for z = [x, u]."""
    nx, nu = ocp.nx, ocp.nu
    x, u, xn = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("x_next", nx)
    p, W = ca.SX.sym("p", ocp.np), ca.SX.sym("W", ocp.ny)
    z = ca.vertcat(x, u)
    r = ocp.stage_residual(x, u, p)
    J = ca.jacobian(r, z)
    WJ = ca.diag(W) @ J
    H = J.T @ WJ
    if regularization > 0:
        H = H + regularization * ca.SX.eye(nx + nu)
    xnext = ocp.dynamics(x, u, p)
    return {"x": x, "u": u, "x_next": xn, "p": p, "W": W, "z": z, "H": H, "g": WJ.T @ r,
            "AB": ca.jacobian(xnext, z), "neg_defect": xn - xnext, "cost": 0.5 * ca.dot(W * r, r)}


def _gauss_newton_terminal(ocp: OCP, regularization: float) -> ca.Function:
    """``(x_N, p, W_N) -> (H_N, g_N, cost_N)`` of the terminal residual."""
    nx = ocp.nx
    xN, p, WN = ca.SX.sym("xN", nx), ca.SX.sym("p", ocp.np), ca.SX.sym("WN", ocp.ny_terminal)
    rN = ocp.terminal_residual(xN, p)
    JN = ca.jacobian(rN, xN)
    WJN = ca.diag(WN) @ JN
    HN = JN.T @ WJN
    if regularization > 0:
        HN = HN + regularization * ca.SX.eye(nx)
    return ca.Function(f"{ocp.name}_terminal", [xN, p, WN], [HN, WJN.T @ rN, 0.5 * ca.dot(WN * rN, rN)],
                       ["xN", "p", "WN"], ["HN", "gN", "costN"])


def _horizon_symbols(ocp: OCP) -> dict[str, Any]:
    """MX inputs (w, P, W, W_N) of a QP-data function and the stage-wise views of w and P.

    ``P`` holds one parameter column per stage (np x (N+1), the terminal stage's last): a caller
    with constant parameters repeats them (:meth:`RTISolver.prepare` does), which evaluates every
    stage on the same numbers as before, bit for bit."""
    N, nx, nz = ocp.horizon, ocp.nx, ocp.nx + ocp.nu
    w = ca.MX.sym("w", ocp.n_vars)
    body = ca.reshape(w[:N * nz], nz, N)
    wN = w[N * nz:]
    P = ca.MX.sym("p", ocp.np, N + 1)
    return {"w": w, "p": P, "Ps": P[:, :N], "pN": P[:, N], "W": ca.MX.sym("W", ocp.ny),
            "WN": ca.MX.sym("WN", ocp.ny_terminal), "Xs": body[:nx, :], "Us": body[nx:, :], "wN": wN,
            "Xnext": ca.horzcat(body[:nx, 1:], wN) if N > 1 else wN}


def stage_parameter_matrix(ocp: OCP, params: Any) -> np.ndarray:
    """Parameters as an (N+1, np) array, one row per stage: ``(np,)`` is repeated over the
    horizon, ``(N+1, np)`` taken as given; finite, or a ValueError naming ``params``."""
    arr = np.asarray(params, dtype=float) if not isinstance(params, np.ndarray) else params
    if arr.ndim == 1:
        v = check_array("params", arr, (ocp.np,))
        return np.broadcast_to(v, (ocp.horizon + 1, ocp.np))
    return check_array("params", arr, (ocp.horizon + 1, ocp.np))


def build_qp_data_function(ocp: OCP, regularization: float = 0.0) -> ca.Function:
    """The preparation-phase function ``(w, p, W, W_N) -> (H, g, A, lba, uba, cost)``.

    ``H`` and ``A`` are sparse with HPIPM's stage structure; ``g`` is the Gauss-Newton gradient
    J^T W r; ``lba``/``uba`` hold minus the multiple-shooting defects (dynamics rows) and the path
    constraint margins; ``cost`` the objective at ``w``. Stages are evaluated by one SX stage
    function mapped over the horizon, so the generated C is a loop rather than N copies.
    """
    N, nx, nu, nh = ocp.horizon, ocp.nx, ocp.nu, ocp.nh
    nz = nx + nu
    st = _gauss_newton_stage(ocp, regularization)
    outs = [st["H"], st["g"], st["AB"], st["neg_defect"], st["cost"]]
    names = ["H", "g", "AB", "neg_defect", "cost"]
    if nh:
        hval = ocp.path_constraint(st["x"], st["u"], st["p"])
        outs += [ca.jacobian(hval, st["z"]), hval]
        names += ["CD", "h"]
    stage = ca.Function(f"{ocp.name}_stage", [st["x"], st["u"], st["x_next"], st["p"], st["W"]], outs,
                        ["x", "u", "x_next", "p", "W"], names)
    terminal = _gauss_newton_terminal(ocp, regularization)

    # -- whole horizon, MX with a mapped stage ---------------------------------------------------
    m = _horizon_symbols(ocp)
    res = stage.map(N, "serial")(m["Xs"], m["Us"], m["Xnext"], m["Ps"], m["W"])
    Hs, gs, ABs, ndefs, costs = res[:5]
    HNv, gNv, costN = terminal(m["wN"], m["pN"], m["WN"])

    H_full = ca.diagcat(*ca.horzsplit(Hs, nz), HNv)
    g_full = ca.vertcat(ca.vec(gs), gNv)
    if nh:
        CDs, hs = res[5], res[6]
        blocks = [ca.vertcat(ab, cd) for ab, cd in zip(ca.horzsplit(ABs, nz), ca.horzsplit(CDs, nz))]
        h_lo = ca.DM(np.clip(ocp.h_lower, -BOUND_INF, BOUND_INF))
        h_hi = ca.DM(np.clip(ocp.h_upper, -BOUND_INF, BOUND_INF))
        lo = ca.vec(ca.vertcat(ndefs, ca.repmat(h_lo, 1, N) - hs))
        hi = ca.vec(ca.vertcat(ndefs, ca.repmat(h_hi, 1, N) - hs))
    else:
        blocks = ca.horzsplit(ABs, nz)
        lo = hi = ca.vec(ndefs)
    A_stages = ca.horzcat(ca.diagcat(*blocks), ca.MX(ocp.n_cons, nx))
    A_full = A_stages + ca.MX(_minus_identity_pattern(ocp))
    cost_total = ca.sum2(costs) + costN
    return ca.Function(f"{ocp.name}_qpdata", [m["w"], m["p"], m["W"], m["WN"]],
                       [H_full, ca.densify(g_full), A_full, ca.densify(lo), ca.densify(hi),
                        ca.densify(cost_total)],
                       ["w", "p", "W", "WN"], ["H", "g", "A", "lba", "uba", "cost"])


def build_stage_qp_data_function(ocp: OCP, regularization: float = 0.0) -> ca.Function:
    """The preparation-phase function for :mod:`controllers.hpipm_direct`:
    ``(w, p, W, W_N) -> (Q, S, R, q, r, A, B, b, cost)`` as dense per-stage blocks, each output a
    horizontal concatenation of the stages' (column-major) blocks: Q (nx, nx (N+1)) with the
    terminal Hessian last, S (nu, nx N), R (nu, nu N), q (nx, N+1), r (nu, N), dynamics
    x_{k+1} = A x_k + B u_k + b with A (nx, nx N), B (nx, nu N) and the defect b (nx, N). The same
    Gauss-Newton data as :func:`build_qp_data_function`, laid out as HPIPM's setters take them.
    With path constraints, four more outputs: their Jacobians C (nh, nx N) and D (nh, nu N) and the
    step's bounds lg = h_lower - h, ug = h_upper - h (nh, N; infinite sides at +-BOUND_INF)."""
    N, nx, nh = ocp.horizon, ocp.nx, ocp.nh
    st = _gauss_newton_stage(ocp, regularization)
    H, g, AB = st["H"], st["g"], st["AB"]
    outs = [H[:nx, :nx], H[nx:, :nx], H[nx:, nx:], g[:nx], g[nx:], AB[:, :nx], AB[:, nx:], -st["neg_defect"],
            st["cost"]]
    if nh:
        hval = ocp.path_constraint(st["x"], st["u"], st["p"])
        h_lo = ca.DM(np.clip(ocp.h_lower, -BOUND_INF, BOUND_INF))
        h_hi = ca.DM(np.clip(ocp.h_upper, -BOUND_INF, BOUND_INF))
        outs += [ca.jacobian(hval, st["x"]), ca.jacobian(hval, st["u"]), h_lo - hval, h_hi - hval]
    stage = ca.Function(f"{ocp.name}_sstage", [st["x"], st["u"], st["x_next"], st["p"], st["W"]], outs)
    terminal = _gauss_newton_terminal(ocp, regularization)
    m = _horizon_symbols(ocp)
    res = stage.map(N, "serial")(m["Xs"], m["Us"], m["Xnext"], m["Ps"], m["W"])
    Q, S, R, q, rr, A, B, b, costs = res[:9]
    QN, qN, costN = terminal(m["wN"], m["pN"], m["WN"])
    outs = [ca.horzcat(Q, QN), S, R, ca.horzcat(q, qN), rr, A, B, b, ca.sum2(costs) + costN]
    names = ["Q", "S", "R", "q", "r", "A", "B", "b", "cost"]
    if nh:
        outs += list(res[9:13])
        names += ["C", "D", "lg", "ug"]
    return ca.Function(f"{ocp.name}_sqpdata", [m["w"], m["p"], m["W"], m["WN"]], [ca.densify(o) for o in outs],
                       ["w", "p", "W", "WN"], names)


def _minus_identity_pattern(ocp: OCP) -> ca.DM:
    """The constant -I blocks coupling dyn_k rows to x_{k+1} (sparse DM, na x n_vars)."""
    N, nx, nz, nh = ocp.horizon, ocp.nx, ocp.nx + ocp.nu, ocp.nh
    rows, cols = [], []
    for k in range(N):
        for i in range(nx):
            rows.append(k * (nx + nh) + i)
            cols.append((k + 1) * nz + i)
    sp = ca.Sparsity.triplet(ocp.n_cons, ocp.n_vars, rows, cols)
    return ca.DM(sp, -1.0)


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
        from .hpipm_direct import HpipmQP
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
        (tests/test_rti.py guards this against ``Function.call``).
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


class IpoptOCPSolver:
    """The same OCP solved to convergence by CasADi + IPOPT, warm-started from the shifted
    previous solution (primal and dual). Reference for tests and the benchmark's baseline."""

    def __init__(self, ocp: OCP, stage_weights, terminal_weights, tol: float = 1e-8,
                 max_iter: int = 200) -> None:
        self.ocp = ocp
        W, WN = ocp.check_weights(stage_weights, terminal_weights)
        N, nx, nu = ocp.horizon, ocp.nx, ocp.nu
        nz = nx + nu
        w = ca.SX.sym("w", ocp.n_vars)
        P = ca.SX.sym("p", ocp.np, N + 1)     # one parameter column per stage, as the RTI solver's
        obj = 0
        cons = []
        for k in range(N):
            xk, uk = w[k * nz:k * nz + nx], w[k * nz + nx:(k + 1) * nz]
            xk1 = w[(k + 1) * nz:(k + 1) * nz + nx]
            p = P[:, k]
            r = ocp.stage_residual(xk, uk, p)
            obj += 0.5 * ca.dot(ca.DM(W) * r, r)
            cons.append(ocp.dynamics(xk, uk, p) - xk1)
            if ocp.nh:
                cons.append(ocp.path_constraint(xk, uk, p))
        rN = ocp.terminal_residual(w[N * nz:], P[:, N])
        obj += 0.5 * ca.dot(ca.DM(WN) * rN, rN)
        nlp = {"x": w, "p": ca.vec(P), "f": obj, "g": ca.vertcat(*cons)}
        opts = {"print_time": False, "ipopt": {
            "print_level": 0, "sb": "yes", "tol": tol, "max_iter": max_iter,
            "warm_start_init_point": "yes", "warm_start_bound_push": 1e-9,
            "warm_start_mult_bound_push": 1e-9, "mu_init": 1e-5}}
        self._solver = ca.nlpsol(f"{ocp.name}_ipopt", "ipopt", nlp, opts)
        lbg, ubg = [], []
        for _ in range(N):
            lbg += [np.zeros(nx)]
            ubg += [np.zeros(nx)]
            if ocp.nh:
                lbg.append(ocp.h_lower)
                ubg.append(ocp.h_upper)
        self._lbg, self._ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._lbx = np.concatenate([np.tile(np.concatenate([ocp.x_lower, ocp.u_lower]), N),
                                    ocp.x_lower])
        self._ubx = np.concatenate([np.tile(np.concatenate([ocp.x_upper, ocp.u_upper]), N),
                                    ocp.x_upper])
        self._w: np.ndarray | None = None
        self._lam_g: np.ndarray | None = None
        self._lam_x: np.ndarray | None = None
        self.last_stats = SolveStats()

    @property
    def iterate(self) -> np.ndarray:
        """The last solution w = [x0 u0 ... xN] (a copy)."""
        if self._w is None:
            raise RuntimeError("no solution yet")
        return self._w.copy()

    def reset(self) -> None:
        """Forget the solution and multipliers (the next solve starts cold)."""
        self._w = self._lam_g = self._lam_x = None

    def initialize(self, x0, inputs=None, states=None) -> None:
        """Warm start from ``x0`` held over the horizon and the fallback input, or the given plan."""
        ocp = self.ocp
        us = np.tile(ocp.fallback_input, (ocp.horizon, 1)) if inputs is None else inputs
        xs = np.tile(x0, (ocp.horizon + 1, 1)) if states is None else states
        self._w = ocp.pack(np.asarray(xs, float), np.asarray(us, float))
        self._lam_g = self._lam_x = None

    def solve(self, x0, params) -> np.ndarray:
        """Converged solution for ``x0`` and ``params``; returns the first input."""
        ocp = self.ocp
        x0 = check_array("x0", x0, (ocp.nx,))
        p = np.ascontiguousarray(stage_parameter_matrix(ocp, params)).reshape(-1)   # = vec of (np, N+1)
        if self._w is None:
            self.initialize(x0)
        lbx, ubx = self._lbx.copy(), self._ubx.copy()
        lbx[:ocp.nx] = ubx[:ocp.nx] = x0
        w0 = self._w.copy()
        w0[:ocp.nx] = x0
        args = dict(x0=w0, p=p, lbx=lbx, ubx=ubx, lbg=self._lbg, ubg=self._ubg)
        if self._lam_g is not None:
            args.update(lam_g0=self._lam_g, lam_x0=self._lam_x)
        t0 = time.perf_counter()
        sol = self._solver(**args)
        elapsed = (time.perf_counter() - t0) * 1e3
        stats = self._solver.stats()
        w = np.asarray(sol["x"]).ravel()
        ok = bool(stats.get("success")) and np.all(np.isfinite(w))
        self.last_stats = SolveStats(solve_ms=elapsed, feedback_ms=elapsed, latency_ms=elapsed,
                                     qp_iterations=int(stats.get("iter_count", -1)),
                                     status=str(stats.get("return_status")), fallback=not ok,
                                     cost=float(sol["f"]))
        if ok:
            self._w = w
            self._lam_g = np.asarray(sol["lam_g"]).ravel()
            self._lam_x = np.asarray(sol["lam_x"]).ravel()
            return np.clip(w[ocp.nx:ocp.nx + ocp.nu], ocp.u_lower, ocp.u_upper)
        self.last_stats.fallback_source = "hover"
        return ocp.fallback_input.copy()

    def shift(self) -> None:
        """Shift primal and dual warm starts by one stage."""
        if self._w is None:
            return
        ocp = self.ocp
        nz, nx, N = ocp.nx + ocp.nu, ocp.nx, ocp.horizon
        for vec in (self._w, self._lam_x):
            if vec is None:
                continue
            n_body = N * nz
            vec[:n_body - nz] = vec[nz:n_body].copy()
            vec[n_body - nz:n_body - nz + nx] = vec[n_body:]
        if self._lam_g is not None:
            m = nx + ocp.nh
            self._lam_g[:-m] = self._lam_g[m:].copy()

    def step(self, x0, params) -> np.ndarray:
        """Solve for ``x0`` and ``params``, shift the warm start by a stage, and return the first input."""
        u = self.solve(x0, params)
        self.shift()
        return u
