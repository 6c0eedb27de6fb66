"""Flying a campaign: one episode (failures recorded, not raised), the episodes over the backends, resumed."""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from wt_inspect_env.util.interrupts import interrupts_deferred, interrupts_raise

from ...evaluation import OutputDirError, prepare_out_dir, registry, resume_runs
from ...evaluation.backends import BACKENDS, check_jobs, run_specs
from ...evaluation.runner import RunResult, RunSpec, exception_result, fly, make_env, save_run
from .draws import CampaignConfig, campaign_specs, clear_start, controller_dir
from .report import config_json, write_comparison, write_report


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
    results, todo = resume_runs(out_dir / "runs", specs,
                                warn=lambda m: print(f"warning: {m}", file=sys.stderr))
    # the earlier invocations' cost counts only when their episodes are reused (not after their
    # run files were discarded, e.g. by wt-inspect reproduce for other code)
    earlier = earlier_invocations(out_dir / "campaign.json", cfg) if results else []

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
            write_report(cfg, out_dir, specs, by_file, results, figure=False, **kw)
        raise
    return write_report(cfg, out_dir, specs, by_file, results, figure=figure, **kw)


def earlier_invocations(path: Path, cfg: CampaignConfig) -> list[float]:
    """Wall times [s] of the earlier invocations of the same campaign in ``out`` (none for a new
    one, or for another campaign's ``campaign.json``), so a resumed campaign reports its whole
    cost, not only its last invocation's. A campaign given more (or fewer) episodes is the same
    campaign: episode k does not depend on how many follow, so its finished run files are reused
    and their cost counts. A format-/1 file gives its summed total as one entry."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(doc, dict) or not isinstance(doc.get("config"), dict) or \
            {**doc["config"], "episodes": cfg.episodes} != config_json(cfg):
        return []
    walls = doc.get("wall_time_invocations_s")
    if not isinstance(walls, list):
        walls = [doc.get("wall_time_total_s", doc.get("wall_time_s", 0.0))]
    ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 for v in walls)
    return [float(v) for v in walls] if ok else []


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
