"""Steady stand-off error of the three controllers on the lab drone against the wind's drag.

The lab table's SM counts samples within 0.1 m of the 0.5 m stand-off; none of the paper's three
controllers has integral action, so a steady wind along the surface normal leaves a steady offset
that sets SM. This sweeps the drag the drone feels (wind speed x the lab250 preset's drag, which
is an estimate) on the model plant of the tests (tests/closed_loop.py: the MPC model plus the
simulator's drag) and prints the settled error |d - d_ref| (mean of the last 2 s of 5 s, hovering
at the stand-off, wind blowing towards the surface). Run from the repository root:

    python results/lab/wind_offset.py > results/lab/wind_offset.csv
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from closed_loop import ModelPlant, SurfacePass, run_closed_loop  # noqa: E402

from controllers.nmpc import NMPCPolicy  # noqa: E402
from controllers.pampc import PAMPCConfig, PAMPCPolicy  # noqa: E402
from controllers.vtnmpc import VTNMPCPolicy  # noqa: E402
from wt_inspect_env.quadrotor import get_preset  # noqa: E402

D_REF = 0.5
LAB = get_preset("lab250")


def build(name: str):
    """A controller with the lab's stand-off (the MPC never knows the drag)."""
    if name == "nmpc":
        return NMPCPolicy(d_ref=D_REF, params=LAB)
    if name == "pampc":
        return PAMPCPolicy(d_ref=D_REF, params=LAB, image_plane_guard=PAMPCConfig.image_plane_guard * D_REF / 7.0)
    return VTNMPCPolicy(d_ref=D_REF, params=LAB)


def settled_error(name: str, wind: float, drag_factor: float = 1.0) -> float:
    params = LAB.replace(rotor_drag=tuple(drag_factor * np.asarray(LAB.rotor_drag)),
                         body_drag_area=tuple(drag_factor * np.asarray(LAB.body_drag_area)))
    sc = SurfacePass(start=(0.0, 0.0, 10.0), normal=(0.0, -1.0, 0.0), speed=0.0)
    plant = ModelPlant(params, dt=0.01, wind=lambda t, p: np.tile((0.0, wind, 0.0), (len(p), 1)))
    pol = build(name)
    res = run_closed_loop(pol, plant, sc, 500, sc.ideal_state(0.0, D_REF), pol.config.scaling, 0.01)
    return float(np.mean(np.abs(res.distance[300:] - D_REF)))


if __name__ == "__main__":
    print("controller,wind_m_s,drag_factor,settled_error_m")
    for name in ("nmpc", "pampc", "vtnmpc"):
        for wind, factor in ((4.0, 1.0), (6.0, 1.0), (8.0, 1.0), (4.0, 2.0), (4.0, 4.0)):
            print(f"{name},{wind},{factor},{settled_error(name, wind, factor):.4f}", flush=True)
