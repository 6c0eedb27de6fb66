"""An input sequence rolled through an OCP's model, with the margin of its path constraints (compiled).

Why: a predictive safety filter (:mod:`controllers.safety_filter`) asks each step whether the
policy's own command, followed by a backup, keeps every path constraint. When it does, the
filter's QP would return the policy's command unchanged (its cost is zero there and no constraint
binds), so the QP - most of the filter's time - need not be solved. The rollout uses the OCP's own
dynamics and path constraint (the same functions the QP is linearised from, not a copy), with the
same stage-wise parameters, so "certified" means the nonlinear model keeps the constraint the QP
would keep in linearised form.

Like the RTI core's QP data it is generated C (compiled once, cached; uncompiled when there is no
compiler) evaluated through a CasADi ``FunctionBuffer`` bound to NumPy arrays, so no conversion
happens per call.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..codegen import CompiledFunction, compile_function, uncompiled
from .ocp import OCP


def build_rollout_function(ocp: OCP) -> ca.Function:
    """``(x0 (nx), U (nu x N), P (np x N+1)) -> (X (nx x N+1), margin (nh x N))``: the states of
    the input sequence ``U`` from ``x0`` under the OCP's dynamics with stage parameters ``P``, and
    each stage's path-constraint margin (distance of h to its nearer finite bound, negative when
    violated; +inf where both bounds are open)."""
    N, nx, nu, npar, nh = ocp.horizon, ocp.nx, ocp.nu, ocp.np, ocp.nh
    x0 = ca.SX.sym("x0", nx)
    U = ca.SX.sym("U", nu, N)
    P = ca.SX.sym("P", npar, N + 1)
    xs, margins = [x0], []
    x = x0
    lo = ocp.h_lower if nh else np.zeros(0)
    hi = ocp.h_upper if nh else np.zeros(0)
    for k in range(N):
        if nh:
            h = ocp.path_constraint(x, U[:, k], P[:, k])
            rows = []
            for i in range(nh):
                m = ca.DM(np.inf)
                if np.isfinite(lo[i]):
                    m = ca.fmin(m, h[i] - float(lo[i]))
                if np.isfinite(hi[i]):
                    m = ca.fmin(m, float(hi[i]) - h[i])
                rows.append(m)
            margins.append(ca.vertcat(*rows))
        x = ocp.dynamics(x, U[:, k], P[:, k])
        xs.append(x)
    margin = ca.horzcat(*margins) if nh else ca.SX(0, N)
    return ca.Function(f"{ocp.name}_rollout", [x0, U, P], [ca.horzcat(*xs), margin],
                       ["x0", "U", "P"], ["X", "margin"])


class Rollout:
    """:func:`build_rollout_function` of ``ocp``, compiled (``compiled``; cached in ``cache_dir``)
    and bound to preallocated arrays: ``rollout(x0, inputs, params)`` returns views of the states
    (N+1, nx) and the margins (N, nh), valid until the next call."""

    def __init__(self, ocp: OCP, *, compiled: bool = True, cache_dir: str | None = None) -> None:
        fun = build_rollout_function(ocp)
        self.ocp = ocp
        self.function: CompiledFunction = compile_function(fun, cache_dir=cache_dir) if compiled else uncompiled(fun)
        N, nx, nu, npar, nh = ocp.horizon, ocp.nx, ocp.nu, ocp.np, ocp.nh
        # CasADi is column-major: a (rows x cols) argument is our (cols, rows) row-major array
        self._x0 = np.zeros(nx)
        self._U = np.zeros((N, nu))
        self._P = np.zeros((N + 1, npar))
        self._X = np.zeros((N + 1, nx))
        self._margin = np.zeros((N, nh))
        f = self.function.function
        self._buf, self._eval = f.buffer()
        for i, arr in enumerate((self._x0, self._U, self._P)):
            self._buf.set_arg(i, memoryview(arr.reshape(-1)))
        for i, arr in enumerate((self._X, self._margin)):
            self._buf.set_res(i, memoryview(arr.reshape(-1)))

    def __call__(self, x0: np.ndarray, inputs: np.ndarray, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States and path-constraint margins of ``inputs`` (N, nu) from ``x0`` with stage
        parameters ``params`` (N+1, np) (or (np,) for every stage)."""
        self._x0[:] = x0
        self._U[:] = inputs
        self._P[:] = params
        self._eval()
        return self._X, self._margin
