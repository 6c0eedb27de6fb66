"""Containment of a PyBullet reference leak: mesh lists passed to ``createCollisionShape`` /
``createVisualShape`` are never released.

PyBullet's C code takes new references to the ``vertices`` / ``indices`` (/ ``uvs``, ``normals``)
sequences and to every inner vertex list (``PySequence_Fast`` / ``PySequence_GetItem``) and never
drops them, so every mesh handed to it stays alive for the life of the process - each
``gym.make``/``close`` cycle kept one copy of the turbine mesh as Python lists (issue 17).

:func:`call_releasing` calls such a function and then drops exactly the references the call took
and kept, *measured* on the arguments (``sys.getrefcount`` before and after): a PyBullet that
fixes the bug leaks nothing, the measured excess is 0 and nothing is released. It only releases
when the measurement is unambiguous (the same small excess on the outer list and on the first
and last inner lists), otherwise it leaves the references alone - a leak is better than a freed
object still in use. The lists must be private to the caller during the call (built for it, not
shared with other threads), which the simulator's are.
"""
from __future__ import annotations

import ctypes
import sys
from typing import Any, Callable, TypeVar

T = TypeVar("T")
MAX_LEAKED_REFS = 4   # PyBullet 3.2.x keeps 2 per call; anything larger is not understood, so left alone
_decref = ctypes.pythonapi.Py_DecRef
_decref.argtypes = [ctypes.py_object]
_decref.restype = None


def _counts(seq: list) -> tuple[int, int, int]:
    inner = [x for x in (seq[0], seq[-1]) if isinstance(x, list)] if seq else []
    first = sys.getrefcount(inner[0]) if inner else 0
    last = sys.getrefcount(inner[-1]) if inner else 0
    return sys.getrefcount(seq), first, last


def call_releasing(fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> T:
    """``fn(*args, **kwargs)``, then release the references it leaked on the list arguments
    (and on their inner lists), as measured (see the module docstring)."""
    lists = [v for v in kwargs.values() if isinstance(v, list) and v]
    # the same access pattern before and after, so the counts differ only by what fn kept
    before = []
    for i in range(len(lists)):
        before.append(_counts(lists[i]))
    result = fn(*args, **kwargs)
    for i in range(len(lists)):
        o1, f1, l1 = _counts(lists[i])
        o0, f0, l0 = before[i]
        seq = lists[i]
        outer = o1 - o0
        if not 0 < outer <= MAX_LEAKED_REFS:
            continue
        has_inner = isinstance(seq[0], list)
        inner = f1 - f0
        if has_inner and (inner != l1 - l0 or not 0 <= inner <= MAX_LEAKED_REFS):
            continue   # not uniform: do not guess
        for _ in range(outer):
            _decref(seq)
        if has_inner and inner:
            for item in seq:
                if isinstance(item, list):
                    for _ in range(inner):
                        _decref(item)
    return result
