"""``wt-inspect tune``: offline weight tuning of an MPC with Optuna, as the paper's authors tuned theirs.

Example (a small study; every trial flies the scenario once per wind)::

    wt-inspect tune --controller vtnmpc --scenario surface --trials 40 --winds 4,7 --out results/tune_vtnmpc
    wt-inspect evaluate --scenario surface --controllers vtnmpc:weights=results/tune_vtnmpc/best_weights.json

Search space: one log-uniform multiplier per weight block (a field of the controller's
``LSQWeights``: ``heading``, ``x_star``, ``inputs``, ..., and ``terminal_factor``) in
[1/spread, spread] around the controller's own weights, so a block's rows keep their ratios and
the search has a handful of dimensions whatever the block sizes; a row whose default is 0 stays 0
(a log scale cannot reach it). The first trial of a new study is the controller's own weights
(all multipliers 1), so the best trial is never worse than the default on the tuning runs.

Objective (maximised): per wind, ``coverage + safety (SM) + centering (CM)`` (each a fraction in
[0, 1], so at most 3; a metric that is undefined counts 0), minus ``crash_penalty`` when the run
ends in a crash (any termination other than mission complete, the time limit or ``--max-time``);
the trial's value is the mean over ``--winds``. Each wind is one run of the evaluation harness
(:func:`wt_inspect.evaluation.evaluate_policy` with the registered name
``CONTROLLER:weights=FILE``), so a trial scores exactly as ``wt-inspect evaluate`` would score
that weights file. The running mean is reported after every wind and Optuna's MedianPruner stops
a trial whose running mean is below the median of earlier trials at the same wind (the harness
scores whole runs, so the wind is the pruning step; with one wind nothing is pruned).

Parallel and resumable through Optuna's storage (default ``sqlite:///OUT/study.db``): ``--jobs N``
runs N worker processes on the same study. ``--trials`` is the study's size: rerunning with the
same storage and ``--study`` runs only the trials still missing (an interrupted study resumes to
its size, a finished one gets none and its outputs are rewritten; raise ``--trials`` to search on;
the sampler's seed is offset by the trials already there, so a resumed study does not repeat its
first random points). Outputs, each written atomically::

    OUT/best_weights.json     the best trial's full weights (accepted by NAME:weights=FILE)
    OUT/trials.csv            one row per trial: state, value, per-wind scores, multipliers, wall time
    OUT/tune.json             the study, the objective, the best trial
    OUT/optimisation_history.png   trial values and the best so far
    OUT/trials/STUDY/trial-N.json   the weights file each trial flew

Exit code 0 when the study ran, 2 for bad arguments (nothing written), 130 when interrupted
(finished trials are in the storage: rerun the same command to go on).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import math
import multiprocessing
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import optuna

from wt_inspect_env.util.atomic_io import check_out_dir, write_text_atomic
from wt_inspect_env.util.figure_io import save_and_close

from ..evaluation import evaluate_policy, registry
from ..evaluation.backends import check_jobs
from ..evaluation.cli import _list
from ..evaluation.runner import make_env
from ..evaluation.scenarios import env_options, get_scenario

#: terminations that are not crashes (the others: collision, leaving the working volume, ...)
CLEAN_ENDS = frozenset({"mission_complete", "time_limit", "max_time"})
OBJECTIVE = "mean over winds of coverage + SM + CM (fractions), minus crash_penalty for a crashed run"


@dataclass(frozen=True)
class TuneConfig:
    """One tuning study (see the module docstring); ``storage`` None: ``sqlite:///OUT/study.db``,
    ``study`` None: ``CONTROLLER-SCENARIO``."""

    controller: str
    scenario: str = "surface"
    trials: int = 20
    out: str = "results/tune"
    storage: str | None = None
    study: str | None = None
    winds: tuple[float, ...] = (4.0,)
    seed: int = 0
    max_time: float | None = None
    jobs: int = 1
    spread: float = 10.0
    crash_penalty: float = 1.0
    progress: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.controller, str) and ":" in self.controller:
            raise ValueError(f"--controller {self.controller!r}: give the plain name; tune writes the weights files")
        entry = registry.entries().get(self.controller)
        if entry is None or not takes_weights_file(entry):
            what = "takes no weights file" if entry is not None else "is not a registered controller"
            raise ValueError(f"--controller {self.controller!r} {what}; tunable: {', '.join(tunable())}")
        get_scenario(self.scenario)
        if isinstance(self.trials, bool) or not isinstance(self.trials, int) or self.trials < 1:
            raise ValueError(f"--trials must be a positive integer, got {self.trials!r}")
        check_jobs(self.jobs)
        if not self.winds or not all(isinstance(w, (int, float)) and math.isfinite(w) and w >= 0 for w in self.winds):
            raise ValueError(f"--winds must be non-negative numbers, got {list(self.winds)!r}")
        if self.max_time is not None and not (math.isfinite(self.max_time) and self.max_time > 0):
            raise ValueError(f"--max-time must be a positive number of simulated seconds, got {self.max_time!r}")
        if not (math.isfinite(self.spread) and self.spread > 1):
            raise ValueError(f"--spread must be a number above 1, got {self.spread!r}")
        if not (math.isfinite(self.crash_penalty) and self.crash_penalty >= 0):
            raise ValueError(f"--crash-penalty must be a non-negative number, got {self.crash_penalty!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"--seed must be a non-negative integer, got {self.seed!r}")

    @property
    def storage_url(self) -> str:
        """The Optuna storage: ``storage`` if given, else ``OUT/study.db``."""
        return self.storage or f"sqlite:///{Path(self.out).resolve() / 'study.db'}"

    @property
    def study_name(self) -> str:
        """The Optuna study name: ``study`` if given, else controller-scenario."""
        return self.study or f"{self.controller}-{self.scenario}"


def takes_weights_file(entry: Any) -> bool:
    """Whether a registry entry's optional argument is (or starts with) ``weights=FILE``: the MPCs',
    which tune can write and re-read."""
    return (entry.optional_argument or "").startswith("weights=FILE")


def tunable() -> list[str]:
    """The registered controllers that take a weights file (the MPCs)."""
    return [n for n, e in registry.entries().items() if takes_weights_file(e)]


def check_storage(url: str) -> None:
    """Open the storage once, so a bad URL is one line before anything runs (Optuna raises the
    database library's own errors, not ValueError)."""
    try:
        optuna.storages.get_storage(url)
    except Exception as exc:   # noqa: BLE001 - any failure to open is the user's URL
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"--storage {url!r} cannot be opened: {first}") from None


