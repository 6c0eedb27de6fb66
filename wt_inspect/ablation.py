"""``wt-inspect ablation``: from the ``paper-faithful`` setup to the project's default, one change at a time.

Why: the paper's table and ours differ in many places at once (lens, coverage rule, reference
timing, control rate, weights, the authors' baseline bugs, and the three changes of VT-NMPC+). Each
row of this study makes exactly one of those changes on top of the previous row, so the difference
between two consecutive rows is the effect of that change alone, for every controller column
(NMPC, PAMPC, VT-NMPC) and every wind. Row 0 is ``paper-faithful``; the last row is the project's
``paper`` scenario with its default controllers (``nmpc``, ``pampc``, ``vtnmpc-plus``).

The chain (:data:`STEPS`), each a change of the environment options or of one column's controller:

=====  ========================  ===========================================================
row    change                    what
=====  ========================  ===========================================================
0      paper-faithful            35 mm lens, the authors' coverage rule, no occlusion,
                                 open-loop reference, 200 Hz; ``nmpc-authors``,
                                 ``pampc-authors``, ``vtnmpc-later`` (the authors' later
                                 tuning file, which matches their plotted results)
1      lens                      24 mm (this project's camera)
2      coverage rule             incidence against the ray, all vertices within range, occlusion
3      reference mode            closed-loop reference (waits for a lagging drone)
4      control rate              100 Hz
5      weights                   VT-NMPC: the paper's printed weights (``vtnmpc``)
6      baseline bugs             ``nmpc``, ``pampc`` (sign-safe yaw, camera along body x)
7      observer                  VT-NMPC + disturbance observer (``vtnmpc-dob``)
8      gimbal heading            + gimbal camera's heading (``vtnmpc-dob-gimbal``)
9      chord residual            + chord heading residual = VT-NMPC+ (``vtnmpc-plus``)
=====  ========================  ===========================================================

A (environment, controller) pair already flown by an earlier row is not flown again: rows 5-9 only
fly the column that changed. Rows that change only the camera or the coverage rule (1 and 2:
:data:`~wt_inspect.evaluation.runner.COVERAGE_KEYS`) are not flown either: neither acts on the flight, so the previous
row's recorded flights are re-scored under the new camera and rule
(:func:`~wt_inspect.evaluation.runner.rescore_coverage`, per-triangle identical to flying them -
tested), which saves a third of the study's flights. Each row's runs go through
:func:`~wt_inspect.evaluation.run_evaluation`
(its own directory under ``OUT/rows/``, resumable), and the study writes ``OUT/results.md``,
``OUT/results.json`` and ``OUT/ablation.png`` (atomically). ``--task blade`` or ``surface`` runs the
chain on the smaller tasks (scenarios ``paper-faithful-blade`` / ``-surface``) when the full mission
does not fit the time available.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.figure_io import FIGURE_FORMATS, check_figure_format, save_and_close

from .evaluation import OutputDirError, prepare_out_dir, run_evaluation
from .evaluation.runner import flight_key, load_run, rescore_coverage
from .evaluation.scenarios import env_options, get_scenario, paper_numbers

COLUMNS = ("NMPC", "PAMPC", "VT-NMPC")
METRICS = (("coverage", "coverage", "%"), ("safety", "SM", "%"), ("centering", "CM", "%"),
           ("min_distance", "min d", "m"))
TASK_SCENARIOS = {"full": "paper-faithful", "blade": "paper-faithful-blade", "surface": "paper-faithful-surface"}


@dataclass(frozen=True)
class AblationStep:
    """One change: environment options merged onto the previous row's, and/or new controllers for
    some columns (the others keep theirs)."""

    key: str
    label: str
    env: Mapping[str, Any] = field(default_factory=dict)
    controllers: Mapping[str, str] = field(default_factory=dict)


BASE_CONTROLLERS: dict[str, str] = {"NMPC": "nmpc-authors", "PAMPC": "pampc-authors", "VT-NMPC": "vtnmpc-later"}
STEPS: tuple[AblationStep, ...] = (
    AblationStep("paper-faithful", "paper-faithful (authors' camera, rule, timing, rate, baselines)"),
    AblationStep("lens", "lens 35 -> 24 mm", env={"camera": {"focal_length_mm": 24.0}}),
    AblationStep("coverage-rule", "coverage rule: ray incidence, vertices in range, occlusion on",
                 env={"camera": {"incidence_reference": "ray", "range_reference": "vertices"}, "occlusion": True}),
    AblationStep("reference", "reference open -> closed loop", env={"reference_mode": "closed_loop"}),
    AblationStep("rate", "control 200 -> 100 Hz", env={"ctrl_hz": 100.0}),
    AblationStep("weights", "VT-NMPC weights: later tuning -> paper", controllers={"VT-NMPC": "vtnmpc"}),
    AblationStep("baseline-bugs", "baselines fixed (sign-safe yaw; camera along body x)",
                 controllers={"NMPC": "nmpc", "PAMPC": "pampc"}),
    AblationStep("observer", "VT-NMPC + disturbance observer", controllers={"VT-NMPC": "vtnmpc-dob"}),
    AblationStep("gimbal-heading", "+ gimbal camera heading", controllers={"VT-NMPC": "vtnmpc-dob-gimbal"}),
    AblationStep("chord", "+ chord heading residual (= VT-NMPC+)", controllers={"VT-NMPC": "vtnmpc-plus"}),
)


def _merge(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in extra.items():
        out[k] = {**out[k], **v} if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def plan_rows(steps: Sequence[AblationStep] = STEPS) -> list[dict[str, Any]]:
    """Each row's cumulative environment overrides and controllers (column -> name)."""
    rows, env, ctrl = [], {}, dict(BASE_CONTROLLERS)
    for step in steps:
        env = _merge(env, step.env)
        ctrl = {**ctrl, **step.controllers}
        rows.append({"key": step.key, "label": step.label, "env": env, "controllers": dict(ctrl)})
    return rows


