"""``wt-inspect campaign``: a robustness campaign - many randomised episodes of one controller.

Example (the README's robustness goal; hours on 2 cores)::

    wt-inspect campaign --episodes 200 --controller vtnmpc-plus --out results/campaign [--ray]

Each episode draws, from one master seed (``--seed``, through ``gymnasium.utils.seeding.np_random``):
a turbine (tower height, blade length and width within :data:`SIZE_RANGES`), a rotor azimuth in
[0, 120) deg with the planner choosing the rotor turns (``rotor_turn_deg=None``), a mean wind in
[0, ``--max-wind``] m/s with Dryden turbulence from a random horizontal direction within 45 deg of
the rotor axis, a start up to ``--max-offset`` m off the ideal stand-off pose (a random direction
with no downward part, so a start is not under ground; a start nearer the turbine than 3/7 d_ref -
inside or against the structure - gets a new direction, ``START_CLEARANCE_RATIO``), and the
episode's reset seed. Every
episode runs through the evaluation harness's backends (the local process pool or Ray, as
``evaluate``) and is recorded: a row of ``episodes.csv`` and its trajectory in
``runs/<name>.npz`` (the evaluation's run-file format). An exception in an episode - building
the turbine, planning, the controller, the simulator - is caught in that episode and recorded
with its message; the campaign goes on.

Reported per episode and in total (``results.md``, ``campaign.json``, ``campaign.png``):
crashes (collision or leaving the working volume), exceptions, non-finite states, collisions,
QP fallbacks per step (``last_stats.fallback`` of the MPC), and memory (the worker's resident set
size after each episode, to show it stays flat). Exit code 0 when the campaign ran (whatever it
found), 2 for bad arguments or an unwritable ``--out``, 130 when interrupted.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import os
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from wt_inspect_env.atomic_io import write_text_atomic
from wt_inspect_env.interrupts import EXIT_INTERRUPTED, interrupted_message, interrupts_deferred, interrupts_raise
from wt_inspect_env.wind import MAX_WIND_SPEED

from ..evaluation import OutputDirError, prepare_out_dir, registry, resume_runs
from ..evaluation.backends import BACKENDS, check_jobs, run_specs
from ..evaluation.runner import RunResult, RunSpec, fly, make_env, make_spec, save_run

SCENARIO = "campaign"
# [lo, hi] of the drawn turbine dimensions [m]: around the paper's V100 (tower 95 m, blades
# 49 m x 4 m) down to a small 2 MW class machine.
SIZE_RANGES: Mapping[str, tuple[float, float]] = {"tower_height": (80.0, 130.0), "blade_length": (35.0, 60.0),
                                                  "blade_width": (2.5, 4.5)}
MAX_DIRECTION_DEG = 45.0   # wind direction: within this of the rotor axis (the paper's wind along it)
# A drawn start nearer the turbine than this fraction of d_ref (the MPCs' default d_min, 3 m at 7 m)
# is a start inside or against the structure - a bad draw, not a test of the controller: its
# direction is redrawn (same distance) from a generator seeded by the episode's seed.
START_CLEARANCE_RATIO = 3.0 / 7.0
MAX_START_REDRAWS = 100
# Upper bound of --episodes: every episode's draw and run spec is made before the first flies
# (so a campaign resumes and its report knows what is missing), a few kB each. 10 000 episodes
# are weeks of flight on a workstation, far beyond the README's 200; a larger number is a typo
# (10**12 would grow memory for hours before the first episode).
MAX_EPISODES = 10_000
RSS_WARMUP_EPISODES = 20   # a worker's first episodes compile solvers and fill caches: memory grows, then holds
COLUMNS = ("episode", "seed", "wind", "wind_direction_deg", "tower_height", "blade_length", "blade_width",
           "rotor_azimuth_deg", "start_offset_m", "start_redraws", "termination", "crashed", "exception", "non_finite",
           "collisions", "steps", "fallback_steps", "fallback_fraction", "coverage", "safety", "centering",
           "min_distance", "clearance_min_m", "time_below_d_min_s", "energy_wh", "path_length", "sim_time",
           "wall_time", "rss_mb", "worker", "run_file", "error")


@dataclass(frozen=True)
class CampaignConfig:
    """What a campaign draws and flies (the command-line options)."""

    episodes: int = 200
    controller: str = "vtnmpc-plus"
    seed: int = 0
    task: str = "full"
    max_wind: float = 10.0
    max_offset: float = 30.0
    max_time: float | None = None
    record_every: int = 10

    def __post_init__(self) -> None:
        for name in ("episodes", "seed", "record_every"):
            v = getattr(self, name)
            lo = 0 if name == "seed" else 1
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if self.episodes > MAX_EPISODES:
            raise ValueError(f"episodes must be at most {MAX_EPISODES:,} (every draw is planned before the first "
                             f"episode flies; split a larger study into campaigns with other --seed), "
                             f"got {self.episodes!r}")
        for name, hi in (("max_wind", MAX_WIND_SPEED), ("max_offset", 1000.0)):
            v = getattr(self, name)
            if isinstance(v, (bool, str)) or not isinstance(v, (int, float)) or not 0 <= v <= hi:
                raise ValueError(f"{name} must be a number in [0, {hi:g}], got {v!r}")
        if self.max_time is not None and (isinstance(self.max_time, (bool, str))
                                          or not isinstance(self.max_time, (int, float)) or not self.max_time > 0):
            raise ValueError(f"max_time must be a positive number of simulated seconds, got {self.max_time!r}")
        if self.task not in ("full", "blade", "surface"):
            raise ValueError(f"unknown task {self.task!r}; valid: full, blade, surface")


def draw_episodes(cfg: CampaignConfig) -> list[dict[str, Any]]:
    """The episodes' random draws (plain data), all from the master seed: the same seed gives
    the same campaign, and episode k does not depend on how many episodes follow it."""
    from gymnasium.utils.seeding import np_random
    rng, _ = np_random(cfg.seed)
    out = []
    for k in range(cfg.episodes):
        sizes = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in SIZE_RANGES.items()}
        azimuth = float(rng.uniform(0.0, 120.0))
        wind = float(rng.uniform(0.0, cfg.max_wind))
        direction_deg = float(rng.uniform(-MAX_DIRECTION_DEG, MAX_DIRECTION_DEG))
        r = float(rng.uniform(0.0, cfg.max_offset))
        v = rng.normal(size=3)
        v[2] = abs(v[2])
        offset = (r * v / max(float(np.linalg.norm(v)), 1e-12)).tolist()
        seed = int(rng.integers(0, 2**31 - 1))
        out.append({"episode": k, "seed": seed, "wind": wind, "wind_direction_deg": direction_deg,
                    "rotor_azimuth_deg": azimuth, "start_offset": offset, "start_offset_m": r, **sizes})
    return out


def episode_options(draw: Mapping[str, Any], task: str) -> dict[str, Any]:
    """The ``gym.make`` options of one drawn episode (the turbine faces +y: wind direction is
    measured from it)."""
    a = math.radians(draw["wind_direction_deg"])
    wind: Any = "none" if draw["wind"] <= 0.0 else {
        "type": "dryden", "mean_speed": draw["wind"], "direction": [math.sin(a), math.cos(a), 0.0]}
    return {"task": task, "wind": wind, "rotor_turn_deg": None, "start_offset": list(draw["start_offset"]),
            "turbine": {"tower_height": draw["tower_height"], "blade_length": draw["blade_length"],
                        "blade_width": draw["blade_width"], "rotor_azimuth_deg": draw["rotor_azimuth_deg"]}}


class _FallbackCounter:
    """Wraps a policy: counts the steps whose ``last_stats.fallback`` is set (an MPC step whose
    QP failed and whose command came from the shifted plan or hover)."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy
        self.fallbacks = 0
        self.steps = 0

    @property
    def last_stats(self) -> Any:
        return getattr(self.policy, "last_stats", None)

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed=seed)

    def act(self, obs: Any) -> np.ndarray:
        action = self.policy.act(obs)
        self.steps += 1
        if bool(getattr(self.last_stats, "fallback", False)):
            self.fallbacks += 1
        return action


