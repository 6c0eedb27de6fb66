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

from .ipopt import IpoptOCPSolver
from .ocp import BOUND_INF, OCP
from .qp_data import build_qp_data_function, build_stage_qp_data_function, stage_parameter_matrix
from .solver import HPIPM_STATUS, QP_SOLVERS, RTIOptions, RTISolver, SolveStats

__all__ = ["BOUND_INF", "HPIPM_STATUS", "OCP", "QP_SOLVERS", "IpoptOCPSolver", "RTIOptions", "RTISolver",
           "SolveStats", "build_qp_data_function", "build_stage_qp_data_function", "stage_parameter_matrix"]
