"""Behaviour digests: what decides whether a committed study is still what the code makes.

A hash of the source files makes every study stale on any refactor (a module moved, a duplicate
merged) although no flight changed. Instead, a study that flies records, in its
``provenance.json``, a *digest* of the flown state of a few of its runs: position and body-frame
velocity at every whole second of the first :data:`SECONDS` simulated seconds, rounded to
:data:`DECIMALS` decimals. ``wt-inspect reproduce --check`` flies that prefix of the same runs
again with the current code and calls the study current when every sample agrees within
:data:`TOLERANCE` - whatever files changed - or, for a run that misses, within :data:`NOISE_FACTOR`
times the spread of its noise twins (:func:`noise_envelope`: the same run from starts moved by
:data:`TWIN_OFFSETS_M`, for closed loops that amplify rounding).

Why these numbers: between machines of one kind, floating point differs in the last digits, and
over a whole 1,000 s mission a closed loop spreads that to the 5th-6th significant digit; over
the first 20 s it stays many orders below a millimetre. A behaviour change - a weight, a gain, an
option, the planner's path - moves the drone by centimetres within seconds. A tolerance of 2 mm
(and 2 mm/s) sits between the two. What a prefix cannot see is a change that acts only later in a
mission (e.g. at the rotor turn); the digests take the first and the last run of each study so
that different controllers, winds or rows are covered, and the full regeneration
(``wt-inspect reproduce --force``) remains the way to refresh a study's numbers.

The runs of a study are those its commands would fly, planned from the commands themselves with
the subcommands' own parsers (:func:`study_runs`); ``evaluate``, ``campaign``, ``ablation`` and
``study safety-filter`` / ``study pose-sweep`` fly runs here (``study imitation``: its expert on the
paper mission), and ``tune`` its first trial (the
controller's own weights). ``study planner-clearance`` flies nothing but plans: its digest is the
stand-off path of its first and last turbine (poses at 21 evenly spaced samples). ``train`` (PPO on
the vector env) digests the first update of its first and last seed (:mod:`agents.digest`: the
rollout, the reward, the update's statistics and the updated policy's actions). A study whose
commands fly nothing (analyses, cloning) has no digest; its staleness is decided by the code
version as before.
"""
from __future__ import annotations

import math
import shlex
from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

#: simulated seconds of each digested prefix
SECONDS = 20.0
#: rounding of the recorded samples [m, m/s]
DECIMALS = 4
#: largest difference of any sample for two digests to agree [m, m/s]
TOLERANCE = 2e-3
#: the starts of a run's *noise twins* move by these distances [m] in x, y and z (see
#: :func:`noise_envelope`): from a few hundred to a few million units in the last place of a
#: coordinate of tens of metres - at and above the rounding differences between machines, so that
#: a loop that switches on them (a solver's active set) switches in a twin too, and all far below
#: anything a controller could mean. Several, because how far one perturbation spreads is itself
#: a matter of chance: the envelope is the largest of them.
TWIN_OFFSETS_M = (1e-12, 1e-10, 1e-8)
#: a recorded digest that differs from the re-flight by less than this many times the twins'
#: largest divergence (at that sample or any earlier) still agrees: the difference is closed-loop noise
NOISE_FACTOR = 5.0


@dataclass(frozen=True)
class StudyRun:
    """One run a study's command flies: how to fly it (``runner``: ``"evaluate"`` for the
    harness's :func:`~wt_inspect.evaluation.runner.execute`, ``"campaign"`` for a campaign
    episode, ``"adversary"`` for a flight of ``wt-inspect study safety-filter``, ``"planner"`` for a
    planned path, ``"train"`` for a training run's first update) and its spec (a RunSpec, or a plain
    dict for the others)."""

    runner: str
    spec: Any

    def label(self) -> str:
        """How the run is named in the digest's table (scenario, controller, wind, seed; or the start)."""
        s = self.spec
        if isinstance(s, Mapping) and self.runner == "planner":
            return f"planned turbine {s['episode']} ({s['turbine']})"
        if isinstance(s, Mapping) and self.runner == "train":
            return f"training {s['recipe'] or 'default recipe'} seed {s['seed']} (first update)"
        if isinstance(s, Mapping):
            return f"adversarial start {s['start']}{' filtered' if s['filtered'] else ''}"
        return f"{s.scenario} {s.controller} wind {s.wind:g} seed {s.seed}"

    def spec_dict(self) -> dict[str, Any]:
        """The run's spec as plain data."""
        return dict(self.spec) if isinstance(self.spec, Mapping) else self.spec.to_dict()


