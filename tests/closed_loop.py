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