def clear_start(env: Any, spec: RunSpec) -> tuple[list[float], int]:
    """The episode's start offset with its start at least ``START_CLEARANCE_RATIO * d_ref`` from
    the turbine: the drawn one, or the first of up to ``MAX_START_REDRAWS`` directions redrawn
    (same length, no downward part) that is. Returns the offset and the number of redraws."""
    from wt_inspect_env.proximity import MeshProximity
    u = env.unwrapped
    near = MeshProximity(u.mission.turbines[0].mesh.triangles)   # the start's rotor position only
    need = START_CLEARANCE_RATIO * float(u.config.standoff)
    offset = np.asarray(spec.env_options.get("start_offset", (0.0, 0.0, 0.0)), dtype=float)
    r = float(np.linalg.norm(offset))
    rng = np.random.default_rng(spec.seed)
    for k in range(MAX_START_REDRAWS + 1):
        u.reset(seed=spec.seed, options={"start_offset": offset.tolist()})
        if float(near.distance(u.sim.state[0:1, 0:3])[0]) >= need:
            return offset.tolist(), k
        v = rng.normal(size=3)
        v[2] = abs(v[2])
        offset = r * v / max(float(np.linalg.norm(v)), 1e-12)
    raise RuntimeError(f"no start {r:.1f} m off the first pose is {need:.1f} m clear of the turbine "
                       f"after {MAX_START_REDRAWS} directions")


