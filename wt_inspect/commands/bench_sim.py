"""``wt-inspect bench sim``: simulated seconds per wall-clock second of the simulator alone.

A drone hovers (hover-thrust, zero-rate command) with wind on, at 100 Hz commands and the physics
and rate loop at 400 Hz by default; the wall time of ``QuadrotorSim.step`` calls is measured over
several repeats and the median real-time factor is reported (the first repeat also warms caches),
for the default compiled integrator and for PyBullet integrating every sub-step (the reference).
Target: at least 200x real time.

It also measures what the compiled integrator changes in a flight (:func:`integrator_difference`):
the same excitation - body-rate commands and thrust swept by sinusoids, through the full rate loop,
motor lag and drag, in the gust - flown with both integrators; the position difference after the
flight is reported.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from typing import Any

import numpy as np

from wt_inspect_env.physics.dynamics import hover_state
from wt_inspect_env.physics.quadrotor import PRESETS, get_preset
from wt_inspect_env.physics.sim_config import INTEGRATORS, SimConfig
from wt_inspect_env.physics.wind import WIND_TYPES, make_wind
from wt_inspect_env.world.sim import QuadrotorSim

from .timing_reference import raw_pybullet_rate


def excitation(k: int, weight: float) -> list[float]:
    """A deterministic command at control step ``k``: rates and thrust swept by sinusoids of
    incommensurate periods (rate errors of up to ~0.5 rad/s, thrust +-15 % of the weight)."""
    return [0.4 * math.sin(0.05 * k), 0.3 * math.cos(0.031 * k), 0.2 * math.sin(0.011 * k),
            weight * (1.0 + 0.15 * math.sin(0.02 * k))]


def integrator_difference(preset: str = "matrice100", wind: Any = None, sim_seconds: float = 10.0,
                          ctrl_hz: float = 100.0, physics_hz: float = 400.0) -> dict:
    """Fly :func:`excitation` for ``sim_seconds`` with the compiled and the PyBullet integrator
    (default wind: the paper's 4 m/s gust); the position difference at the end [m] and its maximum
    over the flight, and how many steps each integrator took itself."""
    params = get_preset(preset)
    wind = {"type": "gust", "mean_speed": 4.0} if wind is None else wind
    tracks, counts = {}, {}
    for name in INTEGRATORS:
        sim = QuadrotorSim(params, SimConfig(ctrl_hz=ctrl_hz, physics_hz=physics_hz, integrator=name),
                           wind=make_wind(wind))
        try:
            sim.reset(hover_state([0.0, 0.0, 50.0]))
            track = []
            for k in range(int(round(sim_seconds * ctrl_hz))):
                sim.step(excitation(k, params.weight))
                track.append(sim.state[0:3])
            tracks[name] = np.array(track)
            counts[name] = {"free_steps": sim.integrator.free_steps, "near_steps": sim.integrator.near_steps}
        finally:
            sim.close()
    diff = np.linalg.norm(tracks["compiled"] - tracks["bullet"], axis=1)
    travelled = float(np.linalg.norm(np.diff(tracks["bullet"], axis=0), axis=1).sum())
    return {"final_position_difference_m": float(diff[-1]), "max_position_difference_m": float(diff.max()),
            "path_length_m": travelled, "sim_seconds": sim_seconds, "wind": wind, "steps": counts}


def run_bench(preset: str = "matrice100", wind: str = "gust", mean_speed: float = 4.0,
              sim_seconds: float = 10.0, repeats: int = 5, ctrl_hz: float = 100.0,
              physics_hz: float = 400.0, obstacle: str | None = None,
              per_rotor_forces: bool = False, seed: int = 0, integrator: str = "compiled") -> dict:
    """Run the benchmark and return its summary (see module docstring)."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    if not sim_seconds > 0:
        raise ValueError(f"sim_seconds must be positive, got {sim_seconds!r}")
    params = get_preset(preset)
    spec: dict = {"type": wind}
    if wind in ("gust", "dryden"):
        spec["mean_speed"] = mean_speed
    mesh = None
    if obstacle:
        import trimesh
        mesh = trimesh.load(obstacle, force="mesh")
    cfg = SimConfig(ctrl_hz=ctrl_hz, physics_hz=physics_hz, per_rotor_forces=per_rotor_forces,
                    integrator=integrator)
    sim = QuadrotorSim(params, cfg, wind=make_wind(spec), obstacles=mesh)
    try:
        command = np.array([0.0, 0.0, 0.0, params.weight])
        n_steps = int(round(sim_seconds * ctrl_hz))
        factors = []
        for rep in range(repeats + 1):          # repeat 0 is a warm-up
            sim.reset(hover_state([0.0, 0.0, 50.0]), seed=seed + rep)
            step = sim.step
            t0 = time.perf_counter()
            for _ in range(n_steps):
                step(command)
            wall = time.perf_counter() - t0
            if rep > 0:
                factors.append(n_steps / ctrl_hz / wall)
        final = sim.state
    finally:
        sim.close()
    raw = raw_pybullet_rate(params, ctrl_hz, physics_hz, obstacle=mesh, control_steps=min(n_steps, 5000))
    median = statistics.median(factors)
    return {
        "benchmark": "sim",
        "realtime_factor": median,
        "realtime_factor_min": min(factors),
        "realtime_factor_max": max(factors),
        "repeats": repeats,
        "sim_seconds": n_steps / ctrl_hz,
        "ctrl_hz": ctrl_hz,
        "physics_hz": physics_hz,
        "preset": preset,
        "wind": spec,
        "obstacle": obstacle,
        "per_rotor_forces": per_rotor_forces,
        "integrator": integrator,
        "final_altitude_m": float(final[2]),
        "target_realtime_factor": 200.0,
        "raw_pybullet_realtime_factor": raw / ctrl_hz,
        "ratio_to_raw_pybullet": median * ctrl_hz / raw,
        "python": platform.python_version(),
    }


def main(argv: list[str], prog: str = "wt-inspect bench sim") -> int:
    """``wt-inspect bench sim``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--preset", default="matrice100", choices=sorted(PRESETS))
    ap.add_argument("--wind", default="gust", choices=[w for w in WIND_TYPES if w != "sum"])
    ap.add_argument("--mean-speed", type=float, default=4.0, help="mean wind speed [m/s]")
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per repeat")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ctrl-hz", type=float, default=100.0)
    ap.add_argument("--physics-hz", type=float, default=400.0)
    ap.add_argument("--obstacle", default=None, help="mesh file (STL/OBJ) loaded as obstacle")
    ap.add_argument("--per-rotor-forces", action="store_true",
                    help="apply the four rotor forces separately instead of their resultant")
    args = ap.parse_args(argv)
    try:
        runs = {name: run_bench(args.preset, args.wind, args.mean_speed, args.seconds, args.repeats,
                                args.ctrl_hz, args.physics_hz, args.obstacle, args.per_rotor_forces, integrator=name)
                for name in INTEGRATORS}
        diff = integrator_difference(args.preset, runs["compiled"]["wind"], args.seconds, args.ctrl_hz, args.physics_hz)
    except ValueError as exc:
        print(f"{prog}: {exc}")
        return 2
    out = {**runs["compiled"], "integrators": runs, "integrator_difference": diff,
           "compiled_over_bullet": runs["compiled"]["realtime_factor"] / runs["bullet"]["realtime_factor"]}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"simulator real-time factor, {args.preset}, wind {out['wind']}, {args.ctrl_hz:g} Hz commands, "
          f"{args.physics_hz:g} Hz physics + rate loop, {out['sim_seconds']:g} s per repeat "
          f"(median of {args.repeats}):")
    for name, r in runs.items():
        print(f"  {name:>8}: {r['realtime_factor']:>8.0f}x real time (min {r['realtime_factor_min']:.0f}x, max "
              f"{r['realtime_factor_max']:.0f}x); ratio to raw PyBullet {r['ratio_to_raw_pybullet']:.3f}")
    print(f"  compiled / bullet = {out['compiled_over_bullet']:.2f}; target >= 200x real time")
    print(f"  reference: raw PyBullet stepping of one body under the same forces, same run: "
          f"{out['raw_pybullet_realtime_factor']:.0f}x real time")
    print(f"physics difference, compiled vs PyBullet integrator, {diff['sim_seconds']:g} s of swept rate and thrust "
          f"commands ({diff['path_length_m']:.1f} m of path): {diff['final_position_difference_m']:.2e} m at the end, "
          f"{diff['max_position_difference_m']:.2e} m at most")
    return 0