def digest(t: np.ndarray, position: np.ndarray, velocity: np.ndarray, seconds: float = SECONDS) -> dict[str, Any]:
    """The digest of one trajectory: ``t`` (N,) simulated time, ``position`` and ``velocity``
    (N, 3), sampled at the first sample at or after each whole second 1 .. ``seconds`` that the
    trajectory reaches (a run that ended earlier, e.g. in a collision, gives fewer samples)."""
    t = np.asarray(t, dtype=float)
    marks = np.arange(1.0, math.floor(seconds) + 1.0)
    marks = marks[marks <= t[-1] + 1e-9] if len(t) else marks[:0]
    idx = np.searchsorted(t, marks - 1e-9)
    return {"t": [round(float(x), 6) for x in t[idx]],
            "position": np.round(np.asarray(position, dtype=float)[idx], DECIMALS).tolist(),
            "velocity": np.round(np.asarray(velocity, dtype=float)[idx], DECIMALS).tolist()}


#: units of the digested quantities, for the reader of a difference
_UNITS = {"position": " m", "velocity": " m/s"}


def compare(recorded: Mapping[str, Any], flown: Mapping[str, Any], tolerance: float = TOLERANCE,
            noise: Mapping[str, np.ndarray] | None = None) -> str:
    """Why two digests differ ("" when they agree): sample count, time or a state beyond
    ``tolerance`` - or beyond :data:`NOISE_FACTOR` times ``noise`` (per quantity and sample, from
    :func:`noise_envelope`) where that is larger - naming the first sample that differs and by how
    much."""
    n_rec, n_flown = len(recorded.get("t", [])), len(flown.get("t", []))
    if n_rec != n_flown:
        return f"{n_flown} samples flown, {n_rec} recorded (the run ends elsewhere)"
    for key in [k for k in recorded if k != "t"]:
        if key not in flown:
            return f"{key}: recorded, not produced"
        a, b = np.asarray(recorded[key], dtype=float), np.asarray(flown[key], dtype=float)
        if a.shape != b.shape:
            return f"{key}: shape {b.shape} flown, {a.shape} recorded"
        if not len(a):
            continue
        err = np.abs(a - b).max(axis=-1)
        allowed = np.full(len(err), tolerance)
        if noise is not None and key in noise and len(noise[key]) == len(err):
            allowed = np.maximum(allowed, NOISE_FACTOR * np.asarray(noise[key], dtype=float))
        bad = np.flatnonzero(~(err <= allowed))
        if len(bad):
            k = int(bad[0])
            unit = _UNITS.get(key, "")
            at = f" at t = {recorded['t'][k]:g} s" if k < len(recorded.get("t", [])) else ""
            return (f"{key}{at} differs by {err[k]:.4g}{unit} "
                    f"(tolerance {tolerance:g}; largest {np.nanmax(err):.4g}{unit})")
    return ""


