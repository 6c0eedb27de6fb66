"""The process's own memory: its resident set, and giving freed C-heap pages back to the OS.

Kept apart from the benchmarks' timing references (which import PyBullet) so that the evaluation
backends can use it without loading the simulator before their argument checks.
"""
from __future__ import annotations

import ctypes
import resource
import sys


def rss_mb() -> float:
    """Current resident set size [MB] (Linux /proc; falls back to the peak)."""
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return pages * resource.getpagesize() / 2**20
    except OSError:  # pragma: no cover
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def release_free_heap() -> bool:
    """Return the C heap's free pages to the OS (glibc ``malloc_trim(0)``); True if it ran.

    A long-lived worker that builds a turbine, a mission and solvers per episode frees them again,
    but glibc keeps the freed arena pages: its resident set then grows in steps with the largest
    episode so far and never shrinks, which reads as a leak in a memory trace. Trimming after each
    episode makes the resident set measure what is still allocated. A no-op off glibc."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        trim = ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):   # musl, or no libc under that name
        return False
    trim(0)   # its result only says whether pages were released
    return True
