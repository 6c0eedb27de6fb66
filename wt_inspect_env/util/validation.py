"""Input validation helpers shared by every module.

Every public constructor checks its inputs with these helpers so that bad input fails early with a
``ValueError`` that names the offending field and its value, instead of a traceback from deep inside
NumPy, CasADi or PyBullet.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import re
from typing import Any, Iterable, Mapping

import numpy as np


def _not_a_number(value: Any) -> bool:
    """True for values ``float()`` would accept but that are not numbers: text (``"5"`` would
    pass validation and fail later, in arithmetic), bools (``True`` is not a length) and complex
    numbers (whose imaginary part a cast would drop)."""
    return isinstance(value, (str, bytes, bool, np.bool_, complex, np.complexfloating))


def check_finite(name: str, value: Any) -> float:
    """Return ``value`` as a float, or raise if it is not a finite real number (strings, bools and
    complex numbers are refused, not converted)."""
    if _not_a_number(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
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


def check_positive_int(name: str, value: Any) -> int:
    """``value`` as an int if it is an integer >= 1 (not a bool); else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_range(name: str, value: Any, lo: float, hi: float) -> float:
    """Return ``value`` as a float, or raise if it lies outside ``[lo, hi]``."""
    v = check_finite(name, value)
    if not lo <= v <= hi:
        raise ValueError(f"{name} must lie in [{lo}, {hi}], got {value!r}")
    return v


def check_array(name: str, value: Any, shape: tuple[int | None, ...] | None = None) -> np.ndarray:
    """Return ``value`` as a finite float64 array of the given shape (``None`` = any length).
    Complex, text and bool arrays are refused rather than cast (a cast drops the imaginary part
    or parses text)."""
    arr = real_array(name, value, shape)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {np.array2string(arr, threshold=12)}")
    return arr


ACTION_TOLERANCE = 1e-6   # |a| up to 1 + this is inside the box (float32 rounding of a clipped action)


def check_actions(value: Any, shape: tuple[int, ...] = (4,), name: str = "action") -> np.ndarray:
    """Normalised action(s) as a float64 array of ``shape`` - ``(4,)`` for the single env,
    ``(n, 4)`` for the vector env - each entry finite and in [-1, 1]; otherwise a one-line
    ValueError naming ``name`` (and, for a batch, the first bad row). The one validation of actions,
    so both envs refuse the same input (text, complex, bool, ragged, NaN, out of the box) alike."""
    a = real_array(name, value, shape)
    for bad, must in ((~np.isfinite(a), "be finite"), (np.abs(a) > 1.0 + ACTION_TOLERANCE, "lie in [-1, 1]")):
        if bad.any():
            if a.ndim == 2:
                row = int(np.flatnonzero(bad.any(axis=1))[0])
                raise ValueError(f"{name} must {must}, got {name}[{row}] = {a[row].tolist()}")
            box = "^4" if must != "be finite" and a.shape == (4,) else ""
            raise ValueError(f"{name} must {must}{box}, got {np.array2string(a)}")
    return a


def real_array(name: str, value: Any, shape: tuple[int | None, ...] | None = None) -> np.ndarray:
    """:func:`check_array` without the finiteness check: ``value`` as a float64 array of ``shape``,
    text, bool and complex entries (also inside an object array) refused."""
    try:
        raw = value if isinstance(value, np.ndarray) else np.asarray(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {value!r}") from None
    if raw.dtype.kind in "cbUSO" and not (raw.dtype.kind == "O" and _all_real(raw)):
        raise ValueError(f"{name} must be a real numeric array, got {_one_line(value)} (dtype {raw.dtype})")
    try:
        arr = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array, got {value!r}") from None
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name} must have shape {want}, got shape {arr.shape}")
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


def json_object_option(option: str, text: str | None) -> dict[str, Any]:
    """The JSON object a command-line ``option`` was given - inline, or the path of a ``.json`` file
    holding it; None or empty: ``{}``. Anything else is a one-line ValueError naming ``option``
    (JSON is data: nothing in it runs)."""
    import json
    from pathlib import Path

    if not text:
        return {}
    src = text
    if not text.lstrip().startswith("{") and text.endswith(".json"):
        p = Path(text)
        if not p.is_file():
            raise ValueError(f"{option} file {text!r} not found")
        src = p.read_text()
    try:
        data = json.loads(src)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{option} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{option} must be a JSON object, got {_one_line(text)}")
    return data


def _one_line(value: Any) -> str:
    """``repr(value)`` on one line (numpy prints a 2-D array over several)."""
    return " ".join(repr(value).split())


def _all_real(arr: np.ndarray) -> bool:
    """An object array (ragged input, Python objects) holds only real numbers."""
    return all(isinstance(v, (int, float, np.integer, np.floating)) and not _not_a_number(v)
               for v in arr.reshape(-1))


_NUMERIC = {"float", "int"}
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z_0-9.]*")


@functools.lru_cache(maxsize=None)
def _field_kinds(cls: type) -> tuple[tuple[str, str], ...]:
    """``(field name, kind)`` for the fields of dataclass ``cls`` whose annotation promises only
    numbers (``number``: ``float``/``int``, optionally ``| None``), tuples of numbers
    (``numbers``) or a bool (``bool``). Annotations are read as text (the modules use
    ``from __future__ import annotations``), so no forward reference needs resolving."""
    out = []
    for f in dataclasses.fields(cls):
        ann = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        tokens = set(_TOKEN.findall(ann)) - {"None"}
        if ann.startswith("tuple[") and tokens - {"tuple"} and tokens - {"tuple"} <= _NUMERIC:
            out.append((f.name, "numbers"))
        elif tokens and tokens <= _NUMERIC:
            out.append((f.name, "number"))
        elif tokens == {"bool"}:
            out.append((f.name, "bool"))
    return tuple(out)


def check_field_types(obj: Any, prefix: str = "") -> None:
    """Refuse, at construction, a value of the wrong kind in any numeric or bool field of the
    dataclass ``obj`` (as its annotation states): text, bools and complex numbers for numbers
    (``time_limit_s="5"`` would otherwise pass a ``float()`` check and fail in arithmetic many
    steps later), anything but a bool for a bool. One generic check, called first in every
    configuration dataclass's ``__post_init__``, so a new field is covered without code."""
    for name, kind in _field_kinds(type(obj)):
        value = getattr(obj, name)
        label = f"{prefix}{name}"
        if kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{label} must be a bool (true/false), got {value!r}")
        elif kind == "number":
            if _not_a_number(value):
                raise ValueError(f"{label} must be a number, got {value!r}")
        elif isinstance(value, (str, bytes)) or any(_not_a_number(v) for v in _iter(value)):
            raise ValueError(f"{label} must be a sequence of numbers, got {value!r}")


def _iter(value: Any) -> Iterable[Any]:
    if value is None:
        return ()
    try:
        return list(np.asarray(value, dtype=object).reshape(-1))
    except (TypeError, ValueError):
        return (value,)


def coerce_config(name: str, value: Any, cls: type) -> Any:
    """A dataclass instance from an instance, a mapping of its fields, or None (defaults)."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        check_unknown_options(name, value.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**dict(value))
    raise ValueError(f"{name} must be a {cls.__name__} or a dict of its fields, got {value!r}")