def _env_key(env: Mapping[str, Any]) -> str:
    return json.dumps(env, sort_keys=True)


def _rescored_row(row: Mapping[str, Any], run_path: Path, scenario: str, env: Mapping[str, Any]) -> dict[str, Any]:
    """``row`` of a flown run with the coverage of its frames under ``env``'s camera and rule."""
    t0 = time.perf_counter()
    score = rescore_coverage(load_run(run_path), env_options(scenario, float(row["wind"]), overrides=env))
    return {**row, "coverage": score["coverage"], "wall_time": time.perf_counter() - t0, "rescored": True}


def run_ablation(out: str | Path, *, task: str = "full", winds: Sequence[float] = (4.0, 7.0),
                 jobs: int | None = None, max_time: float | None = None, progress: bool = False,
                 steps: Sequence[AblationStep] = STEPS, figure_format: str = "png") -> dict[str, Any]:
    """Fly the chain and write the study (see the module docstring); returns the JSON document.
    ``figure_format``: of ``ablation.png`` (png, pdf or svg; the suffix follows it)."""
    check_figure_format(figure_format)
    if task not in TASK_SCENARIOS:
        raise ValueError(f"unknown task {task!r}; valid: {', '.join(TASK_SCENARIOS)}")
    scenario = TASK_SCENARIOS[task]
    get_scenario(scenario)
    out = prepare_out_dir(out)
    t0 = time.perf_counter()
    rows = plan_rows(steps)
    doc = {"scenario": scenario, "task": task, "winds": list(map(float, winds)), "max_time": max_time,
           "n_rows": len(rows), "of_chain": len(STEPS),
           "wall_time_s": 0.0, "n_flights": 0, "flights_wall_s": 0.0, "complete": False, "rows": [],
           "paper": {f"{col}@{w:g}": paper_numbers("paper", w, base)
                     for col, base in zip(COLUMNS, ("nmpc", "pampc", "vtnmpc")) for w in winds}}
    flown: dict[tuple[str, str, float], dict[str, Any]] = {}      # (env key, controller, wind) -> row
    flights: dict[tuple[str, str, float], tuple[dict[str, Any], Path]] = {}   # (flight key, ...) -> row, run file

    def write(final: bool) -> None:
        # after every row, so an interrupted study still reports the rows it finished
        doc["wall_time_s"] = time.perf_counter() - t0
        write_text_atomic(out / "results.json", json.dumps(doc, indent=1, default=float) + "\n")
        write_text_atomic(out / "results.md", markdown(doc))
        if final and doc["rows"]:
            figure(doc, out / "ablation.png", figure_format)

    try:
        for i, row in enumerate(rows):
            ek, fk = _env_key(row["env"]), flight_key(row["env"])
            new = sorted({c for c in row["controllers"].values()
                          if any((fk, c, float(w)) not in flights for w in winds)})
            if new:
                ev = run_evaluation(scenario, new, winds, (0,), out=out / "rows" / f"{i:02d}_{row['key']}",
                                    jobs=jobs, max_time=max_time, env_overrides=row["env"], figures=False,
                                    progress=progress)
                for res in ev.results:   # resumed runs count with the wall time they were flown in
                    doc["n_flights"] += 1
                    doc["flights_wall_s"] += float(res.wall_time_s)
                    r = res.row()
                    flown[(ek, r["controller"], float(r["wind"]))] = r
                    flights[(fk, r["controller"], float(r["wind"]))] = (r, res.path)
            for c in sorted(set(row["controllers"].values())):
                for w in winds:
                    key = (ek, c, float(w))
                    if key not in flown:   # flown before under another camera / rule: re-score its frames
                        flown[key] = _rescored_row(*flights[(fk, c, float(w))], scenario, row["env"])
            row["cells"] = {}
            for col, name in row["controllers"].items():
                for w in winds:
                    r = flown[(ek, name, float(w))]
                    row["cells"][f"{col}@{w:g}"] = {m: float(r[m]) for m, _, _ in METRICS} | {
                        "controller": name, "termination": r["termination"], "wall_time": float(r["wall_time"]),
                        "rescored": bool(r.get("rescored", False))}
            doc["rows"].append(row)
            write(final=False)
        doc["complete"] = True
    finally:
        write(final=True)
    return doc


