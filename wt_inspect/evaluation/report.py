"""results.csv (one row per run) and results.md (the paper's table layout beside its numbers).

The paper's simulation table has the controllers as columns (NMPC, PAMPC, VT-NMPC) and the
metrics as rows (coverage, safety SM, quality CM), plus distances in the text. results.md keeps
that layout, one table per wind speed, each controller's column followed by the paper's number
for the same cell (``-`` where the paper gives none). With several seeds a cell is the mean over
seeds (minimum distance and clearance: the minimum; collisions: the sum), and the number of seeds
is stated.

Two different distances are reported, named apart on purpose: the *distance to the inspection
point* (``mean_distance`` / ``min_distance``: the paper's d, horizontal, to the moving point the
camera looks at) and the *clearance to the turbine* (``clearance_min_m`` ...: to the nearest point
of the turbine's mesh, what decides whether the drone hits a blade edge, the hub or the tower).
A drone can keep 6.5 m from the point while passing 2 m from the structure. Energy, mean power
and path length price the flight (see :mod:`.harness_metrics`).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from wt_inspect_env.task.env_config import EnvConfig
from wt_inspect_env.util.atomic_io import write_text_atomic

from .registry import display_name
from .runner import RunResult
from .scenarios import PAPER_RESULTS, get_scenario, paper_numbers

CSV_COLUMNS = ("scenario", "controller", "wind", "seed", "coverage", "safety", "centering", "centering_body",
               "mean_distance",
               "min_distance", "max_distance", "rms_distance_error", "collisions", "flight_time", "path_length",
               "mean_heading_error_deg", "clearance_min_m", "clearance_body_min_m", "time_below_d_min_s", "d_min_m",
               "energy_wh", "mean_power_w", "solve_median_ms", "solve_p99_ms", "act_median_ms", "act_p99_ms",
               "termination", "mission_complete", "stalls", "skipped_path_m", "steps", "sim_time", "wall_time",
               "run_file", "filter_intervention_fraction", "filter_mean_correction", "filter_fallbacks",
               "filter_passed_fraction", "filter_median_ms", "filter_p99_ms")
#: the safety filter's columns (NaN for a run flown without it; see controllers.safety_filter)
FILTER_COLUMNS = CSV_COLUMNS[-6:]
PAPER_ORDER = ("nmpc", "pampc", "vtnmpc")


def _fmt_csv(v: Any) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return str(v)


def csv_text(results: Iterable[RunResult]) -> str:
    """The runs as results.csv text (columns :data:`CSV_COLUMNS`, one row per run)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in results:
        row = r.row()
        w.writerow([_fmt_csv(row.get(c, "")) for c in CSV_COLUMNS])
    return buf.getvalue()