# ------------------------------------------------------------------ which runs a command flies
def _evaluate_runs(argv: Sequence[str]) -> list[StudyRun]:
    from .evaluation import sweep_specs
    from .evaluation.cli import build_parser, resolve
    kw = resolve(build_parser("wt-inspect evaluate").parse_args(list(argv))).run_kwargs()
    controllers = kw["controllers"]
    if isinstance(controllers, str):
        controllers = [c.strip() for c in controllers.split(",") if c.strip()]
    specs = sweep_specs(kw["scenario"], list(dict.fromkeys(controllers)), kw["winds"], kw["seeds"],
                        wind_type=kw["wind_type"], wind_options=kw["wind_options"], turbine=kw["turbine"],
                        drone=kw["drone"], env_overrides=kw["env_overrides"], max_time=kw["max_time"],
                        record_every=kw["record_every"], trust_model=bool(kw["trust_model"]))
    return [StudyRun("evaluate", s) for s in specs]


def _campaign_runs(argv: Sequence[str]) -> list[StudyRun]:
    from .commands.campaign import build_parser, campaign_specs, configs_from_args
    configs = configs_from_args(build_parser("wt-inspect campaign").parse_args(list(argv)))
    once = {cfg.controller: cfg for cfg in configs}.values()     # a controller named twice flies once
    return [StudyRun("campaign", s) for cfg in once for s in campaign_specs(cfg)[1]]


def _ablation_runs(argv: Sequence[str]) -> list[StudyRun]:
    from .ablation import STEPS, TASK_SCENARIOS, _floats, build_parser, plan_rows
    from .evaluation import sweep_specs
    a = build_parser().parse_args(list(argv))
    scenario = TASK_SCENARIOS[a.task]
    return [StudyRun("evaluate", s) for row in plan_rows(STEPS[:a.rows] if a.rows else STEPS)
            for s in sweep_specs(scenario, sorted(set(row["controllers"].values())), _floats(a.winds), [0],
                                 env_overrides=row["env"], max_time=a.max_time)]


def _study_runs(argv: Sequence[str]) -> list[StudyRun]:
    """``wt-inspect study NAME ...``: the safety-filter and pose-sweep studies fly runs here."""
    if argv and argv[0] == "safety-filter":
        from .studies.safety_filter import planned_flights
        return [StudyRun("adversary", f) for f in planned_flights(list(argv[1:]))]
    if argv and argv[0] == "pose-sweep":
        from .studies.pose_sweep import planned_specs
        return [StudyRun("evaluate", s) for s in planned_specs(list(argv[1:]))]
    if argv and argv[0] == "planner-clearance":
        from .studies.planner_clearance import planned_draws
        return [StudyRun("planner", d) for d in planned_draws(list(argv[1:]))]
    if argv and argv[0] == "imitation":
        # the expert it imitates on the mission of its evaluations and hold check (the paper mission
        # in the 4 m/s gust): a change to the expert, the plant or the mission shows; one to the
        # learner's own code (cloning, DAgger) does not - nothing short of the study itself flies that
        from .demonstrations import DemoConfig
        from .evaluation import sweep_specs
        from .studies.imitation import build_parser
        expert = build_parser().parse_args(list(argv[1:])).expert or DemoConfig.expert
        return [StudyRun("evaluate", s) for s in sweep_specs("paper", [expert], [4.0], [0])]
    return []


def _tune_runs(argv: Sequence[str]) -> list[StudyRun]:
    """``wt-inspect tune``: its first trial, which flies the controller's own weights (all
    multipliers 1, enqueued before the sampler's), on each wind - the registered controller's
    evaluation run. The sampler's draws are Optuna's and not digested."""
    from .commands.tune import build_parser
    from .evaluation import sweep_specs
    a = build_parser("wt-inspect tune").parse_args(list(argv))
    return [StudyRun("evaluate", s) for s in sweep_specs(a.scenario, [a.controller], a.winds, [a.seed],
                                                         max_time=a.max_time)]


