"""Steady stand-off error of the three controllers on the lab drone against the wind's drag.

The lab table's SM counts samples within 0.1 m of the 0.5 m stand-off; none of the paper's three
controllers has integral action, so a steady wind along the surface normal leaves a steady offset
that sets SM. This sweeps the drag the drone feels (wind speed x the lab250 preset's drag, which
is an estimate) on the model plant (:mod:`wt_inspect.studies.closed_loop`: the MPC model plus the
simulator's drag) and prints the settled error |d - d_ref| (mean of the last 2 s of 5 s, hovering
at the stand-off, wind blowing towards the surface) as CSV::

    wt-inspect study wind-offset --out results/lab/wind_offset.csv
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from controllers.nmpc import NMPCPolicy
from controllers.pampc import PAMPCConfig, PAMPCPolicy
from controllers.vtnmpc import VTNMPCPolicy
from wt_inspect_env.physics.quadrotor import get_preset
from wt_inspect_env.util.atomic_io import write_text_atomic

from .closed_loop import ModelPlant, SurfacePass, run_closed_loop

D_REF = 0.5
LAB = get_preset("lab250")
CONTROLLERS = ("nmpc", "pampc", "vtnmpc")
# (wind speed m/s, drag factor) pairs of the committed table
CASES = ((4.0, 1.0), (6.0, 1.0), (8.0, 1.0), (4.0, 2.0), (4.0, 4.0))
HEADER = "controller,wind_m_s,drag_factor,settled_error_m"


def build(name: str):
    """A controller with the lab's stand-off (the MPC never knows the drag)."""
    if name == "nmpc":
        return NMPCPolicy(d_ref=D_REF, params=LAB)
    if name == "pampc":
        return PAMPCPolicy(d_ref=D_REF, params=LAB, image_plane_guard=PAMPCConfig.image_plane_guard * D_REF / 7.0)
    return VTNMPCPolicy(d_ref=D_REF, params=LAB)


def settled_error(name: str, wind: float, drag_factor: float = 1.0, seconds: float = 5.0) -> float:
    """Mean |d - d_ref| over the last 2/5 of ``seconds`` of hover at the stand-off in a steady wind."""
    params = LAB.replace(rotor_drag=tuple(drag_factor * np.asarray(LAB.rotor_drag)),
                         body_drag_area=tuple(drag_factor * np.asarray(LAB.body_drag_area)))
    sc = SurfacePass(start=(0.0, 0.0, 10.0), normal=(0.0, -1.0, 0.0), speed=0.0)
    plant = ModelPlant(params, dt=0.01, wind=lambda t, p: np.tile((0.0, wind, 0.0), (len(p), 1)))
    pol = build(name)
    steps = int(round(seconds / 0.01))
    res = run_closed_loop(pol, plant, sc, steps, sc.ideal_state(0.0, D_REF), pol.config.scaling, 0.01)
    return float(np.mean(np.abs(res.distance[int(0.6 * steps):] - D_REF)))


def main(argv: list[str] | None = None, prog: str = "wt-inspect study wind-offset") -> int:
    """``wt-inspect study wind-offset``: run the study given by ``argv``; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="write the CSV here (default: print it)")
    ap.add_argument("--controllers", default=",".join(CONTROLLERS), help="comma-separated subset of "
                    + ",".join(CONTROLLERS))
    ap.add_argument("--cases", type=int, default=len(CASES), help="the first N (wind, drag) cases only")
    ap.add_argument("--seconds", type=float, default=5.0, help="hover time per case (default 5 s)")
    args = ap.parse_args(argv)
    names = [c for c in args.controllers.split(",") if c]
    bad = [c for c in names if c not in CONTROLLERS]
    if bad:
        ap.error(f"unknown controller {bad[0]!r}; choose from {', '.join(CONTROLLERS)}")
    lines = [HEADER]
    if args.out is None:
        print(HEADER, flush=True)
    for name in names:
        for wind, factor in CASES[:args.cases]:
            line = f"{name},{wind},{factor},{settled_error(name, wind, factor, args.seconds):.4f}"
            lines.append(line)
            if args.out is None:
                print(line, flush=True)
    if args.out is not None:
        write_text_atomic(args.out, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
