"""The in-run references every benchmark reports a ratio to, and shared measuring helpers.

Machines of the kind this project runs on differ by up to ~3x in absolute speed, so a bare
steps-per-second figure cannot be checked elsewhere. Each benchmark therefore also times
:func:`raw_pybullet_rate` - PyBullet stepping one box-shaped body of the drone's mass and inertia
under the hover force, with the same sub-steps and the same API calls per sub-step as the
simulator (apply force, apply torque, step, read pose, read velocity), in a client that holds the
same obstacle mesh - in the same run, and prints its own figure as a ratio to it. The ratio moves
with the project's code, not with the machine.
"""
from __future__ import annotations

import statistics
import time
from typing import Any

import pybullet as p

from wt_inspect_env.physics.quadrotor import QuadrotorParams
from wt_inspect_env.util.process_memory import rss_mb  # noqa: F401 - the benchmarks' memory figure, re-exported
from wt_inspect_env.world.batched_sim import _mesh_arrays, create_drone_body, new_client


def raw_pybullet_rate(params: QuadrotorParams, ctrl_hz: float = 100.0, physics_hz: float = 400.0,
                      obstacle: Any = None, control_steps: int = 5000, repeats: int = 3) -> float:
    """Median control steps per second of bare PyBullet stepping (see the module docstring)."""
    cid = new_client(p.DIRECT, 1.0 / physics_hz)
    try:
        if obstacle is not None:
            verts, idx = _mesh_arrays(obstacle)
            shape = p.createCollisionShape(p.GEOM_MESH, vertices=verts, indices=idx,
                                           flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid)
            p.createMultiBody(0.0, shape, physicsClientId=cid)
        body = create_drone_body(cid, params)
        n_sub = int(round(physics_hz / ctrl_hz))
        force, torque, zero = (0.0, 0.0, params.weight), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        rates = []
        for rep in range(repeats + 1):                    # repeat 0 warms up
            p.resetBasePositionAndOrientation(body, [0.0, -60.0, 50.0], [0, 0, 0, 1], physicsClientId=cid)
            p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=cid)
            t0 = time.perf_counter()
            for _ in range(control_steps):
                for _ in range(n_sub):
                    p.applyExternalForce(body, -1, force, zero, p.LINK_FRAME, physicsClientId=cid)
                    p.applyExternalTorque(body, -1, torque, p.LINK_FRAME, physicsClientId=cid)
                    p.stepSimulation(physicsClientId=cid)
                    p.getBasePositionAndOrientation(body, physicsClientId=cid)
                    p.getBaseVelocity(body, physicsClientId=cid)
                    p.getContactPoints(bodyA=body, physicsClientId=cid)
            if rep:
                rates.append(control_steps / (time.perf_counter() - t0))
        return statistics.median(rates)
    finally:
        p.disconnect(physicsClientId=cid)
