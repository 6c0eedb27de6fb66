"""Whole missions over a grid of rotor poses (``results/pose_sweep``).

Random draws (``wt-inspect campaign``) cover poses thinly; this study flies every rotor azimuth
of a grid (0-170 deg: the three-bladed rotor repeats every 120 deg, and 0-170 includes each
blade passing the tower) crossed with nacelle facings, for one turbine, the paper's 4 m/s gust
and the planner choosing the rotor turn. Each mission is a harness run (``runs/*.npz``, the
evaluation's file format), so the study resumes per mission and a run's behaviour digest is
re-flown by ``wt-inspect reproduce --check`` like an evaluation's::

    wt-inspect study pose-sweep --turbine paper --out results/pose_sweep/paper --jobs 2

Writes ``results.csv`` (one row per mission), ``results.md`` (the grid of coverage, the missions
that fell short of a target and why) and ``coverage.png`` (coverage over azimuth x facing).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

#: turbines the sweep knows: environment ``turbine`` options (the paper's V100-like default, the
#: NREL 5-MW preset as published)
TURBINES: dict[str, dict[str, Any]] = {"paper": {}, "nrel-5mw": {"preset": "nrel-5mw"}}
SCENARIO = "paper"
WIND = 4.0
#: per-mission targets the report checks (the issue's: coverage on every pose, no unrecovered stall)
COVERAGE_TARGET = 0.99
FIELDS = ("controller", "turbine", "azimuth_deg", "facing_deg", "coverage", "sm", "cm", "clearance_min_m",
          "time_below_d_min_s", "collisions", "stalls", "flight_time_s", "termination", "complete", "file")


def _grid(text: str, what: str) -> list[float]:
    """``"0:170:10"`` (start:stop:step, stop included) or ``"-60,0,60"``; one-line error naming ``what``."""
    try:
        if ":" in text:
            a, b, step = (float(x) for x in text.split(":"))
            if step <= 0 or b < a:
                raise ValueError
            n = int(math.floor((b - a) / step + 1e-9)) + 1
            return [a + i * step for i in range(n)]
        values = [float(x) for x in text.split(",") if x.strip()]
        if not values:
            raise ValueError
        return values
    except ValueError:
        raise ValueError(f"{what} must be START:STOP:STEP with STEP > 0 or numbers joined by commas, "
                         f"got {text!r}") from None


def build_parser(prog: str = "wt-inspect study pose-sweep") -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect study pose-sweep``."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--turbine", default="paper", choices=sorted(TURBINES), help="(default paper)")
    ap.add_argument("--controllers", default="vtnmpc-plus", metavar="A,B,...", help="(default vtnmpc-plus)")
    ap.add_argument("--azimuths", default="0:170:10", metavar="GRID", help="rotor azimuths [deg] (default 0:170:10)")
    ap.add_argument("--facings", default="-60,0,60", metavar="GRID", help="nacelle facings [deg] (default -60,0,60)")
    ap.add_argument("--max-time", type=float, metavar="S", help="cap each mission at S simulated seconds")
    ap.add_argument("--out", required=True, metavar="DIR")
    ap.add_argument("--jobs", type=int, metavar="N", help="parallel missions (default: the number of cores)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def planned_specs(argv: Sequence[str]) -> list[Any]:
    """The run specs the command line ``argv`` flies (what ``wt-inspect reproduce`` digests)."""
    return specs_of(build_parser().parse_args(list(argv)))


def specs_of(a: argparse.Namespace) -> list[Any]:
    """The run specs of parsed arguments, in table order (controller, facing, azimuth), each
    planned by the evaluation's own :func:`~wt_inspect.evaluation.sweep_specs`; all validation
    here, before anything runs."""
    from ..evaluation import sweep_specs
    controllers = [c.strip() for c in a.controllers.split(",") if c.strip()]
    if not controllers:
        raise ValueError(f"--controllers names no controller: {a.controllers!r}")
    azimuths, facings = _grid(a.azimuths, "--azimuths"), _grid(a.facings, "--facings")
    if a.max_time is not None and not (math.isfinite(a.max_time) and a.max_time > 0):
        raise ValueError(f"--max-time must be a positive number of simulated seconds, got {a.max_time!r}")
    return [spec for c in controllers for f in facings for az in azimuths
            for spec in sweep_specs(SCENARIO, [c], [WIND], [0], max_time=a.max_time,
                                    turbine={**TURBINES[a.turbine], "rotor_azimuth_deg": az, "facing_deg": f})]


def row(result: Any, turbine: str) -> dict[str, Any]:
    """One mission's table row."""
    m = result.metrics
    t = result.spec.env_options["turbine"]
    return {"controller": result.spec.controller, "turbine": turbine,
            "azimuth_deg": float(t["rotor_azimuth_deg"]), "facing_deg": float(t["facing_deg"]),
            "coverage": m.get("coverage"), "sm": m.get("safety_sm"), "cm": m.get("centering_cm"),
            "clearance_min_m": m.get("clearance_min_m"), "time_below_d_min_s": m.get("time_below_d_min_s"),
            "collisions": m.get("collisions"), "stalls": m.get("stalls"), "flight_time_s": m.get("flight_time_s"),
            "termination": result.termination, "complete": bool(result.mission_complete),
            "file": result.spec.filename, "error": m.get("error", "")}