def _fmt(v: float, unit: str) -> str:
    if not math.isfinite(v):
        return "-"
    return f"{100 * v:.1f}" if unit == "%" else f"{v:.2f}"


def _delta(v: float, prev: float | None, unit: str) -> str:
    if prev is None or not (math.isfinite(v) and math.isfinite(prev)):
        return ""
    d = (100 * (v - prev)) if unit == "%" else (v - prev)
    return "" if abs(d) < 0.05 else f" ({d:+.1f})" if unit == "%" else f" ({d:+.2f})"


def markdown(doc: Mapping[str, Any]) -> str:
    """The study as tables: one per wind, a row per change, coverage / SM / CM / min distance per
    column with the change from the previous row in brackets."""
    lines = [f"# Ablation: `{doc['scenario']}` -> project default, one change at a time", "",
             f"Task `{doc['task']}`" + (f", each run capped at {doc['max_time']:g} s" if doc["max_time"] else "")
             + f"; gust winds {', '.join(f'{w:g}' for w in doc['winds'])} m/s; seed 0. Cells: coverage / SM / CM "
             "in %, minimum distance in m; in brackets the change from the row above (only where it is "
             f"nonzero). Wall time of this invocation {doc['wall_time_s']:.0f} s"
             + (f"; its {doc['n_flights']} flights took {doc['flights_wall_s']:.0f} s of wall time in sum, "
                "each timed when it was flown (resumed ones included; re-scoring excluded)"
                if doc.get("n_flights") else "") + ".", ""]
    if doc.get("n_rows", len(STEPS)) < doc.get("of_chain", len(STEPS)):
        lines += [f"Only the first {doc['n_rows']} of the chain's {doc['of_chain']} rows "
                  f"(`--rows {doc['n_rows']}`).", ""]
    if not doc.get("complete", True):
        lines += [f"**Incomplete: {len(doc['rows'])} of {doc.get('n_rows', len(STEPS))} rows finished** "
                  "(rerun the same command to "
                  "resume: finished runs are reused).", ""]
    for w in doc["winds"]:
        lines += [f"## Mean wind {w:g} m/s", "",
                  "| # | change | " + " | ".join(COLUMNS) + " |", "|---:|---|" + "---|" * len(COLUMNS)]
        prev_row = None
        for i, row in enumerate(doc["rows"]):
            cells = []
            for col in COLUMNS:
                c = row["cells"][f"{col}@{w:g}"]
                p = prev_row["cells"][f"{col}@{w:g}"] if prev_row else None
                parts = [_fmt(c[m], u) + _delta(c[m], p[m] if p else None, u) for m, _, u in METRICS]
                # a run capped by --max-time always ends at its time limit: mark only uncapped ones
                tl = " ⏱" if c["termination"] == "time_limit" and not doc["max_time"] else ""
                rs = " ↻" if c.get("rescored") else ""
                cells.append(" / ".join(parts) + f" `{c['controller']}`{tl}{rs}")
            lines.append(f"| {i} | {row['label']} | " + " | ".join(cells) + " |")
            prev_row = row
        paper = [doc["paper"].get(f"{col}@{w:g}", {}) for col in COLUMNS]
        if any(paper):
            lines.append("| | paper (Gazebo, full mission) | " + " | ".join(
                " / ".join(_fmt(p.get(m, math.nan), u) for m, _, u in METRICS) for p in paper) + " |")
        lines.append("")
    if any(c.get("rescored") for row in doc["rows"] for c in row["cells"].values()):
        lines += ["↻: not flown again - the flight of the row above re-scored under this row's camera and coverage "
                  "rule (neither acts on the flight; `wt_inspect.evaluation.runner.rescore_coverage`).", ""]
    timed_out = any(c["termination"] == "time_limit" for row in doc["rows"] for c in row["cells"].values())
    lines += (["⏱: the run hit its time limit (the closed-loop reference waited for a drone blown off its pose).",
               ""] if timed_out and not doc["max_time"] else []) + ["Rows (see `wt_inspect/ablation.py`): " + "; ".join(
                  f"{i} {r['key']}: env {json.dumps(r['env'], sort_keys=True)}" for i, r in enumerate(doc["rows"])
                  if i in (0, len(doc["rows"]) - 1)) + ".", ""]
    return "\n".join(lines)


