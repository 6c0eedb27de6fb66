"""The acados peer of ``wt-inspect bench solver --acados-python`` poses the same OCP as ours.

The peer runs in acados' own virtual environment; set ``WT_INSPECT_ACADOS_PYTHON`` to its Python
(a venv with ``comma-deps-acados`` and numpy) to run the comparisons, which are skipped otherwise.
On a fixed state off the stand-off (rate bounds active) both give the same cost of a plan and the
same plan after one RTI step from the same warm start, to the QP tolerance.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from controllers.vtnmpc import VTNMPC_PLUS, VTNMPCPolicy, vtnmpc_parameters
from wt_inspect.commands.acados_compare import check_python, ocp_spec, run_peer
from wt_inspect_env.task.geometry import standoff_state

ACADOS_PYTHON = os.environ.get("WT_INSPECT_ACADOS_PYTHON", "")
needs_acados = pytest.mark.skipif(not (ACADOS_PYTHON and os.access(ACADOS_PYTHON, os.X_OK)),
                                  reason="WT_INSPECT_ACADOS_PYTHON (an acados venv's python) not set")
POINT = np.array([0.0, 0.0, 30.0])
NORMAL = np.array([0.0, -1.0, 0.0])


def _problem():
    policy = VTNMPCPolicy(clearance=False)
    x0 = standoff_state(POINT, NORMAL, policy.config.d_ref)
    x0[0:3] += [1.5, -1.0, 0.8]
    x0[3:6] = [0.8, -0.4, 0.3]
    x0[6:10] = [0.0, 0.0, np.sin(np.pi / 4 + 0.25), np.cos(np.pi / 4 + 0.25)]
    params = vtnmpc_parameters(x0, POINT, NORMAL[:2], np.array([0.7, 0.0, 0.0]))
    return policy, x0, params


@needs_acados
def test_peer_cost_and_rti_step_equal_ours(tmp_path):
    policy, x0, params = _problem()
    solver, ocp = policy.solver, policy.ocp
    solver.initialize(x0)
    rng = np.random.default_rng(3)   # a plan that is not the trivial one: states and inputs perturbed
    xs, us = ocp.unpack(solver.iterate)
    xs[1:] += 0.05 * rng.standard_normal(xs[1:].shape)
    xs[:, 6:10] /= np.linalg.norm(xs[:, 6:10], axis=1, keepdims=True)
    us += 0.2 * rng.standard_normal(us.shape)
    us = np.clip(us, ocp.u_lower, ocp.u_upper)
    solver.initialize(x0, inputs=us, states=xs)
    cost = solver.cost(params)
    solver.prepare(params)
    solver.feedback(x0)
    assert solver.last_stats.status == "SUCCESS"
    xs_next, us_next = ocp.unpack(solver.iterate)

    peer = run_peer(ACADOS_PYTHON, {"mode": "probe", "ocp": ocp_spec(policy), "build_dir": str(tmp_path / "b"),
                                    "xs": xs.tolist(), "us": us.tolist(), "params": params.tolist(),
                                    "x0": x0.tolist()})
    assert peer["status"] == 0
    assert peer["cost"] == pytest.approx(cost, rel=1e-10)
    # the same QP solved by HPIPM to 1e-6 on both sides (measured: 5e-14 apart, the step is ~17)
    assert np.abs(np.asarray(peer["us"]) - us_next).max() < 1e-6
    assert np.abs(np.asarray(peer["xs"]) - xs_next).max() < 1e-6
    assert np.all(np.asarray(peer["us"]) <= ocp.u_upper + 1e-9)
    assert np.any(np.isclose(us_next, ocp.u_upper) | np.isclose(us_next, ocp.u_lower))   # bounds active


def test_spec_carries_the_solvers_numbers():
    policy, _, _ = _problem()
    spec = ocp_spec(policy)
    assert spec["stage_weights"] == policy.solver.stage_weights.tolist()
    assert spec["horizon"] == 30 and spec["dt"] == 0.01 and len(spec["terminal_weights"]) == 5
    assert spec["qp_mode"] == policy.config.solver.qp_mode


@pytest.mark.parametrize("options", [VTNMPC_PLUS, {"rk4_steps": 2}, {"backend": "ipopt"}])
def test_spec_refuses_what_the_peer_does_not_write_out(options):
    with pytest.raises(ValueError, match="paper's VT-NMPC"):
        ocp_spec(VTNMPCPolicy(clearance=False, **options))


def test_a_missing_acados_python_is_one_line(tmp_path):
    with pytest.raises(ValueError, match="not an executable file"):
        check_python(str(tmp_path / "nope" / "python"))
