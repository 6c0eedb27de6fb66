"""``wt-inspect bench mission``: the wall time of one whole mission, split into simulator, policy and the rest.

One controller (default VT-NMPC+) flies one full paper mission (the paper's turbine, both phases,
the 4 m/s gust) through the evaluation harness's own episode loop
(:func:`wt_inspect.evaluation.runner.fly`, recording on, as ``wt-inspect evaluate`` flies it). The
wall time of every control step is split into:

* ``sim`` - :meth:`QuadrotorSim.step` (rate loop, motors, drag, integration, contacts);
* ``env`` - the rest of ``env.step``: reference, camera frames and coverage, metrics, observation,
  reward;
* ``policy`` - ``policy.act`` (the MPC's preparation and feedback, its clearance look-up);
* ``harness`` - what is left: recording the run, the episode loop.

It prints medians per step and totals, the mission's wall time against its simulated time, and
the raw PyBullet one-body reference timed in the same run (the same one every benchmark prints).
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from typing import Any

import numpy as np

from ..evaluation.runner import fly, make_env, make_spec
from ..evaluation.scenarios import env_options


def run_bench(controller: str = "vtnmpc-plus", wind: float = 4.0, max_time: float | None = None) -> dict:
    """Fly the mission once and return the split (see the module docstring)."""
    from wt_inspect.commands.timing_reference import raw_pybullet_rate

    from ..evaluation import registry
    opts = env_options("paper", wind)
    spec = make_spec("paper", controller, wind, 0, opts, max_time=max_time)
    env = make_env(spec.env_options)
    u = env.unwrapped
    times: dict[str, list[float]] = {"sim": [], "env": [], "policy": []}
    try:
        t0 = time.perf_counter()
        policy = registry.resolve(controller)(u)
        build_s = time.perf_counter() - t0
        sim_step, env_step, act = u.sim.step, env.step, policy.act

        def timed_sim(command: Any) -> None:
            t = time.perf_counter()
            sim_step(command)
            times["sim"].append(time.perf_counter() - t)

        def timed_env(action: Any) -> Any:
            t = time.perf_counter()
            out = env_step(action)
            times["env"].append(time.perf_counter() - t)
            return out

        def timed_act(obs: Any) -> Any:
            t = time.perf_counter()
            out = act(obs)
            times["policy"].append(time.perf_counter() - t)
            return out

        u.sim.step, env.step, policy.act = timed_sim, timed_env, timed_act
        t0 = time.perf_counter()
        result = fly(env, policy, spec, record=True)
        wall = time.perf_counter() - t0
        raw = raw_pybullet_rate(u.params, u.config.ctrl_hz, u.config.physics_hz,
                                obstacle=u.mission.turbines[0].mesh)
    finally:
        env.close()
    sim, envt, pol = (np.asarray(times[k]) for k in ("sim", "env", "policy"))
    n = min(len(sim), len(envt), len(pol))
    sim, envt, pol = sim[:n], envt[:n], pol[:n]
    rest_env = envt - sim
    total = {"sim": float(sim.sum()), "env": float(rest_env.sum()), "policy": float(pol.sum())}
    total["harness"] = wall - sum(total.values())
    return {
        "benchmark": "mission", "controller": controller, "wind": wind, "steps": n,
        "sim_time_s": result.sim_time_s, "wall_time_s": wall, "policy_build_s": build_s,
        "termination": result.termination, "mission_complete": result.mission_complete,
        "metrics": {"coverage": result.metrics["coverage"], "sm": result.metrics["safety_sm"],
                    "cm": result.metrics["centering_cm"], "path_length_m": result.metrics["path_length_m"]},
        "median_ms": {"sim": 1e3 * statistics.median(sim), "env": 1e3 * statistics.median(rest_env),
                      "policy": 1e3 * statistics.median(pol), "harness": 1e3 * total["harness"] / n},
        "total_s": total, "share": {k: v / wall for k, v in total.items()},
        "raw_pybullet_steps_per_s": raw, "wall_per_step_over_raw_step": (wall / n) * raw,
        "machine": platform.processor() or platform.machine(), "python": platform.python_version(),
    }


def main(argv: list[str], prog: str = "wt-inspect bench mission") -> int:
    """``wt-inspect bench mission``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="vtnmpc-plus", help="registered controller (default vtnmpc-plus)")
    ap.add_argument("--wind", type=float, default=4.0, help="mean gust speed [m/s] (default 4)")
    ap.add_argument("--max-time", type=float, default=None, help="cap the mission at S simulated seconds")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    try:
        if args.max_time is not None and not args.max_time > 0:
            raise ValueError(f"--max-time must be positive, got {args.max_time!r}")
        out = run_bench(args.controller, args.wind, args.max_time)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"mission: {args.controller}, paper turbine, gust {args.wind:g} m/s: {out['sim_time_s']:.0f} s simulated in "
          f"{out['wall_time_s']:.1f} s wall ({out['steps']} steps, {out['termination']}; policy built in "
          f"{out['policy_build_s']:.1f} s)")
    m = out["metrics"]
    print(f"  coverage {m['coverage']:.1%}, SM {m['sm']:.1%}, CM {m['cm']:.1%}")
    print(f"  {'part':<8}{'median ms/step':>15}{'total s':>9}{'share':>7}")
    for k in ("sim", "env", "policy", "harness"):
        print(f"  {k:<8}{out['median_ms'][k]:>15.3f}{out['total_s'][k]:>9.1f}{out['share'][k]:>7.1%}")
    print(f"  reference: raw PyBullet one-body stepping {out['raw_pybullet_steps_per_s']:,.0f} steps/s; "
          f"wall per mission step = {out['wall_per_step_over_raw_step']:.1f} reference steps")
    return 0
