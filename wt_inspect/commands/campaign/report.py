"""A campaign's files: results.md, campaign.json and .png, and the comparison of several controllers."""
from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from wt_inspect_env.util.atomic_io import write_text_atomic

from ...evaluation import OutputDirError
from ...evaluation.runner import RunResult, RunSpec
from .draws import NREL_SCALE_RANGE, SIZE_RANGES, START_CLEARANCE_RATIO, TURBINE_KINDS, CampaignConfig, controller_dir
from .summary import (
    COLUMNS,
    FILTER_FIELDS,
    FORMAT,
    METRICS,
    RSS_WARMUP_EPISODES,
    default_d_min,
    episode_row,
    failures,
    fmt,
    num,
    refly_command,
    summarise,
    worst_by_metric,
    worst_episodes,
)

DIFFER_SHOWN = 10          # episodes where the controllers differ most, in comparison.md


def _conditions(r: Mapping[str, Any]) -> str:
    kind = r["turbine"] if r["turbine"] != "nrel-5mw-scaled" else f"nrel-5mw x{num(r['turbine_scale']):.2f}"
    return (f"{kind} {num(r['tower_height']):.0f}/{num(r['blade_length']):.0f} m, "
            f"az {num(r['rotor_azimuth_deg']):.0f}, "
            f"wind {num(r['wind']):.1f} m/s @ {num(r['wind_direction_deg']):.0f} deg, "
            f"start {num(r['start_offset_m']):.1f} m"
            f", mass x{fmt(r.get('mass_factor'))}")


