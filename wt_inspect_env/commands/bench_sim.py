"""``wt-inspect bench sim``: simulated seconds per wall-clock second of the simulator alone.

A drone hovers (hover-thrust, zero-rate command) with wind on, at 100 Hz commands and the physics
and rate loop at 400 Hz by default; the wall time of ``QuadrotorSim.step`` calls is measured over
several repeats and the median real-time factor is reported (the first repeat also warms caches).
Target: at least 200x real time.
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import numpy as np

from ..dynamics import hover_state
from ..quadrotor import PRESETS, get_preset
from ..sim import QuadrotorSim, SimConfig
from ..wind import WIND_TYPES, make_wind
from .timing_reference import raw_pybullet_rate


def run_bench(preset: str = "matrice100", wind: str = "gust", mean_speed: float = 4.0,
              sim_seconds: float = 10.0, repeats: int = 5, ctrl_hz: float = 100.0,
              physics_hz: float = 400.0, obstacle: str | None = None,
              per_rotor_forces: bool = False, seed: int = 0) -> dict:
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
    cfg = SimConfig(ctrl_hz=ctrl_hz, physics_hz=physics_hz, per_rotor_forces=per_rotor_forces)
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
        "final_altitude_m": float(final[2]),
        "target_realtime_factor": 200.0,
        "raw_pybullet_realtime_factor": raw / ctrl_hz,
        "ratio_to_raw_pybullet": median * ctrl_hz / raw,
        "python": platform.python_version(),
    }


def main(argv: list[str], prog: str = "wt-inspect bench sim") -> int:
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
        out = run_bench(args.preset, args.wind, args.mean_speed, args.seconds, args.repeats,
                        args.ctrl_hz, args.physics_hz, args.obstacle, args.per_rotor_forces)
    except ValueError as exc:
        print(f"{prog}: {exc}")
        return 2
    if args.json:
        print(json.dumps(out))
    else:
        print(f"simulator real-time factor: {out['realtime_factor']:.0f}x (median of "
              f"{out['repeats']}, min {out['realtime_factor_min']:.0f}x, max "
              f"{out['realtime_factor_max']:.0f}x; target >= 200x)")
        print(f"  {args.preset}, wind {out['wind']}, {args.ctrl_hz:g} Hz commands, "
              f"{args.physics_hz:g} Hz physics + rate loop, {out['sim_seconds']:g} s per repeat")
        print(f"  reference: raw PyBullet stepping of one body under the same forces, same run: "
              f"{out['raw_pybullet_realtime_factor']:.0f}x real time; ratio sim / raw = {out['ratio_to_raw_pybullet']:.3f}")
    return 0