def figure(doc: Mapping[str, Any], path: Path, fmt: str = "png") -> Path:
    """Four panels (coverage, SM, CM, minimum distance) against the row, a line per column and wind,
    written as ``fmt`` (``path``'s suffix is replaced by it); returns the written path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = doc["rows"]
    x = list(range(len(rows)))
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), sharex=True)
    for ax, (m, label, unit) in zip(axes.ravel(), METRICS):
        for col, color in zip(COLUMNS, ("tab:blue", "tab:orange", "tab:green")):
            for w, style in zip(doc["winds"], ("-o", "--s", ":^")):
                y = [row["cells"][f"{col}@{w:g}"][m] * (100 if unit == "%" else 1) for row in rows]
                ax.plot(x, y, style, color=color, label=f"{col}, {w:g} m/s", markersize=4)
        ax.set_ylabel(f"{label} [{unit}]")
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xticks(x, [r["key"] for r in rows], rotation=45, ha="right")
    handles, labels = axes[0, 0].get_legend_handles_labels()   # below the panels: inside one it hides data
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=8)
    fig.suptitle(f"{doc['scenario']} -> project default, one change per row (task {doc['task']})")
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return save_and_close(fig, path, fmt)


def _floats(text: str) -> list[float]:
    vals = []
    for part in text.split(","):
        try:
            v = float(part)
        except ValueError:
            raise ValueError(f"--winds must be comma-separated numbers, got {text!r}") from None
        if not math.isfinite(v) or v < 0:
            raise ValueError(f"--winds must be non-negative speeds, got {part!r}")
        vals.append(v)
    return vals


def build_parser(prog: str = "wt-inspect ablation") -> argparse.ArgumentParser:
    """The command line of ``wt-inspect ablation`` (also read by :mod:`wt_inspect.behaviour`)."""
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="output directory (results.md, results.json, ablation.png)")
    parser.add_argument("--task", default="full", choices=list(TASK_SCENARIOS),
                        help="full mission (default), one blade or one surface")
    parser.add_argument("--winds", default="4,7", help="mean wind speeds [m/s] (default 4,7)")
    parser.add_argument("--jobs", type=int, default=None, help="parallel runs (default: the number of cores)")
    parser.add_argument("--max-time", type=float, default=None, help="cap each run at S simulated seconds")
    parser.add_argument("--rows", type=int, default=None,
                        help=f"only the first N rows of the chain (1-{len(STEPS)}; default all)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument("--figure-format", choices=FIGURE_FORMATS, default="png",
                        help="format of the ablation figure (default png; pdf and svg are vector)")
    return parser


def main(argv: list[str], prog: str = "wt-inspect ablation") -> int:
    """``wt-inspect ablation``: run (or resume) the ablation chain given by ``argv``; returns the exit code."""
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    try:
        winds = _floats(args.winds)
        if args.rows is not None and not 1 <= args.rows <= len(STEPS):
            raise ValueError(f"--rows must be between 1 and {len(STEPS)}, got {args.rows}")
        doc = run_ablation(args.out, task=args.task, winds=winds, jobs=args.jobs, max_time=args.max_time,
                           progress=not args.no_progress, figure_format=args.figure_format,
                           steps=STEPS[:args.rows] if args.rows else STEPS)
    except (ValueError, OutputDirError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {Path(args.out) / 'results.md'} ({len(doc['rows'])} rows, {doc['wall_time_s']:.0f} s)")
    return 0
