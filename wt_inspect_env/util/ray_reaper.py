"""Reaps what is left of a private local Ray instance once the process that started it is gone.

Ray ties its GCS server, raylet and task workers to the driver that started them, so a killed
driver takes those down within a second. Its dashboard and runtime-env agents do not: they
notice the dead raylet, then try to report to the dead GCS and linger for about a minute, and a
``SIGKILL`` of the driver skips ``ray.shutdown`` altogether. Running many ``wt-inspect`` drivers
(a campaign resumed after a kill, a scheduler's retries) would pile such processes up.

:class:`Reaper` starts ``python -m wt_inspect_env.util.ray_reaper DRIVER`` before ``ray.init`` and
names the Ray processes the driver started once it has returned; the reaper follows the process
subtrees under them (under every new child of the driver until they are named),
and once the driver is gone or the roots have exited it ``SIGKILL``s every process seen in those
subtrees that is still alive. A process
is identified by its pid and start time, so a reused pid is never hit. Linux only (``/proc``);
elsewhere no reaper is started and Ray's own clean-up is all there is.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

POLL_S = 0.5
_PROC = Path("/proc")


def supported() -> bool:
    """Whether this system exposes the process table the reaper reads."""
    return (_PROC / "self" / "stat").is_file()


def _stat(pid: int) -> tuple[int, int, str] | None:
    """(parent pid, start time in clock ticks, state) of a live process; None when it is gone."""
    try:
        text = (_PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()   # after the command name, which may hold spaces
    return int(fields[1]), int(fields[19]), fields[0]


def children(pid: int) -> set[int]:
    """The direct children of ``pid`` now."""
    out = set()
    for d in _PROC.iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None and st[0] == pid:
                out.add(int(d.name))
    return out


def _subtree(roots: dict[int, int]) -> dict[int, int]:
    """pid -> start time of every live process under (and including) the live ``roots``."""
    table: dict[int, tuple[int, int]] = {}
    for d in _PROC.iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None and st[2] != "Z":
                table[int(d.name)] = (st[0], st[1])
    found = {p: t for p, t in roots.items() if table.get(p, (0, -1))[1] == t}
    frontier = set(found)
    while frontier:
        frontier = {p for p, (pp, _) in table.items() if pp in frontier and p not in found}
        found.update({p: table[p][1] for p in frontier})
    return found


def _ray_children_of(raylets: set[int]) -> dict[int, int]:
    """pid -> start time of live processes a raylet of ``raylets`` started (Ray's agents and
    workers carry their raylet's pid in ``RAY_RAYLET_PID``), also after that raylet died and they
    were re-parented - which happens within milliseconds of the driver's death."""
    keys = {f"RAY_RAYLET_PID={p}".encode() for p in raylets}
    out = {}
    for d in _PROC.iterdir():
        if d.name.isdigit():
            try:
                env = (d / "environ").read_bytes().split(b"\0")
            except OSError:
                continue
            if keys.intersection(env) and (st := _stat(int(d.name))) is not None:
                out[int(d.name)] = st[1]
    return out


def _kill(known: dict[int, int], rounds: int = 3, pause_s: float = 0.2) -> int:
    """SIGKILL every process of ``known``, its live descendants and what its raylets started,
    each only while it is still the process seen (same start time); a few rounds, for what a
    dying parent started meanwhile."""
    n = 0
    for k in range(rounds):
        known.update(_subtree(known))
        known.update(_ray_children_of(set(known)))
        for pid, start in known.items():
            st = _stat(pid)
            if st is not None and st[1] == start and st[2] != "Z" and pid != os.getpid():
                try:
                    os.kill(pid, signal.SIGKILL)
                    n += 1
                except OSError:
                    pass
        if k + 1 < rounds:
            time.sleep(pause_s)
    return n


def reap(driver: int, before: dict[int, int], source=None, poll_s: float = POLL_S) -> int:
    """Follow the Ray processes of ``driver`` until it is no longer this process's parent or every
    root has exited (``ray.shutdown``, or Ray's own fate-sharing after the driver died); then kill
    what is left of what was seen. Returns how many processes were killed.

    Until the driver names the roots (one line ``pid:start ...`` on ``source``, sent once
    ``ray.init`` has returned), every child of the driver not in ``before`` (its children before
    ``ray.init``) and not this process counts as one: a driver killed while Ray is starting
    leaves nothing behind either."""
    import select

    me = os.getpid()
    roots: dict[int, int] | None = None
    known: dict[int, int] = {}
    while True:
        if roots is None and source is not None and select.select([source], [], [], 0)[0]:
            line = source.readline()
            if line.strip():
                roots = {int(p): int(t) for p, t in (a.split(":") for a in line.split())}
            source = None   # a line, or EOF (the driver is gone): nothing more comes
        live = roots if roots is not None else {
            p: st[1] for p in children(driver) if p != me and (st := _stat(p)) is not None and before.get(p) != st[1]}
        now = _subtree(live)
        known.update(now)
        if os.getppid() != driver or (roots is not None and not any(p in now for p in roots)):
            return _kill(known)
        time.sleep(poll_s)


class Reaper:
    """The reaper of one private Ray instance, started before ``ray.init`` (:meth:`start`) and
    told its roots after it (:meth:`started`). Inert where unsupported."""

    def __init__(self) -> None:
        self._proc: subprocess.Popen | None = None
        self._before: set[int] = set()

    def start(self) -> None:
        """Start the reaper process, telling it which of this process's children existed before Ray."""
        if not supported():
            return
        me = os.getpid()
        self._before = children(me)
        before = [f"{p}:{st[1]}" for p in self._before if (st := _stat(p)) is not None]
        # no pipes of the driver's held open but stdin, the roots' channel (a caller reading the
        # driver's output to EOF must not wait for us); a terminal's Ctrl-C reaches it and is ignored
        self._proc = subprocess.Popen([sys.executable, "-m", __name__, str(me), *before], stdin=subprocess.PIPE,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, close_fds=True, text=True)

    def started(self) -> None:
        """Name the roots: the driver's children that appeared since :meth:`start`."""
        if self._proc is None or self._proc.stdin is None:
            return
        roots = children(os.getpid()) - self._before - {self._proc.pid}
        line = " ".join(f"{p}:{st[1]}" for p in roots if (st := _stat(p)) is not None)
        try:
            self._proc.stdin.write(line + "\n")
            self._proc.stdin.close()
        except OSError:   # the reaper is gone: nothing to tell
            pass


def main(argv: list[str]) -> int:
    """Run the reaper process (arguments in ``argv``); it ignores Ctrl-C and SIGTERM so that it can clean up."""
    # the driver handles Ctrl-C / SIGTERM and shuts Ray down; the reaper must outlive it to clean up
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    driver = int(argv[0])
    before = {int(p): int(t) for p, t in (a.split(":") for a in argv[1:])}
    reap(driver, before, sys.stdin)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
