"""Evaluation harness: score any policy on the paper's scenarios, reproduce its table and figures.

Python API::

    from wt_inspect.evaluation import evaluate_policy, run_evaluation

    # one run of any object with reset(seed=None) / act(obs) (or a factory env -> policy, or a
    # registered name such as "vtnmpc"), scored exactly as the command line scores the MPCs
    res = evaluate_policy(my_policy, scenario="surface", wind=4.0, seed=0)
    res.metrics["coverage"], res.row()["safety"], res.arrays["distance"]

    # a sweep, in parallel, resumable, with results.csv / results.md / figures in out
    ev = run_evaluation("paper", ["vtnmpc", "nmpc", "pampc"], winds=[0, 4, 7], out="results/paper")

Command line: ``wt-inspect evaluate`` (:mod:`.cli`). Layout of the output directory::

    out/results.csv          one row per run (see report.CSV_COLUMNS)
    out/results.md           the paper's table layout beside the paper's numbers, all runs, setup
    out/*.png                figures (see figures; .pdf / .svg with figure_format)
    out/runs/*.npz           one file per run: trajectory and per-step metrics (see runner)

Resume: a run's file is written atomically when it finishes and named by a hash of everything
that determines its outcome (scenario options, controller, wind, seed, time cap), so rerunning the
same sweep skips the finished runs and an interrupted sweep loses only the runs in flight. Run
files also record a fingerprint of the simulation and controller sources; resumed runs made by
other code are flagged (stderr and results.md) rather than silently mixed in.
"""
from __future__ import annotations

import contextlib
import math
import os
import secrets
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

from wt_inspect_env.util.figure_io import check_figure_format
from wt_inspect_env.util.interrupts import interrupts_deferred, interrupts_raise
from wt_inspect_env.util.ray_session import check_ray_address, import_ray

from . import registry
from .backends import BACKENDS, check_jobs, run_specs
from .report import ReportContext, write_csv, write_markdown
from .runner import RunResult, RunSpec, code_fingerprint, execute, load_run, make_spec, save_run
from .scenarios import SCENARIOS, WIND_TYPES, SweepSpec, env_options, get_scenario

__all__ = ["evaluate_policy", "run_evaluation", "Evaluation", "RunResult", "RunSpec", "SCENARIOS",
           "BACKENDS", "WIND_TYPES", "OutputDirError", "load_run", "env_options"]


class OutputDirError(ValueError):
    """The output directory cannot be created or written (the message names the path)."""


