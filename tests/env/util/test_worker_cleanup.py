"""Evaluation workers die with their parent (issue 17): after SIGKILL or SIGTERM of
``wt-inspect evaluate`` no pool worker and no resource tracker stays alive - nor, on the Ray
backend, any of the private Ray instance's processes (GCS, raylet, its workers; issue 30). Linux
only (the process tree is read from /proc; psutil is not a dependency)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")


def _ppid_map() -> dict[int, int]:
    out = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            out[int(d.name)] = int(stat[stat.rindex(")") + 2:].split()[1])
    return out


def _descendants(pid: int) -> set[int]:
    ppid = _ppid_map()
    found, frontier = set(), {pid}
    while frontier:
        frontier = {c for c, p in ppid.items() if p in frontier} - found
        found |= frontier
    return found


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:   # a zombie (exited, not yet reaped by its new parent) is not running
        return (Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]) != "Z"
    except OSError:
        return False


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _ray_worker_running(pids: set[int]) -> bool:
    """A Ray worker running one of the evaluation's tasks is among ``pids`` (Ray names a worker's
    process after the task it runs; idle workers are started with the instance, before the
    driver's handlers are in place)."""
    return any("_ray_task" in _cmdline(p) for p in pids)


@pytest.mark.slow
@pytest.mark.parametrize("backend,sig", [("local", signal.SIGKILL), ("local", signal.SIGTERM),
                                         ("ray", signal.SIGKILL), ("ray", signal.SIGTERM)])
def test_no_worker_survives_the_evaluation(tmp_path, backend, sig) -> None:
    if backend == "ray":
        pytest.importorskip("ray")
    cmd = [sys.executable, "-m", "wt_inspect.cli", "evaluate", "--scenario", "surface",
           "--controllers", "vtnmpc,nmpc", "--winds", "0", "--jobs", "2", "--no-figures", "--no-progress",
           "--backend", backend, "--out", str(tmp_path / "ev")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    children: set[int] = set()

    def started() -> bool:   # local: the two workers and the resource tracker; ray: a task's worker
        return _ray_worker_running(children) if backend == "ray" else len(children) >= 3

    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            children = _descendants(proc.pid)
            if started():
                break
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.2)
        assert started(), f"workers never started: {children}"
        time.sleep(1.0)   # workers past their initializer, flying
        children = _descendants(proc.pid)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(sig)
        proc.wait(timeout=60)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(p) for p in children):
            time.sleep(0.2)
        survivors = {p: _cmdline(p)[:120] for p in children if _alive(p)}
        assert not survivors, f"still alive after {sig.name} ({backend}): {survivors}"
        if sig == signal.SIGTERM:   # handled like Ctrl-C: a one-line message, exit 130
            assert proc.returncode == 130
            assert "interrupted" in proc.stderr.read()
    finally:
        for p in children | _descendants(proc.pid) | {proc.pid}:
            if _alive(p):
                os.kill(p, signal.SIGKILL)


_DRIVER = """
import subprocess, sys, time
from wt_inspect_env.util.ray_reaper import Reaper
mine = subprocess.Popen(["sleep", "300"])             # the driver's own, before the instance: not reaped
reaper = Reaper()
reaper.start()
tree = subprocess.Popen(["sh", "-c", "sleep 300 & sleep 300"])   # the 'instance': a child with a child
if sys.argv[1] == "named":
    reaper.started()
print(mine.pid, tree.pid, flush=True)
time.sleep(300)
"""


@pytest.mark.slow
@pytest.mark.parametrize("when", ["named", "starting"])
def test_the_reaper_kills_the_instance_not_the_drivers_other_children(tmp_path, when) -> None:
    """A stand-in for a driver with a private Ray instance, SIGKILLed after the reaper was told the
    instance's processes (``named``) or while the instance was starting (``starting``): the
    instance's process tree dies, a child the driver had before does not."""
    proc = subprocess.Popen([sys.executable, "-c", _DRIVER, when], stdout=subprocess.PIPE, text=True)
    mine = tree = None
    try:
        mine, tree = map(int, proc.stdout.readline().split())
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not _descendants(tree):
            time.sleep(0.05)
        instance = {tree} | _descendants(tree)
        assert len(instance) >= 2, instance
        time.sleep(1.0)   # the reaper has polled the tree
        proc.kill()
        proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(p) for p in instance):
            time.sleep(0.1)
        assert not [p for p in instance if _alive(p)]
        assert _alive(mine)
    finally:
        for p in [q for q in (mine, tree) if q] + list(_descendants(proc.pid)) + [proc.pid]:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
