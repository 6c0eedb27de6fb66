"""release_free_heap gives freed C-heap pages back (the campaign's flat-memory measure relies on it)."""
from __future__ import annotations

import ctypes
import sys

import pytest

from wt_inspect_env.util.process_memory import release_free_heap, rss_mb


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc_trim")
def test_freed_heap_pages_stay_resident_until_trimmed():
    libc = ctypes.CDLL("libc.so.6")
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    libc.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
    release_free_heap()
    base = rss_mb()
    blocks = [libc.malloc(4096) for _ in range(40_000)]       # ~160 MB below the mmap threshold
    for b in blocks:
        libc.memset(b, 1, 4096)                                # touched: resident
    for b in blocks[:-1]:
        libc.free(b)                                           # the last block pins the heap top
    held = rss_mb()
    assert held - base > 100                                   # glibc kept the freed pages
    assert release_free_heap() is True
    trimmed = rss_mb()
    libc.free(blocks[-1])
    assert held - trimmed > 100                                # and gave them back when asked