def default_weights(cfg: TuneConfig) -> Any:
    """The controller's own weights as built for the scenario (the centre of the search): read
    from the policy the registry builds, so the tuned entry's variant (``vtnmpc-later``) counts."""
    env = make_env(env_options(cfg.scenario, cfg.winds[0]))
    try:
        policy = registry.resolve(cfg.controller)(env.unwrapped)
    finally:
        env.close()
    weights = getattr(getattr(policy, "config", None), "weights", None)
    if not callable(getattr(weights, "to_dict", None)):
        raise ValueError(f"--controller {cfg.controller!r} has no LSQWeights to tune")
    return weights


def blocks(weights: Any) -> list[str]:
    """The tuned blocks: the fields with a positive value (a block of zeros stays zero)."""
    return [k for k, v in weights.to_dict().items() if max(v if isinstance(v, list) else [v]) > 0]


def scaled(weights: Any, multipliers: Mapping[str, float]) -> Any:
    """``weights`` with each block times its multiplier (validated by the weights class)."""
    data = weights.to_dict()
    for k, m in multipliers.items():
        data[k] = [v * m for v in data[k]] if isinstance(data[k], list) else data[k] * m
    return type(weights).from_mapping(data, base=weights)


#: the metrics a run's score sums, with their column names in trials.csv
SCORE_PARTS = {"coverage": "coverage", "safety_sm": "sm", "centering_cm": "cm"}