def write_csv(results: Iterable[RunResult], path: str | Path) -> Path:
    """results.csv, atomically (full float precision: reruns can be compared exactly)."""
    write_text_atomic(path, csv_text(results))
    return Path(path)


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a results.csv with numbers parsed (for tests and notebooks)."""
    out = []
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            parsed: dict[str, Any] = {}
            for k, v in row.items():
                if k in ("scenario", "controller", "termination", "run_file"):
                    parsed[k] = v
                elif k == "mission_complete":
                    parsed[k] = v == "true"
                else:
                    parsed[k] = float(v) if v != "" else math.nan   # a column older files lack
            out.append(parsed)
    return out


# ------------------------------------------------------------------ markdown
@dataclass
class ReportContext:
    """What results.md says about how the numbers were made."""

    scenario: str
    wind_type: str = "gust"
    backend: str = "local"
    jobs: int = 1
    wall_time_s: float = math.nan
    n_ran: int = 0
    n_resumed: int = 0
    n_planned: int = 0
    command: str = ""
    notes: list[str] = field(default_factory=list)
    overrides: dict = field(default_factory=dict)   # turbine / drone / env options given over the scenario's


def hardware() -> str:
    """CPU model, logical cores and OS of this machine (for the report)."""
    model = platform.processor() or ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{model or 'unknown CPU'}, {os.cpu_count()} logical cores, {platform.system()} {platform.release()}, " \
           f"Python {platform.python_version()}"


def _pct(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{100 * v:.1f} %"


def _m(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.2f} m"


def _ms(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.2f} ms"


def _s(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.1f} s"


def _wh(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.1f} Wh" if abs(v) >= 10 else f"{v:.2f} Wh"


def _w(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.0f} W"


def _path(v: float) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.0f} m" if abs(v) >= 100 else f"{v:.1f} m"


# rows of the paper-layout table: (label, csv column, formatter, aggregation over seeds)
ROWS = (
    ("Coverage", "coverage", _pct, "mean"),
    ("Safety (SM)", "safety", _pct, "mean"),
    ("Quality (CM)", "centering", _pct, "mean"),
    ("CM with body-axis h", "centering_body", _pct, "mean"),
    ("Mean distance to the inspection point", "mean_distance", _m, "mean"),
    ("Min distance to the inspection point", "min_distance", _m, "min"),
    ("Min clearance to the turbine (centre)", "clearance_min_m", _m, "min"),
    ("Min clearance of the body box (lower bound)", "clearance_body_min_m", _m, "min"),
    ("Time below d_min", "time_below_d_min_s", _s, "mean"),
    ("Energy", "energy_wh", _wh, "mean"),
    ("Mean power", "mean_power_w", _w, "mean"),
    ("Path length", "path_length", _path, "mean"),
    ("Collisions", "collisions", lambda v: "-" if not math.isfinite(v) else f"{v:.0f}", "sum"),
    ("Reference stalls", "stalls", lambda v: "-" if not math.isfinite(v) else f"{v:.0f}", "sum"),
    ("Solve time (median)", "solve_median_ms", _ms, "mean"),
    ("Solve time (p99)", "solve_p99_ms", _ms, "mean"),
    ("Flight time", "flight_time", lambda v: "-" if not math.isfinite(v) else f"{v:.0f} s", "mean"),
)


def _aggregate(rows: Sequence[dict[str, Any]], col: str, how: str) -> float:
    vals = np.array([float(r.get(col, math.nan)) for r in rows], dtype=float)
    vals = vals[np.isfinite(vals)]
    if not len(vals):
        return math.nan
    return float({"mean": np.mean, "min": np.min, "sum": np.sum}[how](vals))


def order_controllers(names: Iterable[str]) -> list[str]:
    """The paper's column order (NMPC, PAMPC, VT-NMPC), then the others as given."""
    names = list(dict.fromkeys(names))
    return [n for n in PAPER_ORDER if n in names] + [n for n in names if n not in PAPER_ORDER]


def _values(results: Sequence[RunResult], option: str, fmt: Callable[[Any], str]) -> str:
    """The runs' values of environment option ``option`` (the default's where a run does not set it),
    formatted and joined: the report states what the runs used, not what the defaults are."""
    default = getattr(EnvConfig(), option)
    vals = sorted({r.spec.env_options.get(option, default) for r in results}, key=str)
    return " / ".join(fmt(v) for v in vals) if vals else fmt(default)


def _values_of(results: Sequence[RunResult], key: str, fmt: Callable[[float], str]) -> str:
    """The runs' distinct finite values of metric ``key``, formatted and joined (``-`` if none)."""
    vals = sorted({float(v) for r in results if isinstance(v := r.metrics.get(key), (int, float))
                   and math.isfinite(v)})
    return " / ".join(fmt(v) for v in vals) if vals else "-"


