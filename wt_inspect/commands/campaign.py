"""``wt-inspect campaign``: a robustness campaign - many randomised whole missions of one or several controllers.

Example (the README's robustness goal; hours on 2 cores)::

    wt-inspect campaign --episodes 200 --controllers vtnmpc-plus,ppo:ppo_full_vec128 --out results/campaign

Each episode is flown to the mission's end or its time limit (the environment's, 1.5 x the
nominal mission time + 30 s); ``--max-time S`` caps it at S simulated seconds for quick runs.

Each episode draws, from one master seed (``--seed``, through ``gymnasium.utils.seeding.np_random``;
episode k's draw does not depend on the controller or on how many episodes follow it):

* a turbine (:data:`TURBINE_KINDS`): a generated one (tower height, blade length and width
  within :data:`SIZE_RANGES`, the paper's cuboid blade), the ``nrel-5mw`` preset as published, or
  the ``nrel-5mw`` scaled geometrically by a factor in :data:`NREL_SCALE_RANGE` (every length of
  the preset: tower, blade, hub, overhang, nacelle);
* a rotor azimuth in [0, 120) deg with the planner choosing the rotor turns (``rotor_turn_deg=None``);
* a mean wind in [0, ``--max-wind``] m/s with Dryden turbulence, from any horizontal direction
  (measured from the rotor axis, +y);
* a start up to ``--max-offset`` m off the ideal stand-off pose (a random direction with no
  downward part, so a start is not under ground; a start nearer the turbine than 3/7 d_ref -
  inside or against the structure - gets a new direction, ``START_CLEARANCE_RATIO``);
* the episode's reset seed, from which the environment draws the airframe's domain randomisation
  (:data:`AIRFRAME_RANDOMIZATION`: mass, inertia, drag, thrust, torque coefficient and motor lag
  of the plant; no sensor noise, no latency; ``--no-airframe-randomization`` switches it off).

Every episode runs through the evaluation harness's backends (the local process pool or Ray, as
``evaluate``) and is recorded: a row of ``episodes.csv`` and its trajectory in
``runs/<name>.npz`` (the evaluation's run-file format). An exception in an episode - building
the turbine, planning, the controller, the simulator - is caught in that episode and recorded
with its message; the campaign goes on.

Reported per episode (``episodes.csv``, ``campaign.json``): coverage, SM, CM, the minimum
clearance to the structure and the time below d_min (:mod:`~wt_inspect.evaluation.harness_metrics`),
the minimum distance to the inspection point, collisions, crashes, completion, QP fallbacks
(``last_stats.fallback`` of the MPC), the worker's resident set size after the episode, energy
and path length. ``results.md`` and ``campaign.png`` give the distribution of each metric and the
worst episodes, each with the exact command that flies that one episode again (``--only K``: the
same draw and run spec, so the same numbers). With several controllers (``--controllers a,b``)
each flies the same episodes into ``DIR/<controller>/`` and ``DIR/comparison.md`` (``.csv``,
``.json``, ``.png``) compares them. Wall time is summed over the invocations of a resumed
campaign (``wall_time_s``; each invocation's in ``wall_time_invocations_s``).

Exit code 0 when the campaign ran (whatever it found), 2 for bad arguments or an unwritable
``--out``, 130 when interrupted.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from wt_inspect_env.physics.wind import MAX_WIND_SPEED
from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.interrupts import EXIT_INTERRUPTED, interrupted_message, interrupts_deferred, interrupts_raise

from ..evaluation import OutputDirError, prepare_out_dir, registry, resume_runs
from ..evaluation.backends import BACKENDS, check_jobs, run_specs
from ..evaluation.runner import RunResult, RunSpec, exception_result, fly, make_env, make_spec, save_run

SCENARIO = "campaign"
FORMAT = "wt-inspect-campaign/2"   # /2: whole missions, NREL turbines, any wind direction, airframe DR, invocations
# [lo, hi] of the generated turbines' dimensions [m]: around the paper's V100 (tower 95 m, blades
# 49 m x 4 m) down to a small 2 MW class machine.
SIZE_RANGES: Mapping[str, tuple[float, float]] = {"tower_height": (80.0, 130.0), "blade_length": (35.0, 60.0),
                                                  "blade_width": (2.5, 4.5)}
# Turbine of an episode: a generated one (SIZE_RANGES, cuboid blades), the NREL 5-MW preset as
# published, or the preset scaled geometrically; drawn with these probabilities.
TURBINE_KINDS: Mapping[str, float] = {"generated": 0.5, "nrel-5mw": 0.15, "nrel-5mw-scaled": 0.35}
NREL_SCALE_RANGE = (0.6, 0.95)   # 0.6: 54 m hub, 37 m blades (tips 16 m above ground); 0.95: 85 m hub
# The preset's lengths that a scaled variant multiplies (its blade follows blade_length geometrically).
NREL_SCALED_LENGTHS = ("tower_height", "tower_radius", "tower_top_radius", "hub_radius", "overhang",
                       "nacelle_radius", "nacelle_length")
WIND_DIRECTION_RANGE_DEG = (-180.0, 180.0)   # any horizontal direction, from the rotor axis (+y)
# Domain randomisation of the airframe (the plant PyBullet integrates; the controllers keep the
# nominal model): the environment's default scale ranges, sensor noise and command latency off.
AIRFRAME_RANDOMIZATION: Mapping[str, Any] = {
    "mass": [0.9, 1.1], "inertia": [0.8, 1.2], "drag": [0.7, 1.3], "thrust": [0.95, 1.05],
    "torque_coeff": [0.8, 1.2], "motor_time_constant": [0.75, 1.25],
    "position_noise": [0.0, 0.0], "velocity_noise": [0.0, 0.0], "attitude_noise": [0.0, 0.0],
    "rate_noise": [0.0, 0.0], "latency_steps": [0, 0]}
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
WORST_SHOWN = 10           # worst episodes listed (with their re-fly commands) in results.md
DIFFER_SHOWN = 10          # episodes where the controllers differ most, in comparison.md
COLUMNS = ("episode", "seed", "turbine", "turbine_scale", "wind", "wind_direction_deg", "tower_height",
           "blade_length", "blade_width", "rotor_azimuth_deg", "start_offset_m", "start_redraws", "mass_factor",
           "thrust_factor", "termination", "mission_complete", "crashed", "exception", "non_finite", "collisions",
           "steps", "fallback_steps", "fallback_fraction", "coverage", "safety", "centering", "min_distance",
           "clearance_min_m", "clearance_body_min_m", "time_below_d_min_s", "stalls", "skipped_path_m",
           "energy_wh", "path_length", "sim_time", "wall_time", "rss_mb", "worker", "run_file", "error")
# The per-episode metrics whose distribution is reported: column, label, unit, scale, worse when
# ("low" / "high").
#: a safety filter's counts per episode (controllers.safety_filter; only for NAME+filter)
FILTER_FIELDS = ("filter_intervention_fraction", "filter_mean_correction", "filter_fallbacks", "filter_median_ms",
                 "filter_p99_ms")
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


@dataclass(frozen=True)
class CampaignConfig:
    """What a campaign draws and flies (the command-line options). ``only``: fly just these
    episode numbers of the campaign (same draws: a re-fly of single episodes)."""

    episodes: int = 200
    controller: str = "vtnmpc-plus"
    seed: int = 0
    task: str = "full"
    max_wind: float = 10.0
    max_offset: float = 30.0
    max_time: float | None = None
    record_every: int = 10
    airframe_randomization: bool = True
    only: tuple[int, ...] | None = None

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
        if not isinstance(self.airframe_randomization, bool):
            raise ValueError(f"airframe_randomization must be true or false, got {self.airframe_randomization!r}")
        if self.only is not None:
            bad = [k for k in self.only if isinstance(k, bool) or not isinstance(k, int)
                   or not 0 <= k < self.episodes]
            if bad or not self.only:
                raise ValueError(f"only must name episodes in [0, {self.episodes - 1}], got {list(self.only)!r}")
            object.__setattr__(self, "only", tuple(sorted(set(self.only))))


def _nrel_turbine(scale: float) -> dict[str, Any]:
    """TurbineSpec fields of the NREL 5-MW preset scaled by ``scale`` (1: the preset itself)."""
    if scale == 1.0:
        return {"preset": "nrel-5mw"}
    from wt_inspect_env.turbine.presets import NREL_5MW_HUB_RADIUS, NREL_5MW_TIP_RADIUS, get_turbine_preset
    preset = get_turbine_preset("nrel-5mw")
    return {"preset": "nrel-5mw", **{k: scale * float(preset[k]) for k in NREL_SCALED_LENGTHS},
            "blade_length": scale * (NREL_5MW_TIP_RADIUS - NREL_5MW_HUB_RADIUS)}


def draw_episodes(cfg: CampaignConfig) -> list[dict[str, Any]]:
    """The episodes' random draws (plain data), all from the master seed: the same seed gives
    the same campaign, episode k does not depend on how many episodes follow it, and nothing
    depends on the controller. Every episode takes the same number of variates (the sizes and the
    scale are drawn whichever turbine kind is used), which keeps the prefix property."""
    from gymnasium.utils.seeding import np_random
    rng, _ = np_random(cfg.seed)
    kinds = list(TURBINE_KINDS)
    cum = np.cumsum(list(TURBINE_KINDS.values()))
    out = []
    for k in range(cfg.episodes):
        sizes = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in SIZE_RANGES.items()}
        kind = kinds[min(int(np.searchsorted(cum, rng.uniform(0.0, cum[-1]), side="right")), len(kinds) - 1)]
        scale = float(rng.uniform(*NREL_SCALE_RANGE))
        azimuth = float(rng.uniform(0.0, 120.0))
        wind = float(rng.uniform(0.0, cfg.max_wind))
        direction_deg = float(rng.uniform(*WIND_DIRECTION_RANGE_DEG))
        r = float(rng.uniform(0.0, cfg.max_offset))
        v = rng.normal(size=3)
        v[2] = abs(v[2])
        offset = (r * v / max(float(np.linalg.norm(v)), 1e-12)).tolist()
        seed = int(rng.integers(0, 2**31 - 1))
        if kind == "generated":
            turbine, scale = dict(sizes), None
        else:
            scale = 1.0 if kind == "nrel-5mw" else scale
            turbine = _nrel_turbine(scale)
            sizes = {"tower_height": 90.0 * scale, "blade_length": 61.5 * scale, "blade_width": 4.652 * scale}
        out.append({"episode": k, "seed": seed, "turbine": kind, "turbine_scale": scale, "turbine_spec": turbine,
                    "wind": wind, "wind_direction_deg": direction_deg, "rotor_azimuth_deg": azimuth,
                    "start_offset": offset, "start_offset_m": r, **sizes})
    return out


def episode_options(draw: Mapping[str, Any], task: str, airframe_randomization: bool = True) -> dict[str, Any]:
    """The ``gym.make`` options of one drawn episode (the turbine faces +y: wind direction is
    measured from it)."""
    a = math.radians(draw["wind_direction_deg"])
    wind: Any = "none" if draw["wind"] <= 0.0 else {
        "type": "dryden", "mean_speed": draw["wind"], "direction": [math.sin(a), math.cos(a), 0.0]}
    opts = {"task": task, "wind": wind, "rotor_turn_deg": None, "start_offset": list(draw["start_offset"]),
            "turbine": {**draw["turbine_spec"], "rotor_azimuth_deg": draw["rotor_azimuth_deg"]}}
    if airframe_randomization:
        opts["randomization"] = dict(AIRFRAME_RANDOMIZATION)
    return opts


def campaign_specs(cfg: CampaignConfig) -> tuple[list[dict[str, Any]], list[RunSpec]]:
    """The draws and run specs of the episodes the campaign flies (all, or ``cfg.only``)."""
    registry.check_controller(cfg.controller)
    draws = draw_episodes(cfg)
    if cfg.only is not None:
        draws = [draws[k] for k in cfg.only]
    specs = [make_spec(SCENARIO, cfg.controller, d["wind"], d["seed"],
                       episode_options(d, cfg.task, cfg.airframe_randomization), cfg.max_time, cfg.record_every)
             for d in draws]
    return draws, specs


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

    @property
    def stats(self) -> Any:
        """A safety filter's counts (``NAME+filter``), for the run's report."""
        return getattr(self.policy, "stats", None)

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
    from wt_inspect_env.planner.proximity import MeshProximity
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
    from wt_inspect_env.util.process_memory import release_free_heap, rss_mb
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
        res.solve.update(_airframe_factors(env.unwrapped))
    except Exception as exc:   # the campaign records every failure and goes on
        res = exception_result(spec, exc, time.perf_counter() - t0, steps=counter.steps if counter else 0,
                               solve={"fallback_steps": float(counter.fallbacks) if counter else math.nan})
    finally:
        if env is not None:
            env.close()
    release_free_heap()   # freed episode memory back to the OS: RSS then measures what is still held
    res.solve["rss_mb"] = rss_mb()
    res.solve["worker_pid"] = float(os.getpid())   # memory is per worker process
    return res


def _airframe_factors(u: Any) -> dict[str, float]:
    """The plant's mass and mean rotor-thrust factors that the episode's domain randomisation drew
    (1 without it): what the airframe was, per episode, for the report."""
    plant, sim = u.sim.plants[0], u.sim
    return {"mass_factor": float(plant.mass / u.params.mass),
            "thrust_factor": float(np.mean(np.asarray(sim.thrust_scales[0], dtype=float)))}


def _row(draw: Mapping[str, Any], res: RunResult) -> dict[str, Any]:
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


def _f(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def distribution(values: Sequence[Any]) -> dict[str, float]:
    """``n`` (finite values), ``min``, ``p5``, ``median``, ``mean``, ``p95``, ``max`` of ``values``
    (NaN - an episode that raised - left out; all NaN when none is finite)."""
    v = np.array([_f(x) for x in values], dtype=float)
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
    d_min = _d_min() if d_min is None else d_min
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
            "clearance_below_d_min": sum(_f(r["clearance_min_m"]) < d_min for r in rows), "d_min_m": d_min,
            "episodes_with_stalls": sum(_f(r.get("stalls", math.nan)) > 0 for r in rows),
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


def _d_min() -> float:
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
    if _f(row["clearance_min_m"]) < d_min:
        out.append("clearance below d_min")
    if not row["exception"] and not row["crashed"] and not row["mission_complete"]:
        out.append("not completed" + (f" ({row['termination']})" if row["termination"] else ""))
    if _f(row.get("stalls", math.nan)) > 0:
        out.append(f"reference stalled {int(_f(row['stalls']))}x "
                   f"({_f(row.get('skipped_path_m', math.nan)):.0f} m skipped)")
    return out


def worst_episodes(rows: Sequence[Mapping[str, Any]], d_min: float, n: int = WORST_SHOWN) -> list[Mapping[str, Any]]:
    """The ``n`` worst episodes: exceptions, then crashes and collisions, clearance below d_min,
    missions not completed, then by coverage and SM (lowest first), then by clearance."""
    def key(r: Mapping[str, Any]) -> tuple:
        cov, sm, cl = (_f(r[c]) for c in ("coverage", "safety", "clearance_min_m"))
        return (not r["exception"], not r["non_finite"], not r["crashed"], int(r["collisions"]) == 0,
                not cl < d_min, bool(r["mission_complete"]), cov if math.isfinite(cov) else -1.0,
                sm if math.isfinite(sm) else -1.0, cl if math.isfinite(cl) else -1.0, r["episode"])
    return sorted(rows, key=key)[:n]


def worst_by_metric(rows: Sequence[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """Per metric of :data:`METRICS`, the episode with its worst finite value."""
    out = {}
    for col, _label, _unit, _scale, worse in METRICS:
        ok = [r for r in rows if math.isfinite(_f(r[col]))]
        if ok:
            out[col] = (min if worse == "low" else max)(ok, key=lambda r, c=col: _f(r[c]))
    return out


def _num_arg(v: float) -> str:
    return repr(float(v))   # round-trips exactly: the re-fly's floats equal the campaign's


def refly_command(cfg: CampaignConfig, episode: int, out: str | os.PathLike) -> str:
    """The command that flies episode ``episode`` of this campaign again, alone, into
    ``out/refly-<episode>``: the same options, so the same draw, run spec and run-file name
    (``--only``); it reproduces the episode's numbers (``tests/test_campaign.py`` checks it
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