def prepare_out_dir(out: str | os.PathLike) -> Path:
    """Create ``out`` (and ``out/runs``) and prove it writable, before any run starts."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise OutputDirError(f"output directory {str(path)!r} exists and is not a directory")
    try:
        (path / "runs").mkdir(parents=True, exist_ok=True)
        probe = path / f".write-test-{secrets.token_hex(4)}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OutputDirError(f"cannot write to output directory {str(path)!r}: {exc.strerror or exc}") from None
    return path


def _is_policy(obj: Any) -> bool:
    return callable(getattr(obj, "act", None)) and callable(getattr(obj, "reset", None))


def evaluate_policy(policy: Any, scenario: str = "surface", wind: float = 4.0, seed: int = 0, *,
                    wind_type: str = "gust", wind_options: Mapping[str, Any] | None = None,
                    turbine: Mapping[str, Any] | None = None, drone: str | None = None,
                    env_overrides: Mapping[str, Any] | None = None, max_time: float | None = None,
                    record: bool = True, record_every: int = 1, name: str | None = None,
                    save_dir: str | os.PathLike | None = None) -> RunResult:
    """Score one policy on one scenario run, the same way the command line does.

    ``policy``: an object with ``reset(seed=None)`` and ``act(obs) -> normalised action`` (see
    :class:`wt_inspect_env.policy.Policy`; it must match the scenario's drone and stand-off - the
    environment's ``params`` and ``config.standoff``), a factory ``env -> policy`` called with
    the unwrapped environment (recommended: it can read those), or a registered controller name.
    ``max_time`` caps the simulated seconds. ``save_dir``: also write the run file there.
    """
    if isinstance(policy, str):
        label, factory = policy, None
    elif _is_policy(policy) or callable(policy):
        label, factory = name or getattr(policy, "name", None) or type(policy).__name__, policy
        if not isinstance(label, str):
            label = type(policy).__name__
    else:
        raise ValueError(f"policy must be an object with reset()/act(), a factory env -> policy or a controller "
                         f"name ({registry.valid_names()}), got {policy!r}")
    opts = env_options(scenario, wind, wind_type=wind_type, wind_options=wind_options, turbine=turbine,
                       drone=drone, overrides=env_overrides)
    spec = make_spec(scenario, label, wind, seed, opts, max_time, record_every, custom=factory is not None)
    result = execute(spec, factory, record=record)
    if save_dir is not None:
        out = prepare_out_dir(save_dir)
        save_run(result, out / "runs" / spec.filename)
    return result


@dataclass
class Evaluation:
    """Outcome of :func:`run_evaluation`: every run of the sweep (metrics only, trajectories are in
    the run files: ``load_run(r.path)``), what was executed and resumed, and the files written."""

    out: Path
    results: list[RunResult]
    n_ran: int
    n_resumed: int
    wall_time_s: float
    files: dict[str, Any] = field(default_factory=dict)

    def rows(self) -> list[dict[str, Any]]:
        """One results row per run."""
        return [r.row() for r in self.results]


def _floats(name: str, values: Iterable[Any]) -> list[float]:
    out = []
    for v in values:
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be numbers, got {v!r}") from None
        if not math.isfinite(f) or f < 0:
            raise ValueError(f"{name} must be non-negative finite numbers, got {v!r}")
        out.append(f)
    if not out:
        raise ValueError(f"{name} must not be empty")
    return list(dict.fromkeys(out))


def _seeds(values: Iterable[Any]) -> list[int]:
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ValueError(f"seeds must be non-negative integers, got {v!r}")
        out.append(v)
    if not out:
        raise ValueError("seeds must not be empty")
    return list(dict.fromkeys(out))


def plan_sweep(scenario: str, controllers: Sequence[str], winds: Sequence[float], seeds: Sequence[int], *,
               sweep: SweepSpec, max_time: float | None, record_every: int,
               custom: Iterable[str] = (), trust_model: bool = False) -> list[RunSpec]:
    """The run specs of a sweep in table order (wind, controller, seed); all validation here. A
    controller's runs get the env options it needs (:func:`registry.env_options`) where the sweep
    does not set them."""
    custom = set(custom)
    specs = []
    # what a controller needs of the env (an agent that observes the structure), unless the user set it
    needs = {c: {} if c in custom else registry.env_options(c) for c in controllers}
    for wind in winds:
        opts = sweep.options(wind)
        for c in controllers:
            own = {**{k: v for k, v in needs[c].items() if k not in opts}, **opts}
            for s in seeds:
                specs.append(make_spec(scenario, c, wind, s, own, max_time, record_every, custom=c in custom,
                                       trust_model=trust_model))
    return specs


def sweep_specs(scenario: str, controllers: Sequence[str], winds: Sequence[float] | None, seeds: Sequence[int], *,
                wind_type: str = "gust", wind_options: Mapping[str, Any] | None = None,
                turbine: Mapping[str, Any] | None = None, drone: str | None = None,
                env_overrides: Mapping[str, Any] | None = None, max_time: float | None = None,
                record_every: int = 1, custom: Iterable[str] = (), trust_model: bool = False) -> list[RunSpec]:
    """The run specs :func:`run_evaluation` flies for these arguments (``winds`` None: the
    scenario's), in table order; what ``wt-inspect reproduce`` plans its behaviour digests from."""
    winds_l = _floats("winds", get_scenario(scenario).winds if winds is None else winds)
    sweep = SweepSpec(scenario, wind_type, dict(wind_options or {}), dict(turbine or {}), drone,
                      dict(env_overrides or {}))
    return plan_sweep(scenario, list(controllers), winds_l, _seeds(seeds), sweep=sweep, max_time=max_time,
                      record_every=record_every, custom=custom, trust_model=trust_model)


def run_evaluation(scenario: str = "paper",
                   controllers: Sequence[str] | Mapping[str, Any] = ("vtnmpc", "nmpc", "pampc"),
                   winds: Sequence[float] | None = None, seeds: Sequence[int] = (0,), *,
                   out: str | os.PathLike, backend: str = "local", jobs: int | None = None,
                   address: str | None = None, max_time: float | None = None, wind_type: str = "gust",
                   wind_options: Mapping[str, Any] | None = None, turbine: Mapping[str, Any] | None = None,
                   drone: str | None = None, env_overrides: Mapping[str, Any] | None = None,
                   record_every: int = 1, figures: bool = True, figure_format: str = "png",
                   progress: bool = True, rerun: bool = False, command: str | None = None,
                   on_result: Callable[[RunResult], None] | None = None,
                   trust_model: bool = False) -> Evaluation:
    """Run a sweep (controllers x winds x seeds) on ``backend`` and write the results to ``out``.

    ``controllers``: registered names / ``ppo:PATH`` strings, or a mapping ``label -> name, policy
    factory (env -> policy) or policy object`` for custom policies (with several processes a
    factory must be picklable; an object is used as is only with ``jobs=1``). ``winds`` defaults
    to the scenario's. Finished runs in ``out/runs`` are reused unless ``rerun``. Raises
    ``ValueError`` for bad arguments (naming them) and :class:`OutputDirError` if ``out`` cannot be
    written - both before any run starts. ``figure_format``: png, pdf or svg.
    ``KeyboardInterrupt`` writes the results of the finished runs (marked incomplete) and propagates.
    ``trust_model``: load ``ppo:`` model files even if that runs code from them (the
    CLI's ``--trust-model``; without it such a file is refused before any run starts).
    """
    t0 = time.perf_counter()
    get_scenario(scenario)              # an unknown scenario is refused before anything else
    check_figure_format(figure_format)
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    jobs = check_jobs(jobs)
    if isinstance(controllers, Mapping):
        labels = list(controllers)
        factories = {k: v for k, v in controllers.items() if not isinstance(v, str)}
        aliases = {k: v for k, v in controllers.items() if isinstance(v, str)}
        if any(k != v for k, v in aliases.items()):
            raise ValueError(f"a controller given by name must use its name as label, got {aliases}")
        for k, v in factories.items():
            if _is_policy(v) and (jobs > 1 or backend != "local"):
                raise ValueError(f"controller {k!r} is a policy object: pass a factory (env -> policy) to run it in "
                                 "worker processes, or use backend='local', jobs=1")
            if not callable(v):
                raise ValueError(f"controller {k!r} must be a name, a factory or a policy object, got {v!r}")
    else:
        if isinstance(controllers, str):
            controllers = [c.strip() for c in controllers.split(",") if c.strip()]
        labels, factories = list(dict.fromkeys(controllers)), {}
    if not labels:
        raise ValueError(f"no controllers given; valid: {registry.valid_names()}")
    specs = sweep_specs(scenario, labels, winds, seeds, wind_type=wind_type, wind_options=wind_options,
                        turbine=turbine, drone=drone, env_overrides=env_overrides, max_time=max_time,
                        record_every=record_every, custom=factories, trust_model=trust_model)
    if backend == "ray":   # before the output directory is made: a missing Ray leaves nothing behind
        import_ray()
        if address:
            check_ray_address(address)
    out_dir = prepare_out_dir(out)
    with interrupts_raise():   # SIGTERM as Ctrl-C in every phase below, whatever the backend and jobs
        return _sweep(out_dir, specs, t0=t0, scenario=scenario, backend=backend, jobs=jobs, address=address,
                      wind_type=wind_type, turbine=turbine, drone=drone, env_overrides=env_overrides,
                      factories=factories, figures=figures, figure_format=figure_format, progress=progress,
                      rerun=rerun, command=command, on_result=on_result)


def resume_runs(runs_dir: Path, specs: Sequence[RunSpec], *, rerun: bool = False,
                warn: Callable[[str], None] | None = None) -> tuple[dict[str, RunResult], list[RunSpec]]:
    """The finished runs of ``specs`` in ``runs_dir`` (by file name) and the specs still to run.

    A file at a spec's name that is not a usable run file of that spec (unreadable, foreign or
    malformed metadata, another spec's key) is not an error: the run is done again and its file
    replaced (atomically, when it finishes) - the sweep resumes instead of stopping at a file it
    cannot use. ``warn`` gets one line per such file, naming it and why (shared by ``evaluate``
    and ``campaign``)."""
    done: dict[str, RunResult] = {}
    todo: list[RunSpec] = []
    for spec in specs:
        path = runs_dir / spec.filename
        if path.exists() and not rerun:
            try:
                res = load_run(path, arrays=False)
            except ValueError as exc:
                if warn is not None:
                    warn(f"{exc} - running it again (the file will be replaced)")
            else:
                if res.spec.key == spec.key:
                    done[spec.filename] = res
                    continue
                if warn is not None:
                    warn(f"{path} holds another run (key {res.spec.key}, expected {spec.key}) - running it again")
        todo.append(spec)
    return done, todo


def _warn(msg: str) -> None:
    print(f"warning: {msg}", file=sys.stderr)


def _sweep(out_dir: Path, specs: list[RunSpec], *, t0: float, scenario: str, backend: str, jobs: int,
           address: str | None, wind_type: str, turbine: Mapping[str, Any] | None, drone: str | None,
           env_overrides: Mapping[str, Any] | None, factories: Mapping[str, Any], figures: bool,
           figure_format: str, progress: bool, rerun: bool, command: str | None,
           on_result: Callable[[RunResult], None] | None) -> Evaluation:
    """The part of :func:`run_evaluation` after validation: resume, run, write the tables and
    figures. Interrupted (SIGINT, SIGTERM) or failed in any phase, it writes results.csv and
    results.md of what finished (marked incomplete) before the exception propagates."""
    _remove_stale_temporaries(out_dir / "runs")
    notes: list[str] = []
    done, todo = resume_runs(out_dir / "runs", specs, rerun=rerun,
                             warn=lambda m: (_warn(m), notes.append(f"Warning: {m}")))
    n_resumed = len(done)

    def finished(res: RunResult) -> None:
        try:
            save_run(res, out_dir / "runs" / res.spec.filename)
        except OSError as exc:   # the disk went read-only or full mid-sweep: one line, runs kept
            raise OutputDirError(f"cannot write run file {str(out_dir / 'runs' / res.spec.filename)!r}: "
                                 f"{exc.strerror or exc}; the {len(done)} run(s) finished before are kept - "
                                 "free the disk and rerun the same command to resume") from None
        res.arrays = {}   # keep memory flat; figures reload what they draw
        done[res.spec.filename] = res
        if on_result is not None:
            on_result(res)

    if n_resumed:
        if progress:
            print(f"resuming: {n_resumed} of {len(specs)} runs already finished in {out_dir / 'runs'}",
                  file=sys.stderr)
        code = code_fingerprint()
        stale = sorted(r.spec.filename for r in done.values() if r.code != code)
        if stale:
            msg = (f"{len(stale)} resumed run(s) were made by other simulation/controller code than this one "
                   f"(code {code}); their numbers may differ from a fresh run - use --rerun to redo them: "
                   + ", ".join(stale))
            _warn(msg)
            notes.append(f"Warning: {msg}")
    ctx = ReportContext(scenario=scenario, wind_type=wind_type, backend=backend, jobs=jobs,
                        n_planned=len(specs), n_resumed=n_resumed,
                        command=command or "", notes=notes,
                        overrides={k: v for k, v in (("turbine", dict(turbine or {})), ("drone", drone),
                                                     ("env", dict(env_overrides or {}))) if v})

    def write_tables(results: list[RunResult]) -> None:
        """results.csv and results.md of ``results`` on the way out of an interrupted or failed
        sweep; a second signal does not cut them short, an unwritable disk (what is being
        reported then) is not a second error."""
        ctx.wall_time_s, ctx.n_ran = time.perf_counter() - t0, len(done) - n_resumed
        with interrupts_deferred(raise_noted=False), contextlib.suppress(OSError):
            write_csv(results, out_dir / "results.csv")
            write_markdown(results, ctx, out_dir / "results.md")

    try:
        if todo:
            run_specs(backend, todo, finished, jobs=jobs, address=address, factories=factories, progress=progress)
    except BaseException:
        # An interrupt can land between a run file's rename and its bookkeeping: the files on disk
        # are the truth (they are what a rerun resumes from).
        with interrupts_deferred(raise_noted=False):
            for s in specs:
                path = out_dir / "runs" / s.filename
                if s.filename not in done and path.exists():
                    with contextlib.suppress(ValueError):
                        done[s.filename] = load_run(path, arrays=False)
        write_tables([done[s.filename] for s in specs if s.filename in done])   # "Incomplete: k of n", k >= 0
        raise
    results = [done[s.filename] for s in specs]
    files: dict[str, Any] = {}
    try:
        files["csv"] = write_csv(results, out_dir / "results.csv")
        if figures:
            from .figures import make_figures  # matplotlib only when drawing
            files["figures"] = make_figures([load_run(r.path) for r in _first_seeds(results)], out_dir, scenario,
                                            figure_format)
        stale = stale_files(out_dir, specs, files.get("figures"))
        if stale:
            msg = (f"{len(stale)} file(s) in {out_dir} are not from this sweep (left by an earlier, different "
                   f"one in the same --out; not read, not in these tables): " + ", ".join(stale)
                   + " - delete them or use a fresh --out")
            if progress:
                _warn(msg)
            ctx.notes.append(f"Warning: {msg}")
        files["stale"] = stale
        ctx.wall_time_s, ctx.n_ran = time.perf_counter() - t0, len(done) - n_resumed
        files["md"] = write_markdown(results, ctx, out_dir / "results.md")
    except OSError as exc:
        raise OutputDirError(f"cannot write the results to {str(out_dir)!r}: {exc.strerror or exc}; the run files "
                             "are kept - rerun the same command to write the tables") from None
    except BaseException:   # interrupted (or failed) while drawing the figures: the tables still get written
        if "md" not in files:
            ctx.notes.append("Figures: not all drawn - the command stopped while drawing them; rerun the same "
                             "command to draw them (every run is finished and resumed)")
            write_tables(results)
        raise
    return Evaluation(out=out_dir, results=results, n_ran=ctx.n_ran, n_resumed=n_resumed,
                      wall_time_s=ctx.wall_time_s, files=files)


FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def stale_files(out_dir: Path, specs: Sequence[RunSpec], figures_written: Iterable[Any] | None) -> list[str]:
    """Files in ``out_dir`` that this sweep neither wrote nor read (paths relative to it, sorted):
    run files of other specs in ``runs/`` and, when it drew figures (``figures_written`` not
    None), figures it did not draw. A reused ``--out`` of a different sweep (other controllers,
    winds, options) keeps them, and a reader of the directory would take them for this sweep's -
    so results.md names them (they are not deleted: they may be the only copy of an expensive run)."""
    own_runs = {s.filename for s in specs}
    own_figs = {Path(f).name for f in figures_written or ()}
    out = [f"runs/{p.name}" for p in sorted((out_dir / "runs").glob("*.npz"))
           if p.name not in own_runs and not p.name.startswith(".")]   # .NAME.tmp.npz: a write in flight
    if figures_written is not None:
        out += [p.name for p in sorted(out_dir.iterdir())
                if p.is_file() and p.suffix in FIGURE_SUFFIXES and p.name not in own_figs]
    return out


def _remove_stale_temporaries(runs_dir: Path, min_age_s: float = 60.0) -> None:
    """Delete temporary files that a killed evaluation left mid-write (``.NAME.<hex>.tmp.npz``);
    recent ones are left alone in case another evaluation is writing into the same directory."""
    now = time.time()
    for p in runs_dir.glob(".*.tmp.npz"):
        with contextlib.suppress(OSError):
            if now - p.stat().st_mtime > min_age_s:
                p.unlink()


def _first_seeds(results: Sequence[RunResult]) -> list[RunResult]:
    """For each (controller, wind) the run with the lowest seed (the one the figures draw)."""
    best: dict[tuple[str, float], RunResult] = {}
    for r in results:
        k = (r.spec.controller, r.spec.wind)
        if k not in best or r.spec.seed < best[k].spec.seed:
            best[k] = r
    return list(best.values())


def command_line(argv: Sequence[str], prog: str) -> str:
    return " ".join([prog] + [shlex.quote(a) for a in argv])
