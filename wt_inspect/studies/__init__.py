"""Analyses behind some of the committed results: each reads or flies what its ``results/`` folder
records and writes that folder's derived files (tables, figures).

They live in the package, not beside their data, so they import only installed packages, are
covered by the layering test and run from any directory::

    wt-inspect study sm-vs-wind   --results results        # results/paper_faithful_wind/sm_vs_wind.{csv,png}
    wt-inspect study wind-offset  --out results/lab/wind_offset.csv
    wt-inspect study routes       RUNS_ROOT --out routes   # routes/routes.{json,png}, from runs not committed
    wt-inspect study hold-check   --seconds 12             # printed; part of the imitation study
    wt-inspect study imitation    --out results/imitation/dagger --rounds 8
    wt-inspect study safety-filter --starts 1000 --out results/safety_filter
    wt-inspect study pose-sweep   --turbine paper --out results/pose_sweep/paper --jobs 2
    wt-inspect study planner-clearance --turbines 1000 --out results/planner_clearance --jobs 2

* :mod:`.closed_loop` - the model-plant closed loop (an MPC flown on the CasADi model plus the
  simulator's drag), shared with the controller tests;
* :mod:`.sm_vs_wind` - SM against the mean wind under the authors' conditions;
* :mod:`.wind_offset` - the lab drone's steady stand-off error against the wind's drag;
* :mod:`.routes` - every training route to a full-mission policy on one time axis;
* :mod:`.hold_check` - VT-NMPC+ with its decisions held like the DAgger learner's;
* :mod:`.imitation` - demonstrations, behaviour cloning and DAgger of VT-NMPC+ from nothing, and what each round learns;
* :mod:`.safety_filter` - the safety filter against policies that fly at the structure;
* :mod:`.pose_sweep` - whole missions over a grid of rotor azimuths and nacelle facings;
* :mod:`.planner_clearance` - the planner's stand-off path against d_min on drawn turbines.
"""
from __future__ import annotations

import importlib
import sys

STUDIES: dict[str, tuple[str, str]] = {
    "sm-vs-wind": ("wt_inspect.studies.sm_vs_wind", "SM against the mean wind, paper-faithful (no flight)"),
    "wind-offset": ("wt_inspect.studies.wind_offset", "lab drone: steady stand-off error against the drag"),
    "routes": ("wt_inspect.studies.routes", "training routes to a full-mission policy, one figure"),
    "hold-check": ("wt_inspect.studies.hold_check", "VT-NMPC+ with decisions held at 25 Hz like DAgger's"),
    "imitation": ("wt_inspect.studies.imitation", "DAgger of VT-NMPC+ from nothing, labels and hold check"),
    "safety-filter": ("wt_inspect.studies.safety_filter", "the safety filter against adversarial policies"),
    "pose-sweep": ("wt_inspect.studies.pose_sweep", "whole missions over rotor azimuth x nacelle facing"),
    "planner-clearance": ("wt_inspect.studies.planner_clearance", "planned paths vs d_min (no flight)"),
}


def main(argv: list[str], prog: str = "wt-inspect study") -> int:
    """``wt-inspect study NAME [options]``: run one study (``NAME --help`` for its options)."""
    if not argv or argv[0] in {"-h", "--help"} or argv[0] not in STUDIES:
        out = sys.stdout if argv and argv[0] in {"-h", "--help"} else sys.stderr
        if argv and argv[0] not in {"-h", "--help"}:
            print(f"{prog}: error: unknown study {argv[0]!r}", file=out)
        print(f"usage: {prog} NAME [options]\n\nstudies:", file=out)
        for name, (_, help_) in STUDIES.items():
            print(f"  {name:<12} {help_}", file=out)
        return 0 if out is sys.stdout else 2
    module = importlib.import_module(STUDIES[argv[0]][0])
    return int(module.main(argv[1:], prog=f"{prog} {argv[0]}") or 0)