def _fmt(v: Any, scale: float = 1.0, digits: int = 2) -> str:
    f = _f(v)
    return f"{scale * f:.{digits}f}" if math.isfinite(f) else "-"


def _conditions(r: Mapping[str, Any]) -> str:
    kind = r["turbine"] if r["turbine"] != "nrel-5mw-scaled" else f"nrel-5mw x{_f(r['turbine_scale']):.2f}"
    return (f"{kind} {_f(r['tower_height']):.0f}/{_f(r['blade_length']):.0f} m, az {_f(r['rotor_azimuth_deg']):.0f}, "
            f"wind {_f(r['wind']):.1f} m/s @ {_f(r['wind_direction_deg']):.0f} deg, "
            f"start {_f(r['start_offset_m']):.1f} m"
            f", mass x{_fmt(r.get('mass_factor'))}")


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
        f"| episodes whose reference stalled (moved on without the drone) | {s['episodes_with_stalls']} | 0 |",
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
        lines.append(f"| {label} [{unit}] | {d['n']} | " + " | ".join(_fmt(d[k], scale) for k in
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
                     f"{r['termination']} | {_fmt(r['coverage'], 100, 1)} | {_fmt(r['safety'], 100, 1)} | "
                     f"{_fmt(r['centering'], 100, 1)} | {_fmt(r['clearance_min_m'])} m | "
                     f"{_fmt(r['min_distance'])} m | {_fmt(r['energy_wh'])} Wh | {_fmt(r['fallback_steps'], 1, 0)} |")
    lines += [""]
    for r in worst:
        lines += [f"- episode {r['episode']}: `{refly_command(cfg, r['episode'], out)}`"]
    lines += ["", "## Every episode", "",
              "| # | turbine | wind | azimuth | offset | mass | end | coverage | SM | CM | clearance | below d_min "
              "| to point | energy | fallbacks | RSS | error |",
              "|---:|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        kind = r["turbine"] if r["turbine"] != "nrel-5mw-scaled" else f"nrel x{_f(r['turbine_scale']):.2f}"
        lines.append(f"| {r['episode']} | {kind} {_f(r['tower_height']):.0f}/{_f(r['blade_length']):.0f} | "
                     f"{_f(r['wind']):.1f} | {_f(r['rotor_azimuth_deg']):.0f} | {_f(r['start_offset_m']):.1f} | "
                     f"{_fmt(r.get('mass_factor'))} | {r['termination']} | {_fmt(r['coverage'], 100, 1)} | "
                     f"{_fmt(r['safety'], 100, 1)} | {_fmt(r['centering'], 100, 1)} | {_fmt(r['clearance_min_m'])} | "
                     f"{_fmt(r['time_below_d_min_s'], 1, 1)} | {_fmt(r['min_distance'])} | {_fmt(r['energy_wh'])} | "
                     f"{_fmt(r['fallback_steps'], 1, 0)} | {_fmt(r['rss_mb'], 1, 0)} | {str(r['error'])[:80]} |")
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
        v = np.array([_f(r[col]) for r in rows]) * scale
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
            ax.annotate(f"worst: #{w['episode']}", xy=(_f(w[col]) * scale, 0), xytext=(0, 14),
                        textcoords="offset points", fontsize=7, color="r", ha="center",
                        arrowprops={"arrowstyle": "->", "color": "r", "lw": 0.6})
        ax.set(xlabel=f"{label} [{unit}]", ylabel="episodes")
        ax.title.set_fontsize(8)
    ax = axes.flat[10]
    for w in sorted({r["worker"] for r in rows}):
        mine = [r for r in rows if r["worker"] == w]
        ax.plot([r["episode"] for r in mine], [_f(r["rss_mb"]) for r in mine], ".-", label=f"worker {w}")
    ax.set(xlabel="episode", ylabel="worker RSS [MB]", title="memory after each episode")
    ax.title.set_fontsize(8)
    ax = axes.flat[11]
    bad = np.array([bool(failures(r, d_min)) for r in rows])
    off = np.array([_f(r["start_offset_m"]) for r in rows])
    wind = np.array([_f(r["wind"]) for r in rows])
    ax.scatter(wind[~bad], off[~bad], s=12, label="completed, clear")
    ax.scatter(wind[bad], off[bad], s=20, marker="x", c="r", label="failed / short of the end")
    ax.set(xlabel="mean wind [m/s]", ylabel="start offset [m]", title="conditions")
    ax.title.set_fontsize(8)
    ax.legend(fontsize=7)
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
    draws, specs = campaign_specs(cfg)
    out_dir = prepare_out_dir(out)
    with interrupts_raise():   # SIGTERM = Ctrl-C in every phase, whatever the backend and jobs
        return _fly_campaign(cfg, out_dir, specs, draws, t0=t0, backend=backend, jobs=jobs, address=address,
                             progress=progress, figure=figure, command=command, out=str(out))


def _fly_campaign(cfg: CampaignConfig, out_dir: Path, specs: list[RunSpec], draws: list[dict[str, Any]], *,
                  t0: float, backend: str, jobs: int, address: str | None, progress: bool, figure: bool,
                  command: str, out: str) -> dict[str, Any]:
    by_file = {s.filename: d for s, d in zip(specs, draws)}
    earlier = earlier_invocations(out_dir / "campaign.json", cfg)
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

    kw = {"t0": t0, "earlier": earlier, "command": command, "out": out}
    try:
        if todo:
            run_specs(backend, todo, finished, jobs=jobs, address=address, progress=progress, task=run_episode)
    except BaseException:   # interrupted (or failed): the report of the finished episodes, uncut by a second signal
        with interrupts_deferred(raise_noted=False), contextlib.suppress(OSError, ValueError):
            _report(cfg, out_dir, specs, by_file, results, figure=False, **kw)
        raise
    return _report(cfg, out_dir, specs, by_file, results, figure=figure, **kw)


def _report(cfg: CampaignConfig, out_dir: Path, specs: list[RunSpec], by_file: Mapping[str, Any],
            results: Mapping[str, RunResult], *, t0: float, earlier: Sequence[float], figure: bool, command: str,
            out: str) -> dict[str, Any]:
    """episodes.csv, campaign.json, results.md (all atomic) and campaign.png of the finished episodes."""
    rows = [_row(by_file[s.filename], results[s.filename]) for s in specs if s.filename in results]
    d_min = _d_min()
    summary = summarise(rows, d_min)
    this = time.perf_counter() - t0
    walls = [*earlier, this]
    doc = {"format": FORMAT, "config": _config_json(cfg), "command": command,
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


def _config_json(cfg: CampaignConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=float))


def earlier_invocations(path: Path, cfg: CampaignConfig) -> list[float]:
    """Wall times [s] of the earlier invocations of the same campaign in ``out`` (none for a new
    one, or for another campaign's ``campaign.json``), so a resumed campaign reports its whole
    cost, not only its last invocation's. A format-/1 file gives its summed total as one entry."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(doc, dict) or doc.get("config") != _config_json(cfg):
        return []
    walls = doc.get("wall_time_invocations_s")
    if not isinstance(walls, list):
        walls = [doc.get("wall_time_total_s", doc.get("wall_time_s", 0.0))]
    ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 for v in walls)
    return [float(v) for v in walls] if ok else []


# ------------------------------------------------------------------ several controllers
def controller_dir(controller: str) -> str:
    """Sub-directory of one controller's campaign in a comparison (``ppo:x`` -> ``ppo-x``)."""
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in controller)


def run_comparison(cfg: CampaignConfig, controllers: Sequence[str], out: str | Path, *, backend: str = "local",
                   jobs: int | None = None, address: str | None = None, progress: bool = True,
                   figure: bool = True, command: str = "") -> dict[str, Any]:
    """The same campaign (same master seed: the same episodes) for each of ``controllers``, each
    into ``out/<controller_dir>``, then ``comparison.md``/``.csv``/``.json``/``.png`` in ``out``.
    Each campaign resumes on its own; controllers are checked before anything flies."""
    names = list(dict.fromkeys(controllers))
    if len(names) < 2:
        raise ValueError(f"a comparison needs at least two different controllers, got {list(controllers)!r}")
    for c in names:
        registry.check_controller(c)
    dirs = [controller_dir(c) for c in names]
    if len(set(dirs)) != len(dirs):
        raise ValueError(f"controllers {names!r} map to the same directory names {dirs!r}")
    out_dir = prepare_out_dir(out)
    with contextlib.suppress(OSError):   # the run files are in the controllers' directories
        (out_dir / "runs").rmdir()
    docs = {}
    for c, sub in zip(names, dirs):
        docs[c] = run_campaign(dataclasses.replace(cfg, controller=c), os.path.join(str(out), sub), backend=backend,
                               jobs=jobs, address=address, progress=progress, figure=figure, command=command)
    return write_comparison(cfg, docs, out_dir, str(out), command=command, figure=figure)


def _paired(docs: Mapping[str, Mapping[str, Any]]) -> list[int]:
    """Episodes every controller finished."""
    sets = [{r["episode"] for r in d["episodes"]} for d in docs.values()]
    return sorted(set.intersection(*sets)) if sets else []


def write_comparison(cfg: CampaignConfig, docs: Mapping[str, Mapping[str, Any]], out_dir: Path, out: str, *,
                     command: str = "", figure: bool = True) -> dict[str, Any]:
    """The comparison of the controllers' campaigns (``docs``: controller -> campaign.json)."""
    d_min = _d_min()
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
                  for v in [[_f(r[col]) for r in rs]]}
        cl = [_f(r["clearance_min_m"]) for r in rs]
        outcome_differs = len({(r["termination"], bool(failures(r, d_min))) for r in rs}) > 1
        score = (outcome_differs, spread["coverage"] + spread["safety"] + spread["centering"],
                 max(cl) - min(cl) if all(map(math.isfinite, cl)) else math.inf)
        differ.append((score, k))
    differ.sort(key=lambda x: (not x[0][0], -x[0][1], -x[0][2], x[1]))
    top = [k for _, k in differ[:DIFFER_SHOWN]]
    summaries = {c: summarise([rows[c][k] for k in paired], d_min) for c in names}
    doc = {"format": "wt-inspect-campaign-comparison/1", "config": _config_json(cfg), "controllers": names,
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
        _fmt(summaries[c]["fallback_fraction"], 100, 4) for c in names) + " |")
    lines.append("| wall time [s] | " + " | ".join(_fmt(docs[c]["wall_time_s"], 1, 0) for c in names) + " |")
    lines += ["", "Per metric: median [p5 - p95] (min - max) over the paired episodes.", "",
              "| metric | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for col, label, unit, scale, _worse in METRICS:
        cells = []
        for c in names:
            d = summaries[c]["distribution"][col]
            cells.append(f"{_fmt(d['median'], scale)} [{_fmt(d['p5'], scale)} - {_fmt(d['p95'], scale)}] "
                         f"({_fmt(d['min'], scale)} - {_fmt(d['max'], scale)})")
        lines.append(f"| {label} [{unit}] | " + " | ".join(cells) + " |")
    lines += ["", f"## Where they differ most ({len(top)} episodes)", "",
              "Ranked: a different outcome (termination, or one fails where another does not) first, then the "
              "spread of coverage + SM + CM, then of clearance. Cells: end, coverage / SM / CM [%], clearance [m].",
              "", "| # | conditions | " + " | ".join(names) + " |", "|---:|---|" + "---|" * len(names)]
    for k in top:
        r0 = rows[names[0]][k]
        cells = [f"{rows[c][k]['termination']}, {_fmt(rows[c][k]['coverage'], 100, 1)} / "
                 f"{_fmt(rows[c][k]['safety'], 100, 1)} / {_fmt(rows[c][k]['centering'], 100, 1)}, "
                 f"{_fmt(rows[c][k]['clearance_min_m'])}" for c in names]
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
        data = [np.array([_f(rows[c][k][col]) * scale for k in paired]) for c in names]
        ax.boxplot([d[np.isfinite(d)] for d in data], showfliers=False)
        for i, d in enumerate(data):
            ax.scatter(np.full(len(d), i + 1) + np.linspace(-0.15, 0.15, len(d)), d, s=8, alpha=0.6)
        if col == "clearance_min_m":
            ax.axhline(d_min, color="r", lw=0.8, ls="--")
        ax.set_xticks(range(1, len(names) + 1), names, fontsize=7)
        ax.set_title(f"{label} [{unit}]", fontsize=8)
    fig.tight_layout()
    return save_and_close(fig, path)


def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect campaign`` (defaults from :class:`CampaignConfig`)."""
    d = CampaignConfig()
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=d.episodes, help=f"(default {d.episodes})")
    ap.add_argument("--controller", help=f"a registered controller (default {d.controller})")
    ap.add_argument("--controllers", metavar="A,B,...",
                    help="comma-separated registered controllers (e.g. vtnmpc-plus,ppo:ppo_full_vec128): the same "
                         "episodes for each, into DIR/<controller>/, and DIR/comparison.md comparing them")
    ap.add_argument("--out", required=True, metavar="DIR")
    ap.add_argument("--seed", type=int, default=d.seed, help="master seed of every draw (default 0)")
    ap.add_argument("--task", default=d.task, choices=["full", "blade", "surface"], help="(default full)")
    ap.add_argument("--max-wind", type=float, default=d.max_wind, metavar="M/S", help="(default 10)")
    ap.add_argument("--max-offset", type=float, default=d.max_offset, metavar="M", help="start offset (default 30)")
    ap.add_argument("--max-time", type=float, metavar="S",
                    help="cap each episode at S simulated seconds (quick runs; default: no cap, every episode flies "
                         "to the mission's end or its time limit)")
    ap.add_argument("--no-airframe-randomization", action="store_true",
                    help="fly the nominal airframe (default: per-episode mass, inertia, drag, thrust, torque and "
                         "motor-lag draws)")
    ap.add_argument("--only", metavar="K,...",
                    help="fly only these episode numbers of the campaign (the re-fly commands in results.md)")
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
    """``wt-inspect campaign``: run (or resume) the campaign given by ``argv``; returns the exit code."""
    with interrupts_raise():   # SIGTERM = Ctrl-C from the start, whatever --jobs
        return _main(argv, prog)


def _int_list(text: str, what: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ValueError(f"{what} must be comma-separated episode numbers, got {text!r}") from None


def configs_from_args(args: argparse.Namespace) -> list[CampaignConfig]:
    """One campaign configuration per controller the parsed command line names, in its order
    (ValueError for a bad combination)."""
    if args.controller and args.controllers:
        raise ValueError("give --controller or --controllers, not both")
    controllers = ([c.strip() for c in args.controllers.split(",") if c.strip()] if args.controllers
                   else [args.controller or CampaignConfig().controller])
    if not controllers:
        raise ValueError(f"--controllers names no controller: {args.controllers!r}")
    only = _int_list(args.only, "--only") if args.only is not None else None
    return [CampaignConfig(episodes=args.episodes, controller=c, seed=args.seed, task=args.task,
                           max_wind=args.max_wind, max_offset=args.max_offset, max_time=args.max_time,
                           record_every=args.record_every, airframe_randomization=not args.no_airframe_randomization,
                           only=only) for c in controllers]


def _main(argv: list[str], prog: str) -> int:
    args = build_parser(prog).parse_args(argv)
    from ..evaluation import command_line
    backend = "ray" if args.ray else args.backend
    try:
        configs = configs_from_args(args)
        cfg = configs[0]
        controllers = [c.controller for c in configs]
        kw = {"backend": backend, "jobs": args.jobs, "address": args.address, "progress": not args.no_progress,
              "figure": not args.no_figure, "command": command_line(argv, prog)}
        if len(set(controllers)) > 1:
            cmp = run_comparison(cfg, controllers, args.out, **kw)
        else:
            doc = run_campaign(cfg, args.out, **kw)
    except ValueError as exc:   # OutputDirError included
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"\n{prog}: "
              f"{interrupted_message(exc, args.out, 'episodes', 'results.md, episodes.csv and campaign.json')}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    if len(set(controllers)) > 1:
        for c in cmp["controllers"]:
            print(f"{c}: {_summary_line(cmp['summary'][c])}")
        print(f"wrote {args.out}/comparison.md, comparison.csv, comparison.json and one directory per controller")
        return 0
    s = doc["summary"]
    print(f"{_summary_line(s)}; wall time {doc['wall_time_this_invocation_s']:.0f} s in this invocation, "
          f"{doc['wall_time_s']:.0f} s over {len(doc['wall_time_invocations_s'])}; wrote {args.out}/results.md, "
          "campaign.json, episodes.csv")
    return 0


def _summary_line(s: Mapping[str, Any]) -> str:
    cov = s["distribution"]["coverage"]
    return (f"{s['episodes']} episodes: {s['mission_complete']} completed, {s['exceptions']} exceptions, "
            f"{s['non_finite_states']} non-finite states, {s['crashes']} crashes, {s['episodes_with_collisions']} "
            f"with collisions, {s['clearance_below_d_min']} below d_min, median coverage "
            f"{_fmt(cov['median'], 100, 1)} %, QP fallbacks {100 * s['fallback_fraction']:.4f} % of {s['steps']} "
            f"steps, RSS {s['rss_first_mb']:.0f} -> {s['rss_last_mb']:.0f} MB")