def _energy_note(results: Sequence[RunResult]) -> str:
    """The drones' power-model parameters and hover power, from the runs' options (their preset)."""
    from wt_inspect_env.physics.quadrotor import QuadrotorParams, get_preset
    default = EnvConfig().drone
    names = sorted({str(r.spec.env_options.get("drone", default if isinstance(default, str) else default.name))
                    for r in results}) or ["matrice100"]
    parts = []
    for name in names:
        try:
            p: QuadrotorParams = get_preset(name)
        except ValueError:
            continue
        parts.append(f"`{name}`: rotor radius {p.prop_radius:g} m, figure of merit {p.figure_of_merit:g}, "
                     f"motor + ESC efficiency {p.drive_efficiency:g}, air {p.air_density:g} kg/m^3, hover "
                     f"power {p.hover_power:.0f} W")
    return ("; ".join(parts) + ".") if parts else ""


def _frames_note(results: Sequence[RunResult]) -> str:
    """"camera frames at 10 Hz, occlusion tested", from the runs' own options."""
    hz = _values(results, "camera_hz", lambda v: f"{float(v):g} Hz")
    occ = _values(results, "occlusion", lambda v: "occlusion tested" if v else "no occlusion test")
    return f"camera frames at {hz}, {occ}"


def _stall_lines(results: Sequence[RunResult]) -> list[str]:
    """The section listing every reference stall of the runs (none: no section): when and where it
    happened, what the reference did, and the path it skipped and the coverage the run reached."""
    stalled = [r for r in results if r.stall_log]
    if not stalled:
        return []
    lines = ["", "## Reference stalls", "",
             "The closed-loop reference made no progress for `reference_stall_time` while the drone was held "
             "off its stand-off pose, or fell behind its time limit's schedule; `skipped`: it moved on along "
             "the path without the drone until the drone was back on its pose (the run's skipped path and its "
             "coverage show what the stall cost), `paced`: "
             "the point had fallen so far behind that only the nominal speed from there ended the mission by its "
             "time limit, and it kept that speed to the end; `ended`: the episode ended there "
             "(`reference_on_stall=\"end\"`).", "",
             "| controller | wind | seed | time | mission progress | phase | drone to pose | clearance | why "
             "| then | path skipped (run) | coverage (run) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|---|---:|---:|"]
    for r in stalled:
        s = r.spec
        for e in r.stall_log:
            lines.append(f"| {display_name(s.controller)} | {s.wind:g} | {s.seed} | {e['time_s']:.0f} s | "
                         f"{_pct(e['progress'])} | {e['phase']} | {_m(e['distance_to_pose_m'])} | "
                         f"{_m(e['clearance_m'])} | {e['why']} | {e['action']} | "
                         f"{float(r.metrics.get('skipped_path_m', math.nan)):.0f} m | "
                         f"{_pct(float(r.metrics.get('coverage', math.nan)))} |")
    return lines


