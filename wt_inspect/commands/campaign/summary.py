"""A campaign's numbers: one row per episode, the distribution of each metric, the worst episodes."""
from __future__ import annotations

import math
import os
import shlex
from typing import Any, Mapping, Sequence

import numpy as np

from ...evaluation.runner import RunResult
from .draws import CampaignConfig

FORMAT = "wt-inspect-campaign/2"   # /2: whole missions, NREL turbines, any wind direction, airframe DR, invocations


RSS_WARMUP_EPISODES = 20   # a worker's first episodes compile solvers and fill caches: memory grows, then holds


WORST_SHOWN = 10           # worst episodes listed (with their re-fly commands) in results.md


COLUMNS = ("episode", "seed", "turbine", "turbine_scale", "wind", "wind_direction_deg", "tower_height",
           "blade_length", "blade_width", "rotor_azimuth_deg", "start_offset_m", "start_redraws", "mass_factor",
           "thrust_factor", "termination", "mission_complete", "crashed", "exception", "non_finite", "collisions",
           "steps", "fallback_steps", "fallback_fraction", "coverage", "safety", "centering", "min_distance",
           "clearance_min_m", "clearance_body_min_m", "time_below_d_min_s", "stalls", "skipped_path_m",
           "energy_wh", "path_length", "sim_time", "wall_time", "rss_mb", "worker", "run_file", "error")


# The per-episode metrics whose distribution is reported: column, label, unit, scale, worse when
# ("low" / "high").
#: a safety filter's counts per episode (controllers.safety_filter; only for NAME+filter)
FILTER_FIELDS = ("filter_intervention_fraction", "filter_mean_correction", "filter_fallbacks",
                 "filter_passed_fraction", "filter_median_ms", "filter_p99_ms")


METRICS: tuple[tuple[str, str, str, float, str], ...] = (
    ("coverage", "coverage", "%", 100.0, "low"),
    ("safety", "SM", "%", 100.0, "low"),
    ("centering", "CM", "%", 100.0, "low"),
    ("clearance_min_m", "min clearance to the structure", "m", 1.0, "low"),
    ("time_below_d_min_s", "time below d_min", "s", 1.0, "high"),
    ("min_distance", "min distance to the inspection point", "m", 1.0, "low"),
    ("fallback_fraction", "QP fallbacks", "% of steps", 100.0, "high"),
    ("energy_wh", "energy", "Wh", 1.0, "high"),
    ("path_length", "path length", "m", 1.0, "high"),
    ("sim_time", "simulated time", "s", 1.0, "high"),
    ("rss_mb", "worker RSS after the episode", "MB", 1.0, "high"),
)


def episode_row(draw: Mapping[str, Any], res: RunResult) -> dict[str, Any]:
    """The ``episodes.csv`` row of one episode: its draw and its result's metrics."""
    m = res.metrics
    term = res.termination or ""
    fb = res.solve.get("fallback_steps", math.nan)
    return {**{k: draw[k] for k in ("episode", "seed", "turbine", "turbine_scale", "wind", "wind_direction_deg",
                                    "tower_height", "blade_length", "blade_width", "rotor_azimuth_deg",
                                    "start_offset_m")},
            "start_redraws": int(res.solve.get("start_redraws", 0) or 0),
            "mass_factor": res.solve.get("mass_factor", math.nan),
            "thrust_factor": res.solve.get("thrust_factor", math.nan),
            "termination": term, "mission_complete": bool(res.mission_complete),
            "crashed": term in ("collision", "left_working_volume"),
            "exception": term == "exception", "non_finite": term == "non_finite_state",
            "collisions": m.get("collisions", 0) or 0, "steps": res.steps, "fallback_steps": fb,
            "fallback_fraction": fb / res.steps if res.steps else math.nan,
            "coverage": m.get("coverage", math.nan), "safety": m.get("safety_sm", math.nan),
            "centering": m.get("centering_cm", math.nan), "min_distance": m.get("min_distance_m", math.nan),
            "clearance_min_m": m.get("clearance_min_m", math.nan),
            "clearance_body_min_m": m.get("clearance_body_min_m", math.nan),
            "time_below_d_min_s": m.get("time_below_d_min_s", math.nan),
            "stalls": m.get("stalls", math.nan), "skipped_path_m": m.get("skipped_path_m", math.nan),
            "energy_wh": m.get("energy_wh", math.nan),
            "path_length": m.get("path_length_m", math.nan),
            "sim_time": res.sim_time_s, "wall_time": res.wall_time_s, "rss_mb": res.solve.get("rss_mb", math.nan),
            "worker": int(res.solve.get("worker_pid", 0) or 0), "run_file": res.path.name if res.path else "",
            "error": m.get("error", ""),
            **{k: res.solve[k] for k in FILTER_FIELDS if k in res.solve}}   # a NAME+filter controller


