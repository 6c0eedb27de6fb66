"""``wt-inspect plan``: build the turbine, plan its two-phase inspection, write the results.

Writes ``DIR/turbine.stl`` (blades, hub and tower as planned: phase-1 rotor position),
``DIR/path.csv`` (``x,y,z,nx,ny,nz,surface,phase,s``: inspection point, outward normal, surface id
or -1 on transitions, phase 1 or 2, arc length of the inspection point) and ``DIR/plan.png``
(3-D view per phase; ``--figure-format pdf|svg`` for a vector figure instead), each atomically, and
prints a summary (``--json``: one JSON object).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from wt_inspect_env.planner import PlannerConfig, plan_inspection
from wt_inspect_env.planner.config import PAPER_ROTOR_TURN_DEG, STANDOFF_MODES
from wt_inspect_env.turbine.mesh import build_turbine
from wt_inspect_env.turbine.spec import TurbineSpec
from wt_inspect_env.util.atomic_io import atomic_paths, check_out_dir
from wt_inspect_env.util.figure_io import DEFAULT_FIGURE_FORMAT, FIGURE_FORMATS
from wt_inspect_env.util.validation import coerce_config

from .args import float_or_auto, json_object

_PAPER_OR_AUTO = object()   # --rotor-turn not given: the env's "auto" rule

_SPEC_ARGS = {  # option -> TurbineSpec field
    "tower_height": "tower_height", "blade_length": "blade_length", "blade_width": "blade_width",
    "blade_thickness": "blade_thickness", "tower_radius": "tower_radius", "hub_radius": "hub_radius",
    "overhang": "overhang", "mesh_step": "mesh_step", "rotor_azimuth": "rotor_azimuth_deg",
    "facing": "facing_deg", "position": "position",
}
_PLAN_ARGS = {
    "standoff": "standoff", "spacing": "spacing", "clearance": "clearance",
    "max_down": "max_down_deg", "max_up": "max_up_deg", "standoff_mode": "standoff_mode", "start": "start",
}


def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect plan`` (defaults from TurbineSpec and PlannerConfig)."""
    d = TurbineSpec()
    c = PlannerConfig()
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    ap.add_argument("--no-plot", action="store_true", help="skip plan.png (rendering is the slow part)")
    ap.add_argument("--figure-format", choices=FIGURE_FORMATS, default=DEFAULT_FIGURE_FORMAT,
                    help=f"format of the plan figure (default {DEFAULT_FIGURE_FORMAT}; pdf and svg are vector)")
    t = ap.add_argument_group("turbine (defaults: the paper's Vestas V100)")
    t.add_argument("--turbine", type=json_object("--turbine"), metavar="JSON",
                   help="a TurbineSpec as a JSON object, as evaluate --turbine and gym.make's turbine= take it "
                        "(e.g. '{\"preset\": \"nrel-5mw\"}'); the options below override its fields")
    t.add_argument("--tower-height", type=float, metavar="M", help=f"hub height [m] ({d.tower_height:g})")
    t.add_argument("--blade-length", type=float, metavar="M", help=f"[m] ({d.blade_length:g})")
    t.add_argument("--blade-width", type=float, metavar="M", help=f"chord [m] ({d.blade_width:g})")
    t.add_argument("--blade-thickness", type=float, metavar="M", help="[m] (blade width / 3)")
    t.add_argument("--tower-radius", type=float, metavar="M", help=f"[m] ({d.tower_radius:g})")
    t.add_argument("--hub-radius", type=float, metavar="M", help="[m] (0.7 x blade width)")
    t.add_argument("--overhang", type=float, metavar="M",
                   help="tower axis to rotor plane [m] (tower radius + hub radius)")
    t.add_argument("--mesh-step", type=float, metavar="M", help=f"triangle size [m] ({d.mesh_step:g})")
    t.add_argument("--rotor-azimuth", type=float, metavar="DEG", help="rotor azimuth [deg] (0: inverted Y)")
    t.add_argument("--facing", type=float, metavar="DEG", help=f"rotor axis yaw [deg] ({d.facing_deg:g}: +y)")
    t.add_argument("--position", type=float, nargs=2, metavar=("X", "Y"), help="tower base [m] (0 0)")
    p = ap.add_argument_group("planner")
    p.add_argument("--standoff", type=float, metavar="M", help=f"d_ref [m] ({c.standoff:g})")
    p.add_argument("--spacing", type=float, metavar="M", help=f"path sample spacing [m] ({c.spacing:g})")
    p.add_argument("--clearance", type=float, metavar="M",
                   help=f"min distance of the stand-off path to the turbine [m] ({c.clearance:g})")
    p.add_argument("--rotor-turn", type=float_or_auto("--rotor-turn"), default=_PAPER_OR_AUTO, metavar="DEG|auto",
                   help=f"turn before phase 2 [deg]; auto: the planner chooses the rotor turns (none, one or "
                        f"more) that make every surface inspectable with the least flight (default: "
                        f"{c.rotor_turn_deg:g} on the paper's turbine, auto on any other, as the env does)")
    p.add_argument("--max-down", type=float, metavar="DEG",
                   help=f"steepest downward normal inspected with a level camera [deg] ({c.max_down_deg:g})")
    p.add_argument("--max-up", type=float, metavar="DEG", help=f"steepest upward normal [deg] ({c.max_up_deg:g})")
    p.add_argument("--standoff-mode", choices=STANDOFF_MODES, help=f"({c.standoff_mode})")
    p.add_argument("--start", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="take-off point [m] (ground in front of the rotor)")
    return ap