def _train_runs(argv: Sequence[str]) -> list[StudyRun]:
    """``wt-inspect train --algo ppo`` on the vector backend: one run per recipe and seed, each
    digested by its first update (:mod:`agents.digest`); cloning and DAgger runs have no digest."""
    from agents.seeds import parse_seeds
    from agents.train_cli import build_parser
    a = build_parser("wt-inspect train").parse_args(list(argv))
    if a.algo != "ppo" or a.backend != "vector" or a.timesteps is None:
        return []
    recipes = [r.strip() for r in str(a.recipe).split(",") if r.strip()] if a.recipe else [None]
    seeds = parse_seeds(a.seeds) if a.seeds is not None else [a.seed]
    return [StudyRun("train", {"algo": a.algo, "task": a.task or "surface", "n_envs": a.n_envs,
                               "timesteps": a.timesteps, "recipe": r, "seed": s, "trust_model": a.trust_model,
                               "resume": None if a.resume is None else a.resume.replace("{seed}", str(s))})
            for r in recipes for s in seeds]


_PLANNERS: dict[str, Callable[[Sequence[str]], list[StudyRun]]] = {
    "evaluate": _evaluate_runs, "campaign": _campaign_runs, "ablation": _ablation_runs, "study": _study_runs,
    "tune": _tune_runs, "train": _train_runs}


def study_runs(commands: Sequence[str]) -> list[StudyRun]:
    """Every run the ``wt-inspect`` commands fly, in their order (commands that fly nothing add
    none). ValueError (naming the command) if a flying command does not parse."""
    out: list[StudyRun] = []
    for command in commands:
        argv = shlex.split(command)[1:]
        if not argv or argv[0] not in _PLANNERS:
            continue
        try:
            out += _PLANNERS[argv[0]](argv[1:])
        except SystemExit:
            raise ValueError(f"cannot plan the runs of {command!r}: its arguments do not parse") from None
    return out


def digested_runs(commands: Sequence[str]) -> list[StudyRun]:
    """The runs of a study that carry its digest: the first and the last it flies (one if it flies
    one run, none if it flies none)."""
    runs = study_runs(commands)
    return [runs[0], runs[-1]] if len(runs) > 1 else runs


# ------------------------------------------------------------------ flying a prefix
def fly_prefix(run: StudyRun, seconds: float = SECONDS) -> dict[str, Any]:
    """Fly the first ``seconds`` of ``run`` with the current code (no file written) and return
    its digest. ValueError if the run raised (a campaign episode reports it in its result)."""
    if run.runner == "train":
        from agents.digest import first_update_digest
        return first_update_digest(**run.spec)
    if run.runner == "adversary":
        from .studies.safety_filter import trajectory
        return digest(*trajectory(run.spec, seconds), seconds)
    if run.runner == "planner":
        from .studies.planner_clearance import planned_path
        poses = planned_path(run.spec)
        # the planned path, not a flight: the stand-off pose at every SECONDS-th of the path (as
        # "position"; "t" the sample index, "velocity" zero) - a changed plan moves them by metres
        idx = np.linspace(0, len(poses) - 1, int(seconds) + 1).round().astype(int)
        return {"t": [float(i) for i in idx], "position": np.round(poses[idx], DECIMALS).tolist(),
                "velocity": np.zeros((len(idx), 3)).tolist()}
    spec = replace(run.spec, max_time=seconds if run.spec.max_time is None else min(seconds, run.spec.max_time),
                   record_every=1)
    if run.runner == "campaign":
        from .commands.campaign import run_episode
        res = run_episode(spec, record=True)
        if res.termination == "exception":
            raise ValueError(f"{run.label()}: {res.metrics.get('error')}")
    elif run.runner == "evaluate":
        from .evaluation.runner import execute
        res = execute(spec, record=True)
    else:
        raise ValueError(f"unknown runner {run.runner!r}; known: adversary, campaign, evaluate, planner, train")
    a = res.arrays
    return digest(a["t"], a["position"], a["velocity_body"], seconds)


