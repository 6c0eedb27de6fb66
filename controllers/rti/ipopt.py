"""The OCP solved to convergence by CasADi and IPOPT: the reference for tests and benchmarks."""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from wt_inspect_env.util.validation import check_array

from .ocp import OCP
from .qp_data import stage_parameter_matrix
from .solver import SolveStats


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