def _picked(args: argparse.Namespace, table: dict[str, str]) -> dict:
    return {field: getattr(args, opt) for opt, field in table.items() if getattr(args, opt) is not None}


def main(argv: list[str], prog: str = "wt-inspect plan") -> int:
    """``wt-inspect plan``: plan the path given by ``argv``, write its files and print a summary."""
    args = build_parser(prog).parse_args(argv)
    out = Path(args.out)
    try:
        check_out_dir(out, "--out")
        t0 = time.perf_counter()
        turbine = build_turbine(coerce_config("--turbine", {**(args.turbine or {}), **_picked(args, _SPEC_ARGS)},
                                              TurbineSpec))
        t_build = time.perf_counter() - t0
        # --rotor-turn always reaches the planner: None (auto) is a value, not "not given"
        turn = args.rotor_turn
        if turn is _PAPER_OR_AUTO:
            turn = PAPER_ROTOR_TURN_DEG if turbine.spec == TurbineSpec() else None
        plan = plan_inspection(turbine, PlannerConfig(**_picked(args, _PLAN_ARGS), rotor_turn_deg=turn))
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"{prog}: error: out of memory building or planning this turbine; use a larger --mesh-step "
              f"or --spacing, or a smaller turbine", file=sys.stderr)
        return 2
    names = {"turbine": "turbine.stl", "path": "path.csv"}
    if not args.no_plot:
        names["figure"] = f"plan.{args.figure_format}"
    try:
        # one set: a failure writing any file (full or read-only disk) leaves none of them
        out.mkdir(parents=True, exist_ok=True)
        with atomic_paths(*(out / n for n in names.values())) as tmps:
            tmp = dict(zip(names, tmps))
            turbine.export(tmp["turbine"])
            plan.to_csv(tmp["path"])
            if not args.no_plot:
                from wt_inspect_env.planner.plot import save_plan_figure  # matplotlib only when drawing
                save_plan_figure(plan, tmp["figure"], args.figure_format)
    except OSError as exc:
        print(f"{prog}: error: cannot write --out {str(out)!r}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    files = {k: str(out / n) for k, n in names.items()}
    summary = plan.summary()
    summary["min_clearance_m"] = round(plan.min_clearance(), 4)
    summary["build_time_s"] = round(t_build, 6)
    summary["turbine"] = {"tower_height": turbine.spec.tower_height, "blade_length": turbine.spec.blade_length,
                          "blade_width": turbine.spec.blade_width,
                          "blade_thickness": turbine.spec.blade_thickness,
                          "blade_triangles": turbine.n_blade_triangles}
    summary["files"] = files
    if args.json:
        print(json.dumps(summary))
        return 0
    order = " ".join(f"{t.surface}{'^' if t.entry == 'root' else 'v'}"
                     + (" |" if t.phase == 1 and i + 1 < len(plan.tour) and plan.tour[i + 1].phase == 2 else "")
                     for i, t in enumerate(plan.tour))
    positions = "; ".join(f"{len(rp.surfaces)} at rotor position {rp.phase} (turned {rp.turn_deg:g} deg)"
                          for rp in plan.rotor_positions)
    print(f"{summary['surfaces']} surfaces: {positions}")
    print(f"tour (surface id, ^ entered at the root, v at the tip; | rotor turn): {order}")
    print(f"tour length {summary['tour_length_m']:.1f} m between stand-offs (flown stand-off path "
          f"{summary['path_length_m']:.1f} m, of which inspection {summary['inspection_length_m']:.1f} m)")
    print(f"{summary['samples']} path samples at <= {plan.config.spacing:g} m; stand-off {plan.standoff:g} m; "
          f"min clearance to the turbine {summary['min_clearance_m']:.2f} m")
    tm = summary["timings_s"]
    print(f"plan time {summary['plan_time_s']:.3f} s (cluster {tm['cluster']:.3f}, setup {tm['setup']:.3f}, "
          f"order {tm['order']:.3f}, path {tm['path']:.3f}); turbine mesh {t_build:.3f} s")
    print("wrote " + ", ".join(files.values()))
    return 0