def shortfalls(r: Mapping[str, Any], d_min: float) -> list[str]:
    """Why a mission misses the sweep's targets (empty: it meets them)."""
    out = []
    if not r["complete"]:
        out.append(f"ended: {r['termination']}" + (f" ({r['error']})" if r.get("error") else ""))
    if r["coverage"] is not None and r["coverage"] < COVERAGE_TARGET:
        out.append(f"coverage {100 * r['coverage']:.1f} %")
    if r["collisions"]:
        out.append(f"{r['collisions']} collision(s)")
    if r["stalls"]:
        out.append(f"{r['stalls']} stall(s)")
    if r["clearance_min_m"] is not None and r["clearance_min_m"] < d_min - 0.1:
        out.append(f"clearance {r['clearance_min_m']:.2f} m")
    return out


def markdown(rows: Sequence[Mapping[str, Any]], command: str, d_min: float) -> str:
    """results.md of the sweep: per controller, how many missions meet the targets (``d_min`` [m]), then the
    coverage by rotor azimuth and facing."""
    from wt_inspect_env import __version__
    lines = [f"# Rotor-pose sweep: {rows[0]['turbine'] if rows else ''}", "",
             f"Whole missions, scenario `{SCENARIO}` (d_ref 7 m), the paper's gust at {WIND:g} m/s, the planner "
             "choosing the rotor turn; one mission per controller, rotor azimuth and nacelle facing. Targets "
             f"per mission: complete, coverage >= {100 * COVERAGE_TARGET:.0f} %, no collision, no stall, clearance "
             f">= d_min - 0.1 m (d_min {d_min:.2f} m).", "",
             f"Command: `{command}` (wt-inspect {__version__}).", ""]
    for c in dict.fromkeys(r["controller"] for r in rows):
        mine = [r for r in rows if r["controller"] == c]
        ok = [r for r in mine if not shortfalls(r, d_min)]
        cov = sorted(float(r["coverage"]) for r in mine if r["coverage"] is not None) or [math.nan]
        clr = min((float(r["clearance_min_m"]) for r in mine if r["clearance_min_m"] is not None), default=math.nan)
        done = sum(r["complete"] for r in mine)
        hits = sum(int(r["collisions"] or 0) for r in mine)
        stalls = sum(int(r["stalls"] or 0) for r in mine)
        lines += [f"## {c}", "",
                  f"{len(ok)} of {len(mine)} missions meet every target; completed {done}; "
                  f"collisions {hits}; stalls {stalls}; "
                  f"coverage min {100 * cov[0]:.1f} %, median {100 * cov[len(cov) // 2]:.1f} %; least clearance "
                  f"{clr:.2f} m.", "",
                  "Coverage [%] by rotor azimuth (rows) and facing (columns):", ""]
        facings = sorted({r["facing_deg"] for r in mine})
        lines += ["| azimuth | " + " | ".join(f"facing {f:g}" for f in facings) + " |",
                  "|---:|" + "---:|" * len(facings)]
        for az in sorted({r["azimuth_deg"] for r in mine}):
            cells = []
            for f in facings:
                hit = [r for r in mine if r["azimuth_deg"] == az and r["facing_deg"] == f]
                cov_cell = "-" if not hit or hit[0]["coverage"] is None else f"{100 * hit[0]['coverage']:.1f}"
                cells.append(cov_cell + ("" if not hit or not shortfalls(hit[0], d_min) else " *"))
            lines.append(f"| {az:g} | " + " | ".join(cells) + " |")
        bad = [r for r in mine if shortfalls(r, d_min)]
        lines += ["", "Missions marked * (short of a target):" if bad else "Every mission meets every target.", ""]
        lines += [f"- azimuth {r['azimuth_deg']:g}, facing {r['facing_deg']:g}: "
                  + "; ".join(shortfalls(r, d_min)) + f" (`runs/{r['file']}`)" for r in bad]
        lines.append("")
    return "\n".join(lines)