def run_episode(spec: RunSpec, factory: Any = None, *, record: bool = True, progress: Any = None) -> RunResult:
    """One campaign episode (the backends' ``task``): build, fly, count fallbacks, measure RSS;
    any exception is caught and returned as the episode's result (``termination="exception"``,
    the message in ``metrics["error"]``) so that one failing episode does not end the campaign."""
    from wt_inspect_env.process_memory import release_free_heap, rss_mb
    t0 = time.perf_counter()
    env = None
    counter = None
    try:
        env = make_env(spec.env_options)
        offset, redraws = clear_start(env, spec)
        if redraws:
            env.close()
            env = make_env({**spec.env_options, "start_offset": offset})
        policy = registry.resolve(spec.controller)(env.unwrapped)
        counter = _FallbackCounter(policy)
        res = fly(env, counter, spec, record=record, progress=progress)
        res.solve["fallback_steps"] = float(counter.fallbacks)
        res.solve["start_redraws"] = float(redraws)
    except Exception as exc:   # the campaign records every failure and goes on
        where = traceback.extract_tb(exc.__traceback__)[-1]
        msg = f"{type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''} " \
              f"({Path(where.filename).name}:{where.lineno})"
        res = RunResult(spec=spec, metrics={"error": msg}, termination="exception", mission_complete=False,
                        steps=counter.steps if counter else 0, sim_time_s=math.nan,
                        wall_time_s=time.perf_counter() - t0,
                        solve={"fallback_steps": float(counter.fallbacks) if counter else math.nan},
                        d_ref=math.nan, safety_margin=math.nan)
    finally:
        if env is not None:
            env.close()
    release_free_heap()   # freed episode memory back to the OS: RSS then measures what is still held
    res.solve["rss_mb"] = rss_mb()
    res.solve["worker_pid"] = float(os.getpid())   # memory is per worker process
    return res


def _row(draw: Mapping[str, Any], res: RunResult) -> dict[str, Any]:
    m = res.metrics
    term = res.termination or ""
    fb = res.solve.get("fallback_steps", math.nan)
    return {**{k: draw[k] for k in ("episode", "seed", "wind", "wind_direction_deg", "tower_height", "blade_length",
                                    "blade_width", "rotor_azimuth_deg", "start_offset_m")},
            "start_redraws": int(res.solve.get("start_redraws", 0) or 0),
            "termination": term, "crashed": term in ("collision", "left_working_volume"),
            "exception": term == "exception", "non_finite": term == "non_finite_state",
            "collisions": m.get("collisions", 0) or 0, "steps": res.steps, "fallback_steps": fb,
            "fallback_fraction": fb / res.steps if res.steps else math.nan,
            "coverage": m.get("coverage", math.nan), "safety": m.get("safety_sm", math.nan),
            "centering": m.get("centering_cm", math.nan), "min_distance": m.get("min_distance_m", math.nan),
            "clearance_min_m": m.get("clearance_min_m", math.nan),
            "time_below_d_min_s": m.get("time_below_d_min_s", math.nan), "energy_wh": m.get("energy_wh", math.nan),
            "path_length": m.get("path_length_m", math.nan),
            "sim_time": res.sim_time_s, "wall_time": res.wall_time_s, "rss_mb": res.solve.get("rss_mb", math.nan),
            "worker": int(res.solve.get("worker_pid", 0) or 0), "run_file": res.path.name if res.path else "", "error": m.get("error", "")}