def _markdown(cfg: CampaignConfig, summary: Mapping[str, Any], rows: Sequence[Mapping[str, Any]],
              command: str, walls: Sequence[float], out: str, n_planned: int | None = None) -> str:
    s = summary
    d_min = s["d_min_m"]
    n_planned = s["episodes"] if n_planned is None else n_planned
    count = (f"{s['episodes']} episodes" if s["episodes"] >= n_planned
             else f"{s['episodes']} of {n_planned} episodes, incomplete")
    lines = [f"# Robustness campaign: {cfg.controller}, {count}", "",
             f"`{command}`" if command else "", ""]
    if s["episodes"] < n_planned:
        lines += [f"**Incomplete: {s['episodes']} of {n_planned} episodes finished** (rerun the same command to "
                  "resume).", ""]
    kinds = ", ".join(f"{k} {100 * p:.0f} %" for k, p in TURBINE_KINDS.items())
    only = f"; only episode(s) {', '.join(map(str, cfg.only))} of {cfg.episodes}" if cfg.only else ""
    airframe = ("on (mass, inertia, drag, thrust, torque, motor lag; no noise or latency)"
                if cfg.airframe_randomization else "off")
    lines += [
        f"Task `{cfg.task}`, master seed {cfg.seed}{only}; turbines: {kinds} (generated: tower "
        f"{SIZE_RANGES['tower_height']} m, cuboid blades {SIZE_RANGES['blade_length']} x "
        f"{SIZE_RANGES['blade_width']} m; scaled NREL 5-MW: x{NREL_SCALE_RANGE[0]:g}-{NREL_SCALE_RANGE[1]:g}), "
        f"rotor azimuth [0, 120) deg with the planner's rotor turns; Dryden wind, mean [0, {cfg.max_wind:g}] m/s from "
        f"any horizontal direction; starts up to {cfg.max_offset:g} m off the stand-off pose; airframe domain "
        f"randomisation {airframe}; "
        + (f"**episodes capped at {cfg.max_time:g} simulated s** (not whole missions)." if cfg.max_time
           else "every episode flown to the mission's end or its time limit."), "",
        "| measure | value | goal |", "|---|---:|---|",
        f"| exceptions | {s['exceptions']} | 0 |",
        f"| non-finite states | {s['non_finite_states']} | 0 |",
        f"| crashes (collision / left the working volume) | {s['crashes']} | 0 |",
        f"| episodes with a collision | {s['episodes_with_collisions']} | 0 |",
        f"| missions completed | {s['mission_complete']} of {s['episodes']} | all |",
        f"| episodes with clearance to the structure below d_min = {d_min:g} m | {s['clearance_below_d_min']} | 0 |",
        f"| episodes whose reference stalled | {s['episodes_with_stalls']} | 0 |",
        f"| QP fallbacks | {s['fallback_steps']:.0f} of {s['steps']} steps ({100 * s['fallback_fraction']:.4f} %) "
        f"| < 0.01 % |",
        f"| worker memory (RSS after each episode) | {s['rss_first_mb']:.1f} -> {s['rss_last_mb']:.1f} MB, max "
        f"{s['rss_max_mb']:.1f}, largest slope of a worker {s['rss_slope_mb_per_episode']:+.3f} MB/episode "
        f"({s['rss_slope_after_warmup_mb_per_episode']:+.3f} after its first {RSS_WARMUP_EPISODES}) | flat |",
        f"| starts redrawn (drawn within {START_CLEARANCE_RATIO:.2f} d_ref of the turbine) | {s['start_redraws']} "
        "| - |",
        *([f"| safety filter: interventions [% of steps], median [min - max] over episodes | "
           f"{100 * s['filter']['filter_intervention_fraction']['median']:.2f} "
           f"[{100 * s['filter']['filter_intervention_fraction']['min']:.2f} - "
           f"{100 * s['filter']['filter_intervention_fraction']['max']:.2f}] | - |",
           f"| safety filter: steps passed without a QP [%], median [min - max] over episodes | "
           f"{100 * s['filter']['filter_passed_fraction']['median']:.2f} "
           f"[{100 * s['filter']['filter_passed_fraction']['min']:.2f} - "
           f"{100 * s['filter']['filter_passed_fraction']['max']:.2f}] | - |",
           f"| safety filter: fallbacks (QP failed, backup plan flown) | "
           f"{s['filter']['filter_fallbacks']['mean'] * s['filter']['filter_fallbacks']['n']:.0f} in all | 0 |",
           f"| safety filter: time per step, median of the episodes' median / p99 [ms] | "
           f"{s['filter']['filter_median_ms']['median']:.3f} / {s['filter']['filter_p99_ms']['median']:.3f} | "
           "<= 0.3 / 1 |"] if "filter" in s else []),
        f"| wall time | {sum(walls):.1f} s over {len(walls)} invocation(s) ("
        + ", ".join(f"{w:.1f}" for w in walls) + f" s); {s['wall_time_per_episode_s']:.1f} s per episode in a "
        "worker | - |", "",
        "Terminations: " + ", ".join(f"{k or 'none'} {v}" for k, v in s["terminations"].items()), "",
        "## Distribution of each metric", "",
        "| metric | n | min | p5 | median | mean | p95 | max | worst episode |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    worst_m = worst_by_metric(rows)
    for col, label, unit, scale, _worse in METRICS:
        d = s["distribution"][col]
        w = worst_m.get(col)
        lines.append(f"| {label} [{unit}] | {d['n']} | " + " | ".join(fmt(d[k], scale) for k in
                     ("min", "p5", "median", "mean", "p95", "max")) + f" | {w['episode'] if w else '-'} |")
    worst = worst_episodes(rows, d_min)
    lines += ["", f"## Worst episodes ({len(worst)} of {len(rows)})", "",
              "Ranked: exceptions, crashes, collisions, clearance below d_min, missions not completed, then lowest "
              "coverage and SM. Each command flies that one episode again (same draw, same run spec: the same "
              "numbers).", "",
              "| # | what went wrong | conditions | end | coverage | SM | CM | clearance | to point | energy "
              "| fallbacks |", "|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in worst:
        lines.append(f"| {r['episode']} | {', '.join(failures(r, d_min)) or '-'} | {_conditions(r)} | "
                     f"{r['termination']} | {fmt(r['coverage'], 100, 1)} | {fmt(r['safety'], 100, 1)} | "
                     f"{fmt(r['centering'], 100, 1)} | {fmt(r['clearance_min_m'])} m | "
                     f"{fmt(r['min_distance'])} m | {fmt(r['energy_wh'])} Wh | {fmt(r['fallback_steps'], 1, 0)} |")
    lines += [""]
    for r in worst:
        lines += [f"- episode {r['episode']}: `{refly_command(cfg, r['episode'], out)}`"]
    lines += ["", "## Every episode", "",
              "| # | turbine | wind | azimuth | offset | mass | end | coverage | SM | CM | clearance | below d_min "
              "| to point | energy | fallbacks | RSS | error |",
              "|---:|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        kind = r["turbine"] if r["turbine"] != "nrel-5mw-scaled" else f"nrel x{num(r['turbine_scale']):.2f}"
        lines.append(f"| {r['episode']} | {kind} {num(r['tower_height']):.0f}/{num(r['blade_length']):.0f} | "
                     f"{num(r['wind']):.1f} | {num(r['rotor_azimuth_deg']):.0f} | {num(r['start_offset_m']):.1f} | "
                     f"{fmt(r.get('mass_factor'))} | {r['termination']} | {fmt(r['coverage'], 100, 1)} | "
                     f"{fmt(r['safety'], 100, 1)} | {fmt(r['centering'], 100, 1)} | {fmt(r['clearance_min_m'])} | "
                     f"{fmt(r['time_below_d_min_s'], 1, 1)} | {fmt(r['min_distance'])} | {fmt(r['energy_wh'])} | "
                     f"{fmt(r['fallback_steps'], 1, 0)} | {fmt(r['rss_mb'], 1, 0)} | {str(r['error'])[:80]} |")
    return "\n".join(lines) + "\n"


def _figure(rows: Sequence[Mapping[str, Any]], path: Path, d_min: float) -> Path:
    """Histogram of each metric (the worst episode's number over its bar) and the worker RSS."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from wt_inspect_env.util.figure_io import save_and_close
    fig, axes = plt.subplots(3, 4, figsize=(14, 9))
    worst_m = worst_by_metric(rows)
    for ax, (col, label, unit, scale, _worse) in zip(axes.flat, METRICS[:10]):
        v = np.array([num(r[col]) for r in rows]) * scale
        ok = np.isfinite(v)
        if ok.any():
            vals = v[ok]
            lo, hi = float(vals.min()), float(vals.max())
            pad = max(1e-6, 0.01 * max(abs(lo), abs(hi)))
            if hi - lo <= 1e-9 * max(1.0, abs(lo), abs(hi)):   # (nearly) one value: one bar round it
                ax.hist(vals, bins=1, range=(lo - pad, hi + pad), color="C0")
            else:
                ax.hist(vals, bins=min(30, max(5, int(ok.sum()) // 3)), color="C0")
        if col == "clearance_min_m":
            ax.axvline(d_min, color="r", lw=0.8, ls="--", label=f"d_min {d_min:g} m")
            ax.legend(fontsize=7)
        w = worst_m.get(col)
        if w is not None:
            ax.annotate(f"worst: #{w['episode']}", xy=(num(w[col]) * scale, 0), xytext=(0, 14),
                        textcoords="offset points", fontsize=7, color="r", ha="center",
                        arrowprops={"arrowstyle": "->", "color": "r", "lw": 0.6})
        ax.set(xlabel=f"{label} [{unit}]", ylabel="episodes")
        ax.title.set_fontsize(8)
    ax = axes.flat[10]
    for w in sorted({r["worker"] for r in rows}):
        mine = [r for r in rows if r["worker"] == w]
        ax.plot([r["episode"] for r in mine], [num(r["rss_mb"]) for r in mine], ".-", label=f"worker {w}")
    ax.set(xlabel="episode", ylabel="worker RSS [MB]", title="memory after each episode")
    ax.title.set_fontsize(8)
    ax = axes.flat[11]
    bad = np.array([bool(failures(r, d_min)) for r in rows])
    off = np.array([num(r["start_offset_m"]) for r in rows])
    wind = np.array([num(r["wind"]) for r in rows])
    ax.scatter(wind[~bad], off[~bad], s=12, label="completed, clear")
    ax.scatter(wind[bad], off[bad], s=20, marker="x", c="r", label="failed / short of the end")
    ax.set(xlabel="mean wind [m/s]", ylabel="start offset [m]", title="conditions")
    ax.title.set_fontsize(8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_and_close(fig, path)


def write_report(cfg: CampaignConfig, out_dir: Path, specs: list[RunSpec], by_file: Mapping[str, Any],
            results: Mapping[str, RunResult], *, t0: float, earlier: Sequence[float], figure: bool, command: str,
            out: str) -> dict[str, Any]:
    """episodes.csv, campaign.json, results.md (all atomic) and campaign.png of the finished episodes."""
    rows = [episode_row(by_file[s.filename], results[s.filename]) for s in specs if s.filename in results]
    d_min = default_d_min()
    summary = summarise(rows, d_min)
    this = time.perf_counter() - t0
    walls = [*earlier, this]
    doc = {"format": FORMAT, "config": config_json(cfg), "command": command,
           "complete": len(rows) == len(specs), "episodes_planned": len(specs),
           "wall_time_s": sum(walls), "wall_time_invocations_s": walls, "wall_time_this_invocation_s": this,
           "wall_time_total_s": sum(walls),   # = wall_time_s (the name format /1 used for the sum)
           "summary": summary,
           "worst_episodes": [{"episode": r["episode"], "failures": failures(r, d_min),
                               "command": refly_command(cfg, r["episode"], out)} for r in worst_episodes(rows, d_min)],
           "episodes": rows, "draws": [by_file[s.filename] for s in specs]}
    try:
        buf = io.StringIO()
        filtered = any(k in r for r in rows for k in FILTER_FIELDS)
        w = csv.DictWriter(buf, fieldnames=COLUMNS + FILTER_FIELDS if filtered else COLUMNS)
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(out_dir / "episodes.csv", buf.getvalue())
        write_text_atomic(out_dir / "campaign.json", json.dumps(doc, indent=1, default=float) + "\n")
        write_text_atomic(out_dir / "results.md", _markdown(cfg, summary, rows, command, walls, out,
                                                            n_planned=len(specs)))
        if figure and rows:
            doc["figure"] = str(_figure(rows, out_dir / "campaign.png", d_min))
    except OSError as exc:
        raise OutputDirError(f"cannot write the campaign results to {str(out_dir)!r}: "
                             f"{exc.strerror or exc}") from None
    return doc


def config_json(cfg: CampaignConfig) -> dict[str, Any]:
    """The configuration as plain JSON data (what ``campaign.json`` records and a resume compares)."""
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=float))


def _paired(docs: Mapping[str, Mapping[str, Any]]) -> list[int]:
    """Episodes every controller finished."""
    sets = [{r["episode"] for r in d["episodes"]} for d in docs.values()]
    return sorted(set.intersection(*sets)) if sets else []


def write_comparison(cfg: CampaignConfig, docs: Mapping[str, Mapping[str, Any]], out_dir: Path, out: str, *,
                     command: str = "", figure: bool = True) -> dict[str, Any]:
    """The comparison of the controllers' campaigns (``docs``: controller -> campaign.json)."""
    d_min = default_d_min()
    names = list(docs)
    draws = {c: {d["episode"]: d for d in doc["draws"]} for c, doc in docs.items()}
    same = all(draws[c] == draws[names[0]] for c in names)
    rows = {c: {r["episode"]: r for r in doc["episodes"]} for c, doc in docs.items()}
    paired = _paired(docs)
    differ = []
    for k in paired:
        rs = [rows[c][k] for c in names]
        spread = {col: (max(v) - min(v)) if all(math.isfinite(x) for x in v) else math.inf
                  for col in ("coverage", "safety", "centering")
                  for v in [[num(r[col]) for r in rs]]}
        cl = [num(r["clearance_min_m"]) for r in rs]
        outcome_differs = len({(r["termination"], bool(failures(r, d_min))) for r in rs}) > 1
        score = (outcome_differs, spread["coverage"] + spread["safety"] + spread["centering"],
                 max(cl) - min(cl) if all(map(math.isfinite, cl)) else math.inf)
        differ.append((score, k))
    differ.sort(key=lambda x: (not x[0][0], -x[0][1], -x[0][2], x[1]))
    top = [k for _, k in differ[:DIFFER_SHOWN]]
    summaries = {c: summarise([rows[c][k] for k in paired], d_min) for c in names}
    doc = {"format": "wt-inspect-campaign-comparison/1", "config": config_json(cfg), "controllers": names,
           "command": command, "same_draws": same, "paired_episodes": paired,
           "wall_time_s": {c: docs[c]["wall_time_s"] for c in names},
           "summary": summaries, "differ_most": [
               {"episode": k, **{c: {col: rows[c][k][col] for col in ("termination", "coverage", "safety",
                                                                    "centering", "clearance_min_m", "energy_wh")}
                                 for c in names},
                "commands": {c: refly_command(dataclasses.replace(cfg, controller=c), k,
                                              os.path.join(out, controller_dir(c))) for c in names}}
               for k in top]}
    lines = [f"# Campaign side by side: {', '.join(names)}", "", f"`{command}`" if command else "", "",
             f"The same {len(paired)} episodes (master seed {cfg.seed}, "
             + ("identical draws for every controller" if same else "**draws differ between the controllers**")
             + "; " + ("each flown to the mission's end or its time limit" if cfg.max_time is None
                       else f"**capped at {cfg.max_time:g} simulated s**")
             + "). Each controller's own report: " + ", ".join(f"[{c}]({controller_dir(c)}/results.md)" for c in names)
             + ".", "",
             "| measure | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for label, key in (("exceptions", "exceptions"), ("non-finite states", "non_finite_states"),
                       ("crashes", "crashes"), ("episodes with a collision", "episodes_with_collisions"),
                       ("missions completed", "mission_complete"),
                       (f"clearance below d_min = {d_min:g} m", "clearance_below_d_min"),
                       ("episodes with a reference stall", "episodes_with_stalls")):
        lines.append(f"| {label} | " + " | ".join(str(summaries[c][key]) for c in names) + " |")
    lines.append("| QP fallbacks [% of steps] | " + " | ".join(
        fmt(summaries[c]["fallback_fraction"], 100, 4) for c in names) + " |")
    lines.append("| wall time [s] | " + " | ".join(fmt(docs[c]["wall_time_s"], 1, 0) for c in names) + " |")
    lines += ["", "Per metric: median [p5 - p95] (min - max) over the paired episodes.", "",
              "| metric | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for col, label, unit, scale, _worse in METRICS:
        cells = []
        for c in names:
            d = summaries[c]["distribution"][col]
            cells.append(f"{fmt(d['median'], scale)} [{fmt(d['p5'], scale)} - {fmt(d['p95'], scale)}] "
                         f"({fmt(d['min'], scale)} - {fmt(d['max'], scale)})")
        lines.append(f"| {label} [{unit}] | " + " | ".join(cells) + " |")
    lines += ["", f"## Where they differ most ({len(top)} episodes)", "",
              "Ranked: a different outcome (termination, or one fails where another does not) first, then the "
              "spread of coverage + SM + CM, then of clearance. Cells: end, coverage / SM / CM [%], clearance [m].",
              "", "| # | conditions | " + " | ".join(names) + " |", "|---:|---|" + "---|" * len(names)]
    for k in top:
        r0 = rows[names[0]][k]
        cells = [f"{rows[c][k]['termination']}, {fmt(rows[c][k]['coverage'], 100, 1)} / "
                 f"{fmt(rows[c][k]['safety'], 100, 1)} / {fmt(rows[c][k]['centering'], 100, 1)}, "
                 f"{fmt(rows[c][k]['clearance_min_m'])}" for c in names]
        lines.append(f"| {k} | {_conditions(r0)} | " + " | ".join(cells) + " |")
    lines.append("")
    for item in doc["differ_most"]:
        for c in names:
            lines.append(f"- episode {item['episode']}, {c}: `{item['commands'][c]}`")
    try:
        buf = io.StringIO()
        cols = ["episode", "controller"] + [c for c in COLUMNS if c not in ("episode",)]
        w = csv.DictWriter(buf, fieldnames=cols)
        w.writeheader()
        for k in paired:
            for c in names:
                w.writerow({**rows[c][k], "controller": c})
        write_text_atomic(out_dir / "comparison.csv", buf.getvalue())
        write_text_atomic(out_dir / "comparison.json", json.dumps(doc, indent=1, default=float) + "\n")
        write_text_atomic(out_dir / "comparison.md", "\n".join(lines) + "\n")
        if figure and paired:
            doc["figure"] = str(_comparison_figure(names, rows, paired, out_dir / "comparison.png", d_min))
    except OSError as exc:
        raise OutputDirError(f"cannot write the comparison to {str(out_dir)!r}: {exc.strerror or exc}") from None
    return doc


def _comparison_figure(names: Sequence[str], rows: Mapping[str, Mapping[int, Mapping[str, Any]]],
                       paired: Sequence[int], path: Path, d_min: float) -> Path:
    """Per metric, each controller's values over the paired episodes (box plot and the points)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from wt_inspect_env.util.figure_io import save_and_close
    shown = METRICS[:9]
    fig, axes = plt.subplots(3, 3, figsize=(4 + 1.6 * len(names) * 3, 9))
    for ax, (col, label, unit, scale, _worse) in zip(axes.flat, shown):
        data = [np.array([num(rows[c][k][col]) * scale for k in paired]) for c in names]
        ax.boxplot([d[np.isfinite(d)] for d in data], showfliers=False)
        for i, d in enumerate(data):
            ax.scatter(np.full(len(d), i + 1) + np.linspace(-0.15, 0.15, len(d)), d, s=8, alpha=0.6)
        if col == "clearance_min_m":
            ax.axhline(d_min, color="r", lw=0.8, ls="--")
        ax.set_xticks(range(1, len(names) + 1), names, fontsize=7)
        ax.set_title(f"{label} [{unit}]", fontsize=8)
    fig.tight_layout()
    return save_and_close(fig, path)
