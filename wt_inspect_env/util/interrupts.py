"""SIGINT and SIGTERM, one way for every command: an interrupt is a ``KeyboardInterrupt``.

Ctrl-C (SIGINT) raises ``KeyboardInterrupt`` in Python's main thread; SIGTERM (``kill``, a batch
scheduler's time limit, ``docker stop``) would end the process at once, before any report of the
finished work is written. Within :func:`interrupts_raise` SIGTERM raises :class:`Terminated`, a
``KeyboardInterrupt``, instead, so each command has a single path for both signals, in every
phase and with any number of worker processes: the finished work is kept, its report is written
(marked incomplete) and the command exits with :data:`EXIT_INTERRUPTED`.

:func:`interrupts_deferred` protects the writing of that report: a second signal (an impatient
second Ctrl-C) is noted instead of cutting the report short, and raised once it is written.

Both only act in the main thread (the only one Python delivers signals to); elsewhere they change
nothing.
"""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Any, Iterator

#: exit code of an interrupted command, SIGINT and SIGTERM alike (128 + SIGINT, the shell's code
#: for Ctrl-C: the one code scripts test for "interrupted, rerun to resume").
EXIT_INTERRUPTED = 130


class Terminated(KeyboardInterrupt):
    """SIGTERM received (handled like Ctrl-C: the command stops, keeps and reports its work)."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(f"signal {signum}")
        self.signum = signum


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def interrupts_raise() -> Iterator[None]:
    """Within the block SIGTERM raises :class:`Terminated` in the main thread (SIGINT keeps
    raising ``KeyboardInterrupt``; an ignored SIGTERM stays ignored). The previous handler is
    restored on leaving; nested uses are fine."""
    if not _in_main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous == signal.SIG_IGN:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise Terminated(signum)
    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def interrupts_deferred(raise_noted: bool = True) -> Iterator[list[int]]:
    """Within the block SIGINT and SIGTERM are noted, not raised (the block - writing a report -
    runs to its end); on leaving, the first noted signal is raised as ``KeyboardInterrupt`` /
    :class:`Terminated` (unless ``raise_noted`` is False - the caller re-raises the interrupt it
    is already handling - or an exception propagates from the block). Yields the list of noted
    signal numbers."""
    noted: list[int] = []
    if not _in_main_thread():
        yield noted
        return
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def note(signum: int, frame: Any) -> None:
        noted.append(signum)
    for s, old in previous.items():
        if old != signal.SIG_IGN:
            signal.signal(s, note)
    try:
        yield noted
    finally:
        for s, old in previous.items():
            signal.signal(s, old if old is not None else signal.SIG_DFL)
    if noted and raise_noted:
        raise Terminated(noted[0]) if noted[0] == signal.SIGTERM else KeyboardInterrupt()


def signal_name(exc: BaseException) -> str:
    """``SIGTERM`` for a :class:`Terminated`, ``SIGINT`` for any other ``KeyboardInterrupt``."""
    return signal.Signals(getattr(exc, "signum", signal.SIGINT)).name


def interrupted_message(exc: BaseException, out: Any, what: str = "runs",
                        reports: str = "results.md and results.csv") -> str:
    """The one line an interrupted sweep prints: which signal, where the finished work is, that
    the reports list it marked incomplete, and how to resume (or that nothing was written yet,
    when the signal came before ``out/results.md`` was)."""
    from pathlib import Path
    if out is None or not (Path(out) / "results.md").is_file():
        return f"interrupted ({signal_name(exc)}) before any {what} finished; nothing written"
    return (f"interrupted ({signal_name(exc)}); the finished {what} are kept in {out} and listed in its {reports} "
            f"(marked incomplete) - rerun the same command to resume")
