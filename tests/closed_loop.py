"""Closed-loop harness of the controller tests: the model-plant loop of
:mod:`wt_inspect.studies.closed_loop` (re-exported here, so the tests import it as before) and the
same loop through the PyBullet simulator (:func:`run_in_simulator`).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from wt_inspect.studies.closed_loop import (  # noqa: F401 - re-exported for the tests
    ClosedLoopResult,
    ModelPlant,
    SurfacePass,
    inspection_geometry,
    make_observation,
    offset_start,
    run_closed_loop,
)
from wt_inspect_env.physics.quadrotor import QuadrotorParams


def run_in_simulator(policy: Any, params: QuadrotorParams, scenario: SurfacePass, x0: np.ndarray,
                     steps: int) -> tuple[np.ndarray, np.ndarray, list[Any], np.ndarray]:
    """Closed loop through the PyBullet simulator (rate loop, motor lag, drag; no wind), with the
    simulator's body rates in the observation: (distances, headings, per-step stats, final state)."""
    from wt_inspect_env.world.sim import QuadrotorSim, SimConfig
    dists, heads, stats = [], [], []
    with QuadrotorSim(params, SimConfig()) as sim:
        sim.reset(x0)
        policy.reset()
        for k in range(steps):
            t = k * sim.dt
            obs = make_observation(sim.state, scenario.point(t), np.asarray(scenario.normal), scenario.velocity(t))
            obs["body_rates"] = sim.body_rates.astype(np.float32)
            sim.step(policy.scaling.to_command(policy.act(obs)))
            stats.append(policy.last_stats)
            d, h = inspection_geometry(sim.state, scenario.point(t + sim.dt), scenario.normal)
            dists.append(d)
            heads.append(h)
        final = sim.state
    return np.array(dists), np.array(heads), stats, final


def check_standoff_hold(policy: Any, params: QuadrotorParams, scenario: SurfacePass,
                                      x0: np.ndarray, d_ref: float, steps: int = 400) -> np.ndarray:
    """Fly ``policy`` from ``x0`` through the simulator over a still ``scenario`` and check what
    every baseline's hold must do: each step solved (``SUCCESS``, no fallback, a positive solve
    time), the distance within 0.1 m of ``d_ref`` over the second half and 0.02 m at the end, the
    final position within 5 cm of the stand-off pose. Returns the headings (the controllers'
    headings converge differently; their tests check those)."""
    dists, heads, stats, final = run_in_simulator(policy, params, scenario, x0, steps=steps)
    assert all(s.status == "SUCCESS" and not s.fallback and s.solve_ms > 0 for s in stats)
    assert np.all(np.abs(dists[steps // 2:] - d_ref) < 0.1)
    assert abs(dists[-1] - d_ref) < 0.02
    assert np.linalg.norm(final[:3] - scenario.ideal_state(0.0, d_ref)[:3]) < 0.05
    return heads


def check_sqp_vs_ipopt(ocp: Any, cfg: Any, x0: np.ndarray, p: np.ndarray) -> tuple[Any, Any]:
    """Solve ``ocp`` (weights from ``cfg``) to convergence with the RTI core's SQP mode and with
    IPOPT (both at tol 1e-10) and check that IPOPT converged and the first inputs agree to 1e-5.
    Returns (rti, ipopt) for further checks of the iterates."""
    from controllers.rti import IpoptOCPSolver, RTISolver
    W, WN = cfg.weights.stage_vector(), cfg.weights.terminal_vector()
    rti = RTISolver(ocp, W, WN, cfg.solver)
    u_rti = rti.solve(x0, p, tol=1e-10)
    ip = IpoptOCPSolver(ocp, W, WN, tol=1e-10)
    u_ip = ip.solve(x0, p)
    assert not ip.last_stats.fallback
    np.testing.assert_allclose(u_rti, u_ip, rtol=1e-5, atol=1e-5)
    return rti, ip