def num(v: Any) -> float:
    """``v`` as a float (NaN when it is missing or not a number)."""
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def distribution(values: Sequence[Any]) -> dict[str, float]:
    """``n`` (finite values), ``min``, ``p5``, ``median``, ``mean``, ``p95``, ``max`` of ``values``
    (NaN - an episode that raised - left out; all NaN when none is finite)."""
    v = np.array([num(x) for x in values], dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return {"n": 0, **{k: math.nan for k in ("min", "p5", "median", "mean", "p95", "max")}}
    return {"n": int(len(v)), "min": float(v.min()), "p5": float(np.percentile(v, 5)),
            "median": float(np.median(v)), "mean": float(v.mean()), "p95": float(np.percentile(v, 95)),
            "max": float(v.max())}


def summarise(rows: Sequence[Mapping[str, Any]], d_min: float | None = None) -> dict[str, Any]:
    """Totals of a campaign (the README's goal: 0 exceptions, 0 non-finite states, fallbacks
    below 0.1 % of steps, memory flat) and the distribution of each of :data:`METRICS`."""
    n = len(rows)
    d_min = default_d_min() if d_min is None else d_min
    steps = sum(int(r["steps"]) for r in rows)
    fb = sum(float(r["fallback_steps"]) for r in rows if not math.isnan(float(r["fallback_steps"])))
    rss = [float(r["rss_mb"]) for r in rows if not math.isnan(float(r["rss_mb"]))]
    slopes, late = [], []   # per worker: episodes run one after another in the same process
    for w in sorted({r["worker"] for r in rows}):
        mine = [float(r["rss_mb"]) for r in rows if r["worker"] == w and not math.isnan(float(r["rss_mb"]))]
        if len(mine) >= 3:
            slopes.append(float(np.polyfit(np.arange(len(mine)), mine, 1)[0]))
        if len(mine) >= RSS_WARMUP_EPISODES + 3:   # after the first-use compiles and caches
            late.append(float(np.polyfit(np.arange(len(mine) - RSS_WARMUP_EPISODES), mine[RSS_WARMUP_EPISODES:], 1)[0]))
    slope = max(slopes) if slopes else math.nan
    wall = [float(r["wall_time"]) for r in rows]
    return {"episodes": n, "exceptions": sum(bool(r["exception"]) for r in rows),
            "non_finite_states": sum(bool(r["non_finite"]) for r in rows),
            "crashes": sum(bool(r["crashed"]) for r in rows),
            "episodes_with_collisions": sum(int(r["collisions"]) > 0 for r in rows),
            "mission_complete": sum(r["termination"] == "mission_complete" for r in rows),
            "clearance_below_d_min": sum(num(r["clearance_min_m"]) < d_min for r in rows), "d_min_m": d_min,
            "episodes_with_stalls": sum(num(r.get("stalls", math.nan)) > 0 for r in rows),
            "steps": steps, "fallback_steps": fb, "fallback_fraction": fb / steps if steps else math.nan,
            "rss_first_mb": rss[0] if rss else math.nan, "rss_last_mb": rss[-1] if rss else math.nan,
            "rss_max_mb": max(rss) if rss else math.nan, "rss_slope_mb_per_episode": slope,
            "rss_slope_after_warmup_mb_per_episode": max(late) if late else math.nan,
            "start_redraws": sum(int(r.get("start_redraws", 0) or 0) for r in rows),
            "wall_time_per_episode_s": float(np.mean(wall)) if wall else math.nan,
            "terminations": {t: sum(r["termination"] == t for r in rows)
                             for t in sorted({r["termination"] for r in rows})},
            **({"filter": {k: distribution([r.get(k, math.nan) for r in rows]) for k in FILTER_FIELDS}}
               if any(k in r for r in rows for k in FILTER_FIELDS) else {}),
            "distribution": {col: distribution([r[col] for r in rows]) for col, *_ in METRICS}}


def default_d_min() -> float:
    """The d_min the episodes fly with: the environment's default at the default stand-off."""
    from wt_inspect_env.task.env_config import EnvConfig
    return float(EnvConfig().d_min)     # the episodes fly the default stand-off


def failures(row: Mapping[str, Any], d_min: float) -> list[str]:
    """What went wrong in an episode, worst first (empty: a completed mission, clear of d_min)."""
    out = []
    if row["exception"]:
        out.append("exception")
    if row["non_finite"]:
        out.append("non-finite state")
    if row["crashed"]:
        out.append(str(row["termination"]).replace("_", " "))
    elif int(row["collisions"]) > 0:
        out.append("collision")
    if num(row["clearance_min_m"]) < d_min:
        out.append("clearance below d_min")
    if not row["exception"] and not row["crashed"] and not row["mission_complete"]:
        out.append("not completed" + (f" ({row['termination']})" if row["termination"] else ""))
    if num(row.get("stalls", math.nan)) > 0:
        out.append(f"reference stalled {int(num(row['stalls']))}x "
                   f"({num(row.get('skipped_path_m', math.nan)):.0f} m skipped)")
    return out


def worst_episodes(rows: Sequence[Mapping[str, Any]], d_min: float, n: int = WORST_SHOWN) -> list[Mapping[str, Any]]:
    """The ``n`` worst episodes: exceptions, then crashes and collisions, clearance below d_min,
    missions not completed, then by coverage and SM (lowest first), then by clearance."""
    def key(r: Mapping[str, Any]) -> tuple:
        cov, sm, cl = (num(r[c]) for c in ("coverage", "safety", "clearance_min_m"))
        return (not r["exception"], not r["non_finite"], not r["crashed"], int(r["collisions"]) == 0,
                not cl < d_min, bool(r["mission_complete"]), cov if math.isfinite(cov) else -1.0,
                sm if math.isfinite(sm) else -1.0, cl if math.isfinite(cl) else -1.0, r["episode"])
    return sorted(rows, key=key)[:n]


def worst_by_metric(rows: Sequence[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """Per metric of :data:`METRICS`, the episode with its worst finite value."""
    out = {}
    for col, _label, _unit, _scale, worse in METRICS:
        ok = [r for r in rows if math.isfinite(num(r[col]))]
        if ok:
            out[col] = (min if worse == "low" else max)(ok, key=lambda r, c=col: num(r[c]))
    return out


def _num_arg(v: float) -> str:
    return repr(float(v))   # round-trips exactly: the re-fly's floats equal the campaign's


def refly_command(cfg: CampaignConfig, episode: int, out: str | os.PathLike) -> str:
    """The command that flies episode ``episode`` of this campaign again, alone, into
    ``out/refly-<episode>``: the same options, so the same draw, run spec and run-file name
    (``--only``); it reproduces the episode's numbers (``tests/cli/test_campaign.py`` checks it
    bit for bit on the trajectory)."""
    args = ["wt-inspect", "campaign", "--controller", cfg.controller, "--seed", str(cfg.seed),
            "--episodes", str(cfg.episodes), "--task", cfg.task, "--max-wind", _num_arg(cfg.max_wind),
            "--max-offset", _num_arg(cfg.max_offset), "--record-every", str(cfg.record_every)]
    if cfg.max_time is not None:
        args += ["--max-time", _num_arg(cfg.max_time)]
    if not cfg.airframe_randomization:
        args.append("--no-airframe-randomization")
    args += ["--only", str(episode), "--jobs", "1", "--out", os.path.join(str(out), f"refly-{episode}")]
    return " ".join(shlex.quote(a) for a in args)


def fmt(v: Any, scale: float = 1.0, digits: int = 2) -> str:
    """``v`` x ``scale`` with ``digits`` decimals, ``-`` when it is not a finite number."""
    f = num(v)
    return f"{scale * f:.{digits}f}" if math.isfinite(f) else "-"
