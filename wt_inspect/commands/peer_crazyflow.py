"""Steps per second of crazyflow stepped like a Gymnasium environment - run by *crazyflow's* Python.

``wt-inspect bench vecenv --crazyflow-python PATH`` runs this file with the interpreter of a
virtual environment that has crazyflow installed (it needs JAX, which this project does not), so it
imports nothing from this project. Per drone count N: ``Sim(n_worlds=N, n_drones=1)`` with
first-principles dynamics and body-rate control at 400 Hz; every control step (10 ms) sets a
body-rate command for all drones from Python and advances 4 physics steps - what an environment
step of our vector env does, without contacts, rays, coverage or metrics. Prints one JSON object
``{N: median aggregate drone-steps per second}``.

Usage: ``python peer_crazyflow.py N1,N2,... STEPS REPEATS``.
"""
from __future__ import annotations

import json
import statistics
import sys
import time


def measure(n: int, steps: int, repeats: int) -> float:
    """Median aggregate drone-steps per second of ``n`` crazyflow drones over ``repeats`` timed blocks."""
    import numpy as np
    from crazyflow.sim import Sim

    sim = Sim(n_worlds=n, n_drones=1, dynamics="first_principles", control="body_rate", freq=400,
              body_rate_freq=400, state_freq=100, attitude_freq=400, force_torque_freq=400)
    rng = np.random.default_rng(0)
    hover = 0.3   # [N], about a cf2.1 hover; the exact value does not change the cost
    rates = []
    for rep in range(repeats + 1):            # repeat 0 compiles (JAX jit) and warms up
        sim.reset()
        cmds = np.zeros((steps, n, 1, 4), dtype=np.float32)
        cmds[..., 0] = hover
        cmds[..., 1:] = rng.normal(0.0, 0.02, (steps, n, 1, 3))
        t0 = time.perf_counter()
        for k in range(steps):
            sim.body_rate_control(cmds[k])
            sim.step(4)
        sim.data.states.pos.block_until_ready()
        if rep:
            rates.append(steps * n / (time.perf_counter() - t0))
    return statistics.median(rates)


def main() -> None:
    """Measure each drone count of the command line and print the JSON object (see the module)."""
    counts = [int(x) for x in sys.argv[1].split(",")]
    steps, repeats = int(sys.argv[2]), int(sys.argv[3])
    print(json.dumps({str(n): measure(n, max(20, steps // n), repeats) for n in counts}))


if __name__ == "__main__":
    main()