def noise_twin(run: StudyRun, offset_m: float) -> StudyRun | None:
    """The same run started ``offset_m`` away in x, y and z - a stand-in for another machine's
    rounding - or None for runs that cannot be so moved (a campaign episode chooses its own start;
    training and planning runs are not closed loops of one flight)."""
    if run.runner == "evaluate":
        opts = dict(run.spec.env_options)
        offset = np.asarray(opts.get("start_offset", (0.0, 0.0, 0.0)), dtype=float) + offset_m
        return StudyRun("evaluate", replace(run.spec, env_options={**opts, "start_offset": offset.tolist()}))
    if run.runner == "adversary":
        return StudyRun("adversary", {**run.spec, "start_offset_m": offset_m})
    return None


def noise_envelope(flown: Mapping[str, Any], twins: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    """Per quantity, the largest difference between a run's digest and any of its noise twins'
    (:func:`noise_twin`) at each sample or an earlier one (a closed loop does not forget a
    perturbation it has amplified); samples a twin did not reach allow anything.

    Why: some closed loops amplify the last bits in which machines differ to millimetres within
    seconds - a solver whose active set switches one step apart, a controller near its limits -
    while most keep them many orders below the tolerance. A run's own twins measure how far *this*
    loop spreads noise; a recorded digest within :data:`NOISE_FACTOR` times that is noise, while a
    change of behaviour (a weight, a gain, the planned path) still moves it by far more."""
    out = {}
    for key in [k for k in flown if k != "t"]:
        a = np.asarray(flown[key], dtype=float)
        env = np.zeros(len(a))
        for twin in twins:
            b = np.asarray(twin.get(key, []), dtype=float)
            n = min(len(a), len(b))
            err = np.full(len(a), np.inf)
            if n:
                err[:n] = np.abs(a[:n] - b[:n]).max(axis=-1)
            env = np.maximum(env, np.maximum.accumulate(err))
        out[key] = env
    return out


def record(commands: Sequence[str], seconds: float = SECONDS,
           progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The ``behaviour`` entry of a study's provenance: its digested runs, each with its spec
    (for the reader) and digest."""
    runs = []
    for r in digested_runs(commands):
        if progress:
            progress(r.label())
        runs.append({"runner": r.runner, "run": r.label(), "spec": r.spec_dict(), "digest": fly_prefix(r, seconds)})
    return {"seconds": seconds, "decimals": DECIMALS, "tolerance": TOLERANCE, "runs": runs}


def verify(commands: Sequence[str], behaviour: Mapping[str, Any],
           progress: Callable[[str], None] | None = None) -> str:
    """Why the current code does not fly the recorded ``behaviour`` ("" when every digested run
    agrees): the digested runs are planned from ``commands`` again and their prefix flown."""
    try:
        runs = digested_runs(commands)
    except ValueError as exc:
        return str(exc)
    recorded = list(behaviour.get("runs", []))
    if len(recorded) != len(runs):
        return f"{len(runs)} digested runs planned, {len(recorded)} recorded"
    seconds = float(behaviour.get("seconds", SECONDS))
    tolerance = float(behaviour.get("tolerance", TOLERANCE))
    for r, rec in zip(runs, recorded):
        if progress:
            progress(r.label())
        try:
            flown = fly_prefix(r, seconds)
        except Exception as exc:   # any failure of the re-flight is a difference, reported in one line
            return f"{r.label()}: the re-flight failed: {type(exc).__name__}: {exc}"
        why = compare(rec.get("digest", {}), flown, tolerance)
        twins = [t for o in TWIN_OFFSETS_M if (t := noise_twin(r, o)) is not None] if why else []
        if twins:
            # a second look: does the difference stay within what this loop makes of rounding noise?
            try:
                envelope = noise_envelope(flown, [fly_prefix(t, seconds) for t in twins])
            except Exception as exc:
                return f"{r.label()}: a noise twin's re-flight failed: {type(exc).__name__}: {exc}"
            if not compare(rec.get("digest", {}), flown, tolerance, envelope):
                continue
            why += f"; beyond {NOISE_FACTOR:g} times its noise twins' spread too"
        if why:
            return f"behaviour differs: {r.label()}: {why}"
    return ""