def run_score(result: Any, crash_penalty: float) -> float:
    """One run's score (see the module docstring)."""
    m = result.metrics
    total = sum(float(v) if isinstance(v := m.get(k), (int, float)) and math.isfinite(v) else 0.0
                for k in SCORE_PARTS)
    crashed = (result.termination or "") not in CLEAN_ENDS or (m.get("collisions") or 0) > 0
    return total - (crash_penalty if crashed else 0.0)


class Objective:
    """The trial function (picklable: the worker processes rebuild nothing but the study)."""

    def __init__(self, cfg: TuneConfig, weights: Any) -> None:
        self.cfg, self.weights, self.blocks = cfg, weights, blocks(weights)
        safe = "".join(c if c.isalnum() or c in "-_." else "-" for c in cfg.study_name)
        self.trial_dir = Path(cfg.out) / "trials" / safe   # trial numbers are per study

    def __call__(self, trial: optuna.Trial) -> float:
        """Fly the trial's weights (the blocks' multipliers drawn by Optuna); returns the mean score."""
        cfg = self.cfg
        lo, hi = 1.0 / cfg.spread, cfg.spread
        mult = {k: trial.suggest_float(k, lo, hi, log=True) for k in self.blocks}
        weights = scaled(self.weights, mult)
        trial.set_user_attr("weights", weights.to_dict())
        path = self.trial_dir / f"trial-{trial.number}.json"
        write_text_atomic(path, json.dumps(weights.to_dict(), indent=1) + "\n")
        scores: list[float] = []
        for i, wind in enumerate(cfg.winds):
            res = evaluate_policy(f"{cfg.controller}:weights={path}", scenario=cfg.scenario, wind=float(wind),
                                  seed=cfg.seed, max_time=cfg.max_time, record=False)
            scores.append(run_score(res, cfg.crash_penalty))
            trial.set_user_attr(f"score_w{wind:g}", scores[-1])
            trial.set_user_attr(f"termination_w{wind:g}", res.termination or "")
            for key, short in SCORE_PARTS.items():
                v = res.metrics.get(key)   # the score's parts, so trials.csv says why a trial scored so
                trial.set_user_attr(f"{short}_w{wind:g}", float(v) if isinstance(v, (int, float)) else math.nan)
            mean = sum(scores) / len(scores)
            trial.report(mean, step=i)
            if i < len(cfg.winds) - 1 and trial.should_prune():
                raise optuna.TrialPruned()
        return sum(scores) / len(scores)


def _study(cfg: TuneConfig, *, seed_offset: int = 0) -> optuna.Study:
    sampler = optuna.samplers.TPESampler(seed=cfg.seed + seed_offset)
    pruner = optuna.pruners.MedianPruner(n_startup_trials=3, n_warmup_steps=0)
    return optuna.create_study(storage=cfg.storage_url, study_name=cfg.study_name, direction="maximize",
                               sampler=sampler, pruner=pruner, load_if_exists=True)


