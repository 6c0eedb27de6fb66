"""Where runs execute: a local process pool over the machine's cores, or a Ray cluster.

A backend takes run specs (plain data, see :class:`~.runner.RunSpec`) and hands every finished
:class:`~.runner.RunResult` to ``on_result`` *in the calling process*, which saves it. Workers
never write files, so a Ray cluster needs no shared file system, and both backends produce the
same files from the same results: a run's outcome depends only on its spec (seeded environment,
deterministic controllers), not on which process or machine executed it.

``factories`` maps controller labels to policy factories for custom policies; registered names
(:mod:`.registry`) are resolved inside the worker. With several processes a custom factory must be
picklable (a module-level function or class; Ray also ships lambdas via cloudpickle).

Progress: the local backend shows an overall bar plus one bar per active run (simulated seconds,
reported by the workers through a queue); the Ray backend shows the overall bar.

Orphans: local pool workers die with the process that started them, however it ends. On Linux
each worker asks the kernel for SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``), and on
every platform a daemon thread in the worker exits it once its parent is gone (reparenting changes
``os.getppid()``), so a SIGKILLed ``wt-inspect evaluate`` leaves no worker behind - and with the
workers gone the resource tracker, which exits when the last holder of its pipe does, follows.
SIGTERM of the parent is turned into :class:`~wt_inspect_env.util.interrupts.Terminated` (a
``KeyboardInterrupt``) while runs execute (:func:`~wt_inspect_env.util.interrupts.interrupts_raise`, with
any number of jobs), so the pool is terminated and the finished runs' files are written as on Ctrl-C.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import multiprocessing as mp
import os
import queue as queue_mod
import signal
import sys
import threading
import time
from typing import Any, Callable, Mapping, Sequence

from wt_inspect_env.util.interrupts import Terminated, interrupts_raise  # noqa: F401 - Terminated: re-exported
from wt_inspect_env.util.process_memory import release_free_heap
from wt_inspect_env.util.ray_session import import_ray, init_ray

from .runner import RunResult, RunSpec, execute

OnResult = Callable[[RunResult], None]
# What a worker does with one spec: ``task(spec, factory, record=..., progress=...) -> RunResult``;
# :func:`~.runner.execute` for an evaluation, a campaign's own episode function (module-level, so
# it pickles) for a campaign.
Task = Callable[..., RunResult]
BACKENDS = ("local", "ray")


class ProgressBoard:
    """tqdm bars: one for the sweep, one per active run (created on its first report)."""

    def __init__(self, total: int, enabled: bool, desc: str = "runs") -> None:
        self.enabled = enabled
        self._lock = threading.Lock()
        self._bars: dict[str, Any] = {}
        self.overall = None
        if enabled:
            from tqdm.auto import tqdm
            self._tqdm = tqdm
            self.overall = tqdm(total=total, desc=desc, unit="run", position=0, dynamic_ncols=True)

    def report(self, key: str, label: str, t: float, total: float) -> None:
        """Show run ``key`` (``label``) at ``t`` of ``total`` simulated seconds."""
        if not self.enabled:
            return
        with self._lock:
            bar = self._bars.get(key)
            if bar is None:
                if key in self._bars:   # already finished
                    return
                bar = self._tqdm(total=round(total, 1), desc=label, unit="sim s", leave=False,
                                 dynamic_ncols=True, bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                                 "{n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]")
                self._bars[key] = bar
            bar.n = min(round(t, 1), bar.total)
            bar.refresh()

    def finish(self, key: str, note: str = "") -> None:
        """Mark run ``key`` finished, with an optional ``note``."""
        if not self.enabled:
            return
        with self._lock:
            bar = self._bars.get(key)
            if bar is not None:
                bar.close()
            self._bars[key] = None
            self.overall.update(1)
            if note:
                self.overall.set_postfix_str(note, refresh=True)

    def close(self) -> None:
        """Close every progress bar."""
        if not self.enabled:
            return
        with self._lock:
            for bar in self._bars.values():
                if bar is not None:
                    bar.close()
            self.overall.close()


def _label(spec: RunSpec) -> str:
    return f"{spec.controller} {spec.wind:g} m/s s{spec.seed}"


def _note(result: RunResult) -> str:
    m = result.metrics
    return (f"{_label(result.spec)}: cov {m.get('coverage', float('nan')):.3f} "
            f"SM {m.get('safety_sm', float('nan')):.3f} ({result.termination})")


# ------------------------------------------------------------------ local
_WORKER_QUEUE: Any = None   # set in each pool worker by the initializer (per-process, not shared state)


PR_SET_PDEATHSIG = 1   # <linux/prctl.h>
PARENT_POLL_S = 0.5


def die_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """Make this process end when ``parent_pid`` does: ``PR_SET_PDEATHSIG`` on Linux, and on every
    platform a daemon thread that polls ``os.getppid()`` (an orphan is reparented) and exits.
    The poll also covers a parent that died before the ``prctl`` call."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent_pid:
                os._exit(1)
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _init_worker(q: Any, parent_pid: int | None = None) -> None:
    global _WORKER_QUEUE
    _WORKER_QUEUE = q
    if parent_pid is not None:
        die_with_parent(parent_pid)