def markdown(results: Sequence[RunResult], ctx: ReportContext) -> str:
    """results.md of an evaluation: the metrics of every run, then how the numbers were made."""
    sc = get_scenario(ctx.scenario)
    rows = [r.row() for r in results]
    lines = [f"# Evaluation: scenario `{sc.name}`", "",
             f"{sc.description}"
             + ("".join(f"; **{k} overridden**: `{json.dumps(v, sort_keys=True)}`" for k, v in ctx.overrides.items())
                + " (the description above is the scenario's default)" if ctx.overrides else "")
             + f"; wind: {ctx.wind_type}"
             + (" (the paper's: mean + sinusoid of period 10 s and std 0.5 m/s along y)" if ctx.wind_type == "gust"
                else " (Dryden turbulence about the mean, seeded)") + ".", ""]
    if ctx.n_planned and len(results) < ctx.n_planned:
        lines += [f"**Incomplete: {len(results)} of {ctx.n_planned} runs finished** (rerun the same command to "
                  "resume).", ""]
    controllers = order_controllers(r["controller"] for r in rows)
    winds = sorted({r["wind"] for r in rows})
    # a "paper" column only beside controllers the paper reports on in this scenario
    # (and only in the paper's wind: its numbers are for the gust, not for Dryden turbulence)
    paper_cols = {c: ctx.wind_type == "gust"
                  and any(paper_numbers(sc.name, w, c) for w in PAPER_RESULTS.get(sc.name, {}))
                  for c in controllers}
    for wind in winds:
        at = [r for r in rows if r["wind"] == wind]
        seeds = sorted({int(r["seed"]) for r in at})
        lines += [f"## Mean wind {wind:g} m/s" + (f" ({len(seeds)} seeds: mean; minimum distance and clearance: "
                                                  "min; collisions: sum)" if len(seeds) > 1 else f" (seed {seeds[0]})"),
                  ""]
        header, rule = ["metric"], ["---"]
        for c in controllers:
            if not any(r["controller"] == c for r in at):
                continue
            header += [display_name(c), "paper"] if paper_cols[c] else [display_name(c)]
            rule += ["---:", "---:"] if paper_cols[c] else ["---:"]
        lines += ["| " + " | ".join(header) + " |", "|" + "|".join(rule) + "|"]
        for label, col, fmt, how in ROWS:
            label_txt = label + (f" (±{results[0].safety_margin:g} m)" if col == "safety" else "")
            if col == "time_below_d_min_s":
                label_txt += f" ({_values_of(results, 'd_min_m', lambda v: f'{v:g} m')})"
            cells = [label_txt]
            for c in controllers:
                runs = [r for r in at if r["controller"] == c]
                if not runs:
                    continue
                ours = _aggregate(runs, col, how)
                paper = paper_numbers(sc.name, wind, c).get(col)
                cells += [fmt(ours)] + ([fmt(paper) if paper is not None else "-"] if paper_cols[c] else [])
            lines.append("| " + " | ".join(cells) + " |")
        ends = []
        for c in controllers:
            runs = [r for r in at if r["controller"] == c]
            if runs:
                kinds = sorted({r["termination"] for r in runs})
                ends.append(f"{display_name(c)}: {', '.join(kinds)}")
        lines += ["", "Ended: " + "; ".join(ends) + ".", ""]
    lines += ["## All runs", "",
              "| controller | wind | seed | coverage | SM | CM | mean d to point | min d to point "
              "| min clearance | below d_min | energy | mean power | path | collisions | flight time "
              "| solve median / p99 | ended | wall time |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|"]
    for r in rows:
        lines.append(f"| {display_name(r['controller'])} | {r['wind']:g} | {r['seed']} | {_pct(r['coverage'])} | "
                     f"{_pct(r['safety'])} | {_pct(r['centering'])} | {_m(r['mean_distance'])} | "
                     f"{_m(r['min_distance'])} | {_m(r['clearance_min_m'])} | {_s(r['time_below_d_min_s'])} | "
                     f"{_wh(r['energy_wh'])} | {_w(r['mean_power_w'])} | {_path(r['path_length'])} | "
                     f"{r['collisions']} | {r['flight_time']:.0f} s | "
                     f"{_ms(r['solve_median_ms'])} / {_ms(r['solve_p99_ms'])} | {r['termination']} | "
                     f"{r['wall_time']:.0f} s |")
    lines += _stall_lines(results)
    filtered = [r for r in rows if math.isfinite(float(r.get("filter_median_ms", math.nan)))]
    if filtered:
        lines += ["", "## Safety filter", "",
                  "| controller | wind | seed | interventions | mean correction | fallbacks | passed without QP "
                  "| filter median / p99 |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in filtered:
            lines.append(f"| {display_name(r['controller'])} | {r['wind']:g} | {r['seed']} | "
                         f"{_pct(r['filter_intervention_fraction'])} | {r['filter_mean_correction']:.3f} | "
                         f"{r['filter_fallbacks']:.0f} | {_pct(r.get('filter_passed_fraction', math.nan))} | "
                         f"{_ms(r['filter_median_ms'])} / {_ms(r['filter_p99_ms'])} |")
    paper_src = {"paper": "the paper's Table \"Simulation results\" (Gazebo, 4 m/s) and its text (distances; "
                          "100 % coverage for all at 0 m/s)",
                 "paper-faithful": "the paper's Table \"Simulation results\" (Gazebo, 4 m/s) and its text, beside "
                                   "the fixed and the authors' baselines alike and both VT-NMPC weight sets",
                 "lab": "the paper's Table \"Statistical analysis of the experimental results\" (mean of three "
                        "real flights with a 4 m/s blowing tunnel; this is a simulation of that setup)"}
    lines += ["", "## How these numbers were made", "",
              (f"- Paper columns: {paper_src[sc.name]}. Paper solve times are per solve on a Jetson TX2 "
               "(ACADO + qpOASES); ours are the policy's own solve time per control step on the machine below."
               if any(paper_cols.values()) else
               "- No paper columns: the paper has no numbers for this scenario and wind. Solve times are the "
               "policy's own time per control step on the machine below."),
              "- Metrics (wt_inspect_env.task.metrics): coverage = share of the mission's blade triangles "
              "seen at least "
              f"once ({_frames_note(results)}); SM = share of inspecting samples with "
              "|d - d_ref| below the margin, d the horizontal distance to the inspection point; CM = mean heading "
              "function h of the gimbal camera (the horizontal part of the body x axis, as the authors' code "
              "computed it); \"CM with body-axis h\" uses the paper's printed full-attitude formula, which "
              "drops by cos(tilt) when the drone leans into the wind while the image stays centred; all at "
              f"every control step ({_values(results, 'ctrl_hz', lambda v: f'{1.0 / float(v):g} s')}). "
              "\"Distance to the inspection point\" is that d; it is not the distance to the turbine.",
              "- Clearance (wt_inspect.evaluation.harness_metrics): distance from the drone's centre to the nearest "
              "point of the turbine's collision mesh (blades, hub, nacelle, tower; the rotor position in force at "
              "each control step), its minimum over the whole flight and the time spent below d_min = 3/7 d_ref "
              "(the MPCs' default clearance constraint: 3 m at 7 m); the body-box row subtracts the radius of the "
              "sphere round the drone's collision box, a lower bound of the box's distance.",
              "- Energy: per rotor momentum theory's ideal induced power T^1.5 / sqrt(2 rho A) over the figure of "
              "merit and the motor + ESC efficiency, summed over the rotors and integrated over the flight "
              f"(trapezoid at every control step); {_energy_note(results)} Typical published values for small "
              "multirotor propellers, not measured on the airframe; forward-flight inflow, avionics and idle "
              "draw are not modelled, so compare controllers with it rather than read battery life off it. "
              "Mean power = energy / flight time; path length = sum of the distances between consecutive "
              "positions.",
              *(["- Safety filter (controllers.safety_filter, a `+filter` controller): interventions = share of "
                 "control steps whose action it changed (by more than 0.001 of the normalised range); mean "
                 "correction = mean max-norm change of the normalised action; fallbacks = steps whose QP failed "
                 "and the filter's backup plan flew; its time per step, besides the policy's own."]
                if filtered else []),
              f"- Hardware: {hardware()}.",
              f"- Backend: {ctx.backend}, {ctx.jobs} parallel jobs; wall time of this invocation "
              f"{ctx.wall_time_s:.0f} s ({ctx.n_ran} runs executed, {ctx.n_resumed} resumed from earlier run files)."]
    if ctx.command:
        lines.append(f"- Command: `{ctx.command}`")
    lines += [f"- {n}" for n in (*sc.notes, *ctx.notes)]
    return "\n".join(lines) + "\n"


def write_markdown(results: Sequence[RunResult], ctx: ReportContext, path: str | Path) -> Path:
    """Write :func:`markdown` to ``path`` atomically and return the path."""
    write_text_atomic(path, markdown(results, ctx))
    return Path(path)