def _worker(cfg: TuneConfig, weights: Any, n_trials: int, seed_offset: int) -> None:
    """One process of ``--jobs``: its share of the trials on the shared study."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    _study(cfg, seed_offset=seed_offset).optimize(Objective(cfg, weights), n_trials=n_trials, catch=())


def _shares(total: int, jobs: int) -> list[int]:
    return [n for n in (total // jobs + (i < total % jobs) for i in range(jobs)) if n]


def tune(cfg: TuneConfig) -> dict[str, Any]:
    """Run (or continue) the study, write the outputs, return the summary of ``tune.json``."""
    from tqdm import tqdm
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    weights = default_weights(cfg)
    objective = Objective(cfg, weights)
    objective.trial_dir.mkdir(parents=True, exist_ok=True)
    study = _study(cfg)
    before = len(study.trials)
    study.sampler = optuna.samplers.TPESampler(seed=cfg.seed + before)
    # --trials is the study's size: a rerun runs only the trials still missing, so an interrupted
    # study resumes to the same size and rerunning a finished one (wt-inspect reproduce) adds none
    todo = max(cfg.trials - _finished(study), 0)
    t0 = time.perf_counter()
    bar = tqdm(total=todo, desc=f"tune {cfg.study_name}", unit="trial", disable=not cfg.progress)
    tick = [lambda s, t: bar.update(1)]
    try:
        if before == 0 and todo:   # the controller's own weights first, in this process (workers racing for an
            # enqueued trial on SQLite can run it twice): the baseline every trial is compared with
            study.enqueue_trial({k: 1.0 for k in blocks(weights)})
            study.optimize(objective, n_trials=1, catch=(), callbacks=tick)
            todo -= 1
        jobs = min(check_jobs(cfg.jobs), max(todo, 1))
        if todo and jobs == 1:
            study.optimize(objective, n_trials=todo, catch=(), callbacks=tick)
        elif todo:
            ctx = multiprocessing.get_context("spawn")
            procs = [ctx.Process(target=_worker, args=(cfg, weights, n, before + 1 + 1000 * i))
                     for i, n in enumerate(_shares(todo, jobs))]
            for p in procs:
                p.start()
            while any(p.is_alive() for p in procs):
                time.sleep(1.0)
                bar.update(max(0, _finished(study) - before - bar.n))
            bar.update(max(0, _finished(study) - before - bar.n))
            failed = [p.exitcode for p in procs if p.exitcode]
            if failed:
                raise RuntimeError(f"{len(failed)} tuning worker(s) failed (exit codes {failed})")
    finally:
        bar.close()
    return write_outputs(cfg, study, before=before, wall_time_s=time.perf_counter() - t0)


def _finished(study: optuna.Study) -> int:
    return sum(t.state.is_finished() for t in study.get_trials(deepcopy=False))


def write_outputs(cfg: TuneConfig, study: optuna.Study, *, before: int, wall_time_s: float) -> dict[str, Any]:
    """best_weights.json, trials.csv, tune.json and the figure, from the storage (so they describe
    the whole study, resumed trials included)."""
    out = Path(cfg.out)
    trials = study.get_trials(deepcopy=False)
    complete = [t for t in trials if t.state == optuna.trial.TrialState.COMPLETE]
    if not complete:
        raise RuntimeError(f"study {cfg.study_name!r} has no complete trial")
    best = study.best_trial
    write_text_atomic(out / "best_weights.json", json.dumps(best.user_attrs["weights"], indent=1) + "\n")
    params = sorted({k for t in trials for k in t.params})
    attrs = sorted({k for t in trials for k in t.user_attrs if k != "weights"})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["number", "state", "value", *attrs, *(f"x_{k}" for k in params), "wall_time_s"])
    for t in trials:
        dur = t.duration.total_seconds() if t.duration is not None else math.nan
        w.writerow([t.number, t.state.name, "" if t.value is None else t.value,
                    *(t.user_attrs.get(k, "") for k in attrs), *(t.params.get(k, "") for k in params), f"{dur:.3f}"])
    write_text_atomic(out / "trials.csv", buf.getvalue())
    summary = {"study": cfg.study_name, "storage": cfg.storage_url, "controller": cfg.controller,
               "scenario": cfg.scenario, "winds": list(cfg.winds), "seed": cfg.seed, "max_time": cfg.max_time,
               "spread": cfg.spread, "crash_penalty": cfg.crash_penalty, "objective": OBJECTIVE,
               "trials": len(trials), "complete": len(complete),
               "pruned": sum(t.state == optuna.trial.TrialState.PRUNED for t in trials),
               "added_now": len(trials) - before, "wall_time_s": round(wall_time_s, 3),
               "best": {"number": best.number, "value": best.value, "multipliers": best.params,
                        "weights": best.user_attrs["weights"]},
               "default_value": next((t.value for t in complete if t.number == 0), None)}
    write_text_atomic(out / "tune.json", json.dumps(summary, indent=1) + "\n")
    _figure(cfg, trials, out / "optimisation_history.png")
    return summary


def _figure(cfg: TuneConfig, trials: Sequence[Any], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    done = [t for t in trials if t.state == optuna.trial.TrialState.COMPLETE]
    pruned = [t for t in trials if t.state == optuna.trial.TrialState.PRUNED and t.intermediate_values]
    ax.plot([t.number for t in done], [t.value for t in done], "o", ms=4, label="trial")
    if pruned:
        ax.plot([t.number for t in pruned], [t.intermediate_values[max(t.intermediate_values)] for t in pruned],
                "x", ms=5, color="0.5", label="pruned (last running mean)")
    order = sorted(done, key=lambda t: t.number)
    best, xs, ys = -math.inf, [], []
    for t in order:
        best = max(best, t.value)
        xs.append(t.number)
        ys.append(best)
    ax.step(xs, ys, where="post", color="C3", label="best so far")
    ax.set_xlabel("trial")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("objective (coverage + SM + CM - crash)")
    ax.set_title(f"{cfg.study_name}: winds {', '.join(f'{w:g}' for w in cfg.winds)} m/s", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_and_close(fig, path, "png")


def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect tune`` (its epilog states the objective)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="objective: " + OBJECTIVE)
    ap.add_argument("--controller", required=True, help="a registered MPC (" + ", ".join(tunable()) + ")")
    ap.add_argument("--scenario", default="surface", help="evaluation scenario (default surface)")
    ap.add_argument("--trials", type=int, required=True, help="trials to add to the study in this run")
    ap.add_argument("--storage", help="Optuna storage URL (default sqlite:///OUT/study.db)")
    ap.add_argument("--study", help="study name (default CONTROLLER-SCENARIO); the same name resumes")
    ap.add_argument("--out", default="results/tune", help="output directory (default results/tune)")
    ap.add_argument("--winds", type=_list(float, "--winds"), default=[4.0], metavar="W,...",
                    help="mean winds [m/s] each trial flies (default 4)")
    ap.add_argument("--seed", type=int, default=0, help="episode seed of every run and the sampler's base seed")
    ap.add_argument("--max-time", type=float, metavar="S", help="cap each run at S simulated seconds")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes on the shared storage (default 1)")
    ap.add_argument("--spread", type=float, default=10.0,
                    help="each block's multiplier is searched log-uniformly in [1/spread, spread] (default 10)")
    ap.add_argument("--crash-penalty", type=float, default=1.0, help="subtracted from a crashed run's score")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


def main(argv: list[str], prog: str = "wt-inspect tune") -> int:
    """``wt-inspect tune``: run (or resume) the study given by ``argv``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    try:
        cfg = TuneConfig(controller=args.controller, scenario=args.scenario, trials=args.trials, out=args.out,
                         storage=args.storage, study=args.study, winds=tuple(args.winds), seed=args.seed,
                         max_time=args.max_time, jobs=args.jobs, spread=args.spread,
                         crash_penalty=args.crash_penalty, progress=not args.no_progress)
        check_out_dir(cfg.out)
        if args.storage is not None:   # a bad URL is refused before anything is written
            check_storage(cfg.storage_url)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        summary = tune(cfg)
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted; finished trials are in {cfg.storage_url} - rerun the same command to go on",
              file=sys.stderr)
        return 130
    except RuntimeError as exc:   # a worker process failed (its traceback is above) or no trial completed
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    best = summary["best"]
    print(f"study {summary['study']}: {summary['added_now']} trials added ({summary['trials']} in total, "
          f"{summary['pruned']} pruned) in {summary['wall_time_s']:.1f} s; best trial {best['number']} "
          f"value {best['value']:.4f} (default {summary['default_value']}); wrote {cfg.out}/best_weights.json, "
          "trials.csv, tune.json, optimisation_history.png")
    return 0