def figure(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Coverage over azimuth x facing, one panel per controller."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from wt_inspect_env.util.figure_io import save_and_close
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    fig, axes = plt.subplots(1, len(controllers), figsize=(4.5 * len(controllers) + 1, 4.5), squeeze=False)
    for ax, c in zip(axes[0], controllers):
        mine = [r for r in rows if r["controller"] == c]
        az = sorted({r["azimuth_deg"] for r in mine})
        fa = sorted({r["facing_deg"] for r in mine})
        grid = np.full((len(az), len(fa)), np.nan)
        for r in mine:
            if r["coverage"] is not None:
                grid[az.index(r["azimuth_deg"]), fa.index(r["facing_deg"])] = 100 * float(r["coverage"])
        low = float(np.nanmin(grid)) if np.isfinite(grid).any() else 90.0
        im = ax.imshow(grid, aspect="auto", origin="lower", vmin=min(90.0, low), vmax=100.0,
                       cmap="viridis")
        ax.set_xticks(range(len(fa)), [f"{f:g}" for f in fa])
        ax.set_yticks(range(len(az)), [f"{a:g}" for a in az])
        ax.set_xlabel("nacelle facing [deg]")
        ax.set_ylabel("rotor azimuth [deg]")
        ax.set_title(f"{c}: coverage [%]")
        fig.colorbar(im, ax=ax)
    fig.tight_layout()
    return save_and_close(fig, path)


def main(argv: list[str], prog: str = "wt-inspect study pose-sweep") -> int:
    """``wt-inspect study pose-sweep``: run (or resume) the sweep given by ``argv``; returns the exit code."""
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    try:
        specs = specs_of(args)
    except ValueError as exc:
        ap.error(str(exc))
    from wt_inspect_env.util.atomic_io import write_text_atomic

    from ..evaluation import prepare_out_dir, resume_runs, save_run
    from ..evaluation.backends import check_jobs, run_specs
    from ..evaluation.runner import execute_or_record
    jobs = check_jobs(args.jobs)
    out = prepare_out_dir(args.out)
    runs = out / "runs"
    done, todo = resume_runs(runs, specs, warn=lambda m: print(f"warning: {m}", file=sys.stderr))

    def finished(res: Any) -> None:
        save_run(res, runs / res.spec.filename)
        res.arrays = {}
        done[res.spec.filename] = res

    # a mission that raises (e.g. a turbine the planner cannot route) is recorded, not the end of the sweep
    run_specs("local", todo, finished, jobs=jobs, progress=not args.no_progress, task=execute_or_record)
    rows = [row(done[s.filename], args.turbine) for s in specs]
    from ..commands.campaign.summary import default_d_min  # the paper scenario flies the default stand-off
    d_min = next((float(done[s.filename].metrics["d_min_m"]) for s in specs
                  if "d_min_m" in done[s.filename].metrics), default_d_min())
    tmp = out / "results.csv.tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    tmp.replace(out / "results.csv")
    command = "wt-inspect study pose-sweep " + " ".join(argv)
    write_text_atomic(out / "results.md", markdown(rows, command, d_min))
    write_text_atomic(out / "summary.json", json.dumps({"command": command, "missions": len(rows),
                                                         "meet_targets": sum(not shortfalls(r, d_min) for r in rows)},
                                                        indent=1) + "\n")
    figure(rows, out / "coverage.png")
    print(f"{len(rows)} missions ({len(todo)} flown, {len(rows) - len(todo)} resumed); wrote {out}/results.md")
    return 0


if __name__ == "__main__":   # pragma: no cover
    sys.exit(main(sys.argv[1:]))
