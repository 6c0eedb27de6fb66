"""Input validation helpers shared by every module.

Every public constructor checks its inputs with these helpers so that bad input fails early with a
``ValueError`` that names the offending field and its value, instead of a traceback from deep inside
NumPy, CasADi or PyBullet.
"""
from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np


def check_finite(name: str, value: Any) -> float:
    """Return ``value`` as a float, or raise if it is not a finite real number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def check_positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a float, or raise if it is not finite and positive (or >= 0)."""
    v = check_finite(name, value)
    if v < 0 or (v == 0 and not allow_zero):
        kind = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be {kind}, got {value!r}")
    return v


def check_range(name: str, value: Any, lo: float, hi: float) -> float:
    """Return ``value`` as a float, or raise if it lies outside ``[lo, hi]``."""
    v = check_finite(name, value)
    if not lo <= v <= hi:
        raise ValueError(f"{name} must lie in [{lo}, {hi}], got {value!r}")
    return v


def check_array(name: str, value: Any, shape: tuple[int | None, ...] | None = None) -> np.ndarray:
    """Return ``value`` as a finite float64 array of the given shape (``None`` = any length)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {value!r}") from None
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name} must have shape {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {np.array2string(arr, threshold=12)}")
    return arr


def check_choice(name: str, value: Any, choices: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``choices``; otherwise raise listing the valid ones."""
    options = list(choices)
    if value not in options:
        raise ValueError(f"unknown {name} {value!r}; valid: {', '.join(map(str, options))}")
    return value


def check_unknown_options(name: str, given: Iterable[str], known: Iterable[str]) -> None:
    """Raise if ``given`` contains keys that are not in ``known`` (catches misspelt options)."""
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise ValueError(f"unknown {name} option(s) {unknown}; valid: {sorted(set(known))}")