def _local_task(spec: RunSpec, factory: Any, record: bool, task: Task | None = None) -> RunResult:
    q = _WORKER_QUEUE
    key = spec.filename

    def progress(t: float, total: float) -> None:
        if q is not None:
            q.put((key, t, total))
    try:
        return (task or execute)(spec, factory, record=record, progress=progress)
    finally:
        release_free_heap()   # a long-lived worker keeps no freed arena pages between runs


def run_local(specs: Sequence[RunSpec], on_result: OnResult, *, jobs: int | None = None,
              factories: Mapping[str, Any] | None = None, record: bool = True, progress: bool = True,
              task: Task | None = None) -> None:
    """Run ``specs`` over ``jobs`` processes (default: all cores; 1 = in this process); each
    through ``task`` (default :func:`~.runner.execute`)."""
    factories = dict(factories or {})
    run = task or execute
    jobs = check_jobs(jobs)
    board = ProgressBoard(len(specs), progress)
    try:
        if jobs == 1 or len(specs) <= 1:
            with interrupts_raise():   # in this process too, SIGTERM ends the sweep as Ctrl-C does
                for spec in specs:
                    key = spec.filename
                    res = run(spec, factories.get(spec.controller), record=record,
                              progress=lambda t, tot, k=key, s=spec: board.report(k, _label(s), t, tot))
                    on_result(res)
                    board.finish(key, _note(res))
            return
        ctx = mp.get_context("spawn")   # no inherited PyBullet/CasADi/BLAS state from the parent
        q = ctx.Queue()
        stop = threading.Event()
        labels = {s.filename: _label(s) for s in specs}

        def pump() -> None:
            while not stop.is_set():
                try:
                    key, t, total = q.get(timeout=0.2)
                except queue_mod.Empty:
                    continue
                except (EOFError, OSError):   # queue torn down at shutdown
                    return
                board.report(key, labels.get(key, key), t, total)

        thread = threading.Thread(target=pump, daemon=True)
        thread.start()
        pool = cf.ProcessPoolExecutor(max_workers=min(jobs, len(specs)), mp_context=ctx,
                                      initializer=_init_worker, initargs=(q, os.getpid()))
        with interrupts_raise():
            try:
                futures = {pool.submit(_local_task, s, factories.get(s.controller), record, task): s for s in specs}
                for fut in cf.as_completed(futures):
                    res = fut.result()
                    on_result(res)
                    board.finish(futures[fut].filename, _note(res))
            except BaseException:
                # Interrupted (or a run failed): stop the runs in flight now rather than letting the
                # pool finish them - workers write nothing, so killing them loses no finished result.
                procs = list((getattr(pool, "_processes", None) or {}).values())
                pool.shutdown(wait=False, cancel_futures=True)
                for p in procs:
                    if p.is_alive():
                        p.terminate()
                for p in procs:
                    p.join(timeout=5.0)
                raise
            else:
                pool.shutdown(wait=True)
            finally:
                stop.set()
                thread.join(timeout=2.0)
                q.close()
    finally:
        board.close()


# ------------------------------------------------------------------ ray
def run_ray(specs: Sequence[RunSpec], on_result: OnResult, *, address: str | None = None, jobs: int | None = None,
            factories: Mapping[str, Any] | None = None, record: bool = True, progress: bool = True,
            task: Task | None = None) -> None:
    """Run ``specs`` as Ray tasks (one CPU each). Without ``address`` a local Ray instance with
    ``jobs`` CPUs is started (and stopped afterwards); with ``address`` (``"auto"`` or
    ``"ray://host:10001"``) an existing cluster is used - its nodes need this package installed.
    An already initialised Ray session is used as it is."""
    ray = import_ray()
    factories = dict(factories or {})
    started = init_ray(address, None if address else check_jobs(jobs))
    board = ProgressBoard(len(specs), progress)
    remote = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
    refs: dict[Any, RunSpec] = {}
    with interrupts_raise():   # SIGTERM: cancel the tasks and stop the local Ray instance
        try:
            refs = {remote.remote(s, factories.get(s.controller), record, task): s for s in specs}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    res = ray.get(ref)
                    on_result(res)
                    board.finish(refs[ref].filename, _note(res))
        except BaseException:
            for ref in refs:
                try:
                    ray.cancel(ref, force=True)
                except Exception:   # already finished or gone
                    pass
            raise
        finally:
            board.close()
            if started:
                ray.shutdown()


def _ray_task(spec: RunSpec, factory: Any, record: bool, task: Task | None = None) -> RunResult:
    try:
        return (task or execute)(spec, factory, record=record)
    finally:
        release_free_heap()


def check_jobs(jobs: int | None) -> int:
    """``jobs`` as a positive int (default: the number of cores)."""
    if jobs is None:
        return os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be a positive integer, got {jobs!r}")
    return jobs


def run_specs(backend: str, specs: Sequence[RunSpec], on_result: OnResult, *, jobs: int | None = None,
              address: str | None = None, factories: Mapping[str, Any] | None = None, record: bool = True,
              progress: bool = True, task: Task | None = None) -> None:
    """Dispatch to :func:`run_local` or :func:`run_ray` (``task``: see :data:`Task`)."""
    if backend == "local":
        if address:
            raise ValueError(f"address {address!r} is only used by the ray backend")
        run_local(specs, on_result, jobs=jobs, factories=factories, record=record, progress=progress, task=task)
    elif backend == "ray":
        run_ray(specs, on_result, address=address, jobs=jobs, factories=factories, record=record,
                progress=progress, task=task)
    else:
        raise ValueError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
