"""The problem description: a nonlinear-least-squares optimal control problem (:class:`OCP`).

Kept apart from the solvers (:mod:`.solver`, :mod:`.ipopt`) and from the QP data built from it
(:mod:`.qp_data`), as acados keeps its problem description apart from its solver: a controller
builds an OCP, and any solver of this package solves it.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from wt_inspect_env.util.validation import check_array, check_positive

BOUND_INF = 1e8  # stands for an infinite bound in the QP


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
