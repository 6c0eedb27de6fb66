"""Evaluation workers die with their parent (issue 17): after SIGKILL or SIGTERM of
``wt-inspect evaluate`` no pool worker and no resource tracker stays alive. Linux only (the
process tree is read from /proc; psutil is not a dependency)."""
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


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_no_worker_survives_the_evaluation(tmp_path, sig) -> None:
    cmd = [sys.executable, "-m", "wt_inspect.cli", "evaluate", "--scenario", "surface",
           "--controllers", "vtnmpc,nmpc", "--winds", "0", "--jobs", "2", "--no-figures", "--no-progress",
           "--out", str(tmp_path / "ev")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    children: set[int] = set()
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:   # the two workers and the resource tracker
            children = _descendants(proc.pid)
            if len(children) >= 3:
                break
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.2)
        assert len(children) >= 3, f"workers never started: {children}"
        time.sleep(1.0)   # workers past their initializer, flying
        children = _descendants(proc.pid)
        proc.send_signal(sig)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(_alive(p) for p in children):
            time.sleep(0.2)
        survivors = [p for p in children if _alive(p)]
        assert not survivors, f"still alive after {sig.name}: {survivors}"
        if sig == signal.SIGTERM:   # handled like Ctrl-C: a one-line message, exit 130
            assert proc.returncode == 130
            assert "interrupted" in proc.stderr.read()
    finally:
        for p in children | _descendants(proc.pid) | {proc.pid}:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
