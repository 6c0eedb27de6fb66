"""The Gauss-Newton QP data of an :class:`~.ocp.OCP` as CasADi functions (compiled to C by the solver).

Two layouts: the whole horizon at once (:func:`build_qp_data_function`, for CasADi's HPIPM plugin)
and stage by stage (:func:`build_stage_qp_data_function`, for the direct HPIPM interface).
"""
from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from wt_inspect_env.util.validation import check_array

from .ocp import BOUND_INF, OCP


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