def summarise(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Totals of a campaign (the README's goal: 0 exceptions, 0 non-finite states, fallbacks
    below 0.1 % of steps, memory flat)."""
    n = len(rows)
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
            "steps": steps, "fallback_steps": fb, "fallback_fraction": fb / steps if steps else math.nan,
            "rss_first_mb": rss[0] if rss else math.nan, "rss_last_mb": rss[-1] if rss else math.nan,
            "rss_max_mb": max(rss) if rss else math.nan, "rss_slope_mb_per_episode": slope,
            "rss_slope_after_warmup_mb_per_episode": max(late) if late else math.nan,
            "start_redraws": sum(int(r.get("start_redraws", 0) or 0) for r in rows),
            "wall_time_per_episode_s": float(np.mean(wall)) if wall else math.nan,
            "terminations": {t: sum(r["termination"] == t for r in rows) for t in sorted({r["termination"] for r in rows})}}


def _markdown(cfg: CampaignConfig, summary: Mapping[str, Any], rows: Sequence[Mapping[str, Any]],
              command: str, wall: float, wall_total: float | None = None, n_planned: int | None = None) -> str:
    s = summary
    n_planned = s["episodes"] if n_planned is None else n_planned
    count = (f"{s['episodes']} episodes" if s["episodes"] >= n_planned
             else f"{s['episodes']} of {n_planned} episodes, incomplete")
    lines = [f"# Robustness campaign: {cfg.controller}, {count}", "",
             f"`{command}`" if command else "", ""]
    if s["episodes"] < n_planned:
        lines += [f"**Incomplete: {s['episodes']} of {n_planned} episodes finished** (rerun the same command to "
                  "resume).", ""]
    lines += [
             f"Task `{cfg.task}`, master seed {cfg.seed}; turbines tower {SIZE_RANGES['tower_height']} m, blades "
             f"{SIZE_RANGES['blade_length']} x {SIZE_RANGES['blade_width']} m, rotor azimuth [0, 120) deg with the "
             f"planner's rotor turns; Dryden wind, mean [0, {cfg.max_wind:g}] m/s within {MAX_DIRECTION_DEG:g} deg "
             f"of the rotor axis; starts up to {cfg.max_offset:g} m off the stand-off pose"
             + (f"; episodes capped at {cfg.max_time:g} simulated s" if cfg.max_time else "") + ".", "",
             "| measure | value | goal |", "|---|---:|---|",
             f"| exceptions | {s['exceptions']} | 0 |",
             f"| non-finite states | {s['non_finite_states']} | 0 |",
             f"| crashes (collision / left the working volume) | {s['crashes']} | - |",
             f"| episodes with a collision | {s['episodes_with_collisions']} | - |",
             f"| missions completed | {s['mission_complete']} | - |",
             f"| QP fallbacks | {s['fallback_steps']:.0f} of {s['steps']} steps ({100 * s['fallback_fraction']:.4f} %) "
             f"| < 0.1 % |",
             f"| worker memory (RSS after each episode) | {s['rss_first_mb']:.1f} -> {s['rss_last_mb']:.1f} MB, max "
             f"{s['rss_max_mb']:.1f}, largest slope of a worker {s['rss_slope_mb_per_episode']:+.3f} MB/episode "
             f"({s['rss_slope_after_warmup_mb_per_episode']:+.3f} after its first {RSS_WARMUP_EPISODES}) | flat |",
             f"| starts redrawn (drawn within {START_CLEARANCE_RATIO:.2f} d_ref of the turbine) | {s['start_redraws']} "
             "| - |",
             f"| wall time | {wall_total if wall_total is not None else wall:.1f} s over every invocation, "
             f"{wall:.1f} s in the last ({s['wall_time_per_episode_s']:.1f} s per episode in a worker) | - |", "",
             "Terminations: " + ", ".join(f"{k or 'none'} {v}" for k, v in s["terminations"].items()), "",
             "| # | wind | tower / blade | azimuth | offset | end | coverage | SM | min clearance | below d_min "
             "| energy | fallbacks | RSS | error |",
             "|---:|---:|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        lines.append(f"| {r['episode']} | {r['wind']:.1f} | {r['tower_height']:.0f} / {r['blade_length']:.0f} | "
                     f"{r['rotor_azimuth_deg']:.0f} | {r['start_offset_m']:.1f} | {r['termination']} | "
                     f"{100 * float(r['coverage']):.1f} | {100 * float(r['safety']):.1f} | "
                     f"{_num(r.get('clearance_min_m'), '{:.2f} m')} | {_num(r.get('time_below_d_min_s'), '{:.1f} s')} | "
                     f"{_num(r.get('energy_wh'), '{:.2f} Wh')} | {r['fallback_steps']:.0f} | "
                     f"{float(r['rss_mb']):.0f} | {str(r['error'])[:80]} |")
    return "\n".join(lines) + "\n"


def _num(v: Any, fmt: str) -> str:
    """``fmt`` of a finite number, ``-`` otherwise (an episode that raised, a run file from before
    the clearance and energy columns)."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "-"
    return fmt.format(f) if math.isfinite(f) else "-"


def _figure(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from wt_inspect_env.figure_io import save_and_close
    ep = np.array([r["episode"] for r in rows])
    fig, ax = plt.subplots(2, 2, figsize=(10, 7))
    bad = np.array([bool(r["exception"]) or bool(r["non_finite"]) or bool(r["crashed"]) for r in rows])
    wind = np.array([r["wind"] for r in rows])
    cov = np.array([float(r["coverage"]) for r in rows]) * 100
    ax[0, 0].scatter(wind[~bad], cov[~bad], s=14, label="flew")
    ax[0, 0].scatter(wind[bad], np.nan_to_num(cov[bad]), s=24, marker="x", c="r", label="crash / exception")
    ax[0, 0].set(xlabel="mean wind [m/s]", ylabel="coverage [%]", title="coverage")
    ax[0, 0].legend(fontsize=8)
    frac = np.array([float(r["fallback_fraction"]) for r in rows]) * 100
    ax[0, 1].bar(ep, np.nan_to_num(frac))
    ax[0, 1].axhline(0.1, color="r", lw=0.8, ls="--", label="goal 0.1 %")
    ax[0, 1].set(xlabel="episode", ylabel="QP fallbacks [% of steps]", title="fallbacks")
    ax[0, 1].legend(fontsize=8)
    for w in sorted({r["worker"] for r in rows}):
        mine = [r for r in rows if r["worker"] == w]
        ax[1, 0].plot([r["episode"] for r in mine], [float(r["rss_mb"]) for r in mine], ".-", label=f"worker {w}")
    ax[1, 0].legend(fontsize=8)
    ax[1, 0].set(xlabel="episode", ylabel="worker RSS [MB]", title="memory after each episode")
    off = [r["start_offset_m"] for r in rows]
    ax[1, 1].scatter(off, [float(r["min_distance"]) for r in rows], s=14, label="min distance to the point")
    ax[1, 1].scatter(off, [float(r.get("clearance_min_m", math.nan)) for r in rows], s=14, marker="^",
                     label="min clearance to the turbine")
    from wt_inspect.evaluation.harness_metrics import D_MIN_RATIO
    from wt_inspect_env.env_config import EnvConfig
    d_min = D_MIN_RATIO * EnvConfig().standoff     # the episodes fly the default stand-off
    ax[1, 1].axhline(d_min, color="r", lw=0.8, ls="--", label=f"d_min = {d_min:g} m")
    ax[1, 1].legend(fontsize=8)
    ax[1, 1].set(xlabel="start offset [m]", ylabel="distance [m]", title="start, distance and clearance")
    fig.tight_layout()
    return save_and_close(fig, path)


def run_campaign(cfg: CampaignConfig, out: str | Path, *, backend: str = "local", jobs: int | None = None,
                 address: str | None = None, progress: bool = True, figure: bool = True,
                 command: str = "") -> dict[str, Any]:
    """Draw and fly the campaign, write ``episodes.csv``, ``campaign.json``, ``results.md``,
    ``campaign.png`` and the run files into ``out``; returns the JSON document. Finished episodes'
    run files in ``out/runs`` are reused (same draw and code inputs -> same file name)."""
    t0 = time.perf_counter()
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    jobs = check_jobs(jobs)
    registry.check_controller(cfg.controller)
    draws = draw_episodes(cfg)
    specs = []
    for d in draws:
        specs.append(make_spec(SCENARIO, cfg.controller, d["wind"], d["seed"], episode_options(d, cfg.task),
                               cfg.max_time, cfg.record_every))
    out_dir = prepare_out_dir(out)
    with interrupts_raise():   # SIGTERM = Ctrl-C in every phase, whatever the backend and jobs
        return _fly_campaign(cfg, out_dir, specs, draws, t0=t0, backend=backend, jobs=jobs, address=address,
                             progress=progress, figure=figure, command=command)


def _fly_campaign(cfg: CampaignConfig, out_dir: Path, specs: list[RunSpec], draws: list[dict[str, Any]], *,
                  t0: float, backend: str, jobs: int, address: str | None, progress: bool, figure: bool,
                  command: str) -> dict[str, Any]:
    by_file = {s.filename: d for s, d in zip(specs, draws)}
    earlier_wall = _earlier_wall_time(out_dir / "campaign.json", cfg)
    results, todo = resume_runs(out_dir / "runs", specs,
                                warn=lambda m: print(f"warning: {m}", file=sys.stderr))

    def finished(res: RunResult) -> None:
        if res.arrays:
            try:
                save_run(res, out_dir / "runs" / res.spec.filename)
            except OSError as exc:
                raise OutputDirError(f"cannot write run file in {str(out_dir / 'runs')!r}: {exc.strerror or exc}; "
                                     "finished episodes are kept - rerun the same command to resume") from None
            res.arrays = {}
        results[res.spec.filename] = res

    try:
        if todo:
            run_specs(backend, todo, finished, jobs=jobs, address=address, progress=progress, task=run_episode)
    except BaseException:   # interrupted (or failed): the report of the finished episodes, uncut by a second signal
        with interrupts_deferred(raise_noted=False), contextlib.suppress(OSError, ValueError):
            _report(cfg, out_dir, specs, draws, by_file, results, t0=t0, earlier_wall=earlier_wall, figure=False,
                    command=command)
        raise
    return _report(cfg, out_dir, specs, draws, by_file, results, t0=t0, earlier_wall=earlier_wall, figure=figure,
                   command=command)


def _report(cfg: CampaignConfig, out_dir: Path, specs: list[RunSpec], draws: list[dict[str, Any]],
            by_file: Mapping[str, Any], results: Mapping[str, RunResult], *, t0: float, earlier_wall: float,
            figure: bool, command: str) -> dict[str, Any]:
    """episodes.csv, campaign.json, results.md (all atomic) and campaign.png of the finished episodes."""
    rows = [_row(by_file[s.filename], results[s.filename]) for s in specs if s.filename in results]
    summary = summarise(rows)
    wall = time.perf_counter() - t0
    doc = {"format": "wt-inspect-campaign/1", "config": cfg.__dict__, "command": command,
           "complete": len(rows) == len(specs), "episodes_planned": len(specs), "wall_time_s": wall,
           "wall_time_total_s": earlier_wall + wall, "summary": summary,
           "episodes": rows, "draws": draws}
    try:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(out_dir / "episodes.csv", buf.getvalue())
        write_text_atomic(out_dir / "campaign.json", json.dumps(doc, indent=1, default=float) + "\n")
        write_text_atomic(out_dir / "results.md", _markdown(cfg, summary, rows, command, wall,
                                                            earlier_wall + wall, n_planned=len(specs)))
        if figure and rows:
            doc["figure"] = str(_figure(rows, out_dir / "campaign.png"))
    except OSError as exc:
        raise OutputDirError(f"cannot write the campaign results to {str(out_dir)!r}: "
                             f"{exc.strerror or exc}") from None
    return doc


def _earlier_wall_time(path: Path, cfg: CampaignConfig) -> float:
    """Wall time of the earlier invocations of the same campaign in ``out`` (0 for a new one), so
    a resumed campaign reports its whole cost, not only its last invocation's."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return 0.0
    if not isinstance(doc, dict) or doc.get("config") != json.loads(json.dumps(cfg.__dict__, default=float)):
        return 0.0
    v = doc.get("wall_time_total_s", doc.get("wall_time_s", 0.0))
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) and v >= 0 else 0.0


def build_parser(prog: str) -> argparse.ArgumentParser:
    d = CampaignConfig()
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=d.episodes, help=f"(default {d.episodes})")
    ap.add_argument("--controller", default=d.controller, help=f"a registered controller (default {d.controller})")
    ap.add_argument("--out", required=True, metavar="DIR")
    ap.add_argument("--seed", type=int, default=d.seed, help="master seed of every draw (default 0)")
    ap.add_argument("--task", default=d.task, choices=["full", "blade", "surface"], help="(default full)")
    ap.add_argument("--max-wind", type=float, default=d.max_wind, metavar="M/S", help="(default 10)")
    ap.add_argument("--max-offset", type=float, default=d.max_offset, metavar="M", help="start offset (default 30)")
    ap.add_argument("--max-time", type=float, metavar="S", help="cap each episode at S simulated seconds")
    ap.add_argument("--record-every", type=int, default=d.record_every, metavar="K",
                    help=f"keep every K-th step in the trajectory files (default {d.record_every})")
    ap.add_argument("--backend", default="local", choices=BACKENDS)
    ap.add_argument("--ray", action="store_true", help="same as --backend ray")
    ap.add_argument("--address", help="Ray cluster address (default: a local instance)")
    ap.add_argument("--jobs", type=int, metavar="N", help="parallel episodes (default: the number of cores)")
    ap.add_argument("--no-figure", action="store_true")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def main(argv: list[str], prog: str = "wt-inspect campaign") -> int:
    with interrupts_raise():   # SIGTERM = Ctrl-C from the start, whatever --jobs
        return _main(argv, prog)


def _main(argv: list[str], prog: str) -> int:
    args = build_parser(prog).parse_args(argv)
    from ..evaluation import command_line
    backend = "ray" if args.ray else args.backend
    try:
        cfg = CampaignConfig(episodes=args.episodes, controller=args.controller, seed=args.seed, task=args.task,
                             max_wind=args.max_wind, max_offset=args.max_offset, max_time=args.max_time,
                             record_every=args.record_every)
        doc = run_campaign(cfg, args.out, backend=backend, jobs=args.jobs, address=args.address,
                           progress=not args.no_progress, figure=not args.no_figure,
                           command=command_line(argv, prog))
    except ValueError as exc:   # OutputDirError included
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"\n{prog}: {interrupted_message(exc, args.out, 'episodes', 'results.md, episodes.csv and campaign.json')}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    s = doc["summary"]
    print(f"{s['episodes']} episodes in {doc['wall_time_s']:.0f} s: {s['exceptions']} exceptions, "
          f"{s['non_finite_states']} non-finite states, {s['crashes']} crashes, {s['episodes_with_collisions']} with "
          f"collisions, QP fallbacks {100 * s['fallback_fraction']:.4f} % of {s['steps']} steps, RSS "
          f"{s['rss_first_mb']:.0f} -> {s['rss_last_mb']:.0f} MB; wrote {args.out}/results.md, campaign.json, "
          "episodes.csv")
    return 0
