"""Least-squares weights of the MPCs and the rule that scales them to any stand-off and drone.

Weights (:class:`LSQWeights`) have one shape for every controller: named blocks of the residual
vector, each a number (repeated over its rows) or a tuple, laid out by the class's ``STAGE`` and
``TERMINAL`` tables, with a ``terminal_factor``.

Weight scaling. Every weight set was tuned at the paper's conditions (d_ref 7 m, the Matrice-100-like
drone), and a least-squares weight is only meaningful against the size of its residual: the same
0.1 m error is 1.4 % of a 7 m stand-off but 20 % of a 0.5 m one, and the same thrust deviation in
newtons is a larger share of a light drone's weight. So the weights given (a set, a file, a tuning)
are read as weights at those *reference* conditions, and :meth:`LSQWeights.scaled` converts them
for the instance's stand-off and drone: each block declares the unit of its residual
(:attr:`LSQWeights.UNITS`) and is multiplied by (reference size / size)^2, the sizes being
(:class:`ResidualScales`)

* length: d_ref - the geometry of the inspection scales with the stand-off;
* speed: sqrt(g d_ref), and body rate: sqrt(g / d_ref) - Froude scaling. A multirotor accelerates
  horizontally by tilting its thrust, so its accelerations are fractions of g at any size; a
  manoeuvre over a stand-off L scaled by s at the same tilt angles then takes sqrt(s) the time, at
  sqrt(s) the speed and 1/sqrt(s) the body rates. With these sizes the converged answer of a
  geometrically scaled problem (stage length scaled by sqrt(s)) is exactly the scaled answer
  (tests/controllers/test_weight_scaling.py), so the paper's damping and trade-offs carry over to any size;
* thrust: the drone's hover thrust m g - thrust deviations matter relative to the weight held;
* dimensionless residuals (attitude, heading, image coordinates): unchanged.

The clearance slack is a length too, so its prices scale with it (L2 by the squared length ratio,
L1 by the ratio; :attr:`MPCConfig.clearance_prices`). At the reference conditions every factor is
exactly 1, so the weights and every result made before the rule are unchanged;
``scale_weights=False`` applies the weights as given at any stand-off and drone.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Mapping

import numpy as np

from wt_inspect_env.physics.quadrotor import GRAVITY, QuadrotorParams, get_preset
from wt_inspect_env.util.validation import check_choice, check_field_types, check_positive

REFERENCE_D_REF = 7.0         # [m] the stand-off every weight set was tuned at (the paper's)
REFERENCE_DRONE = "matrice100"  # the drone they were tuned for
WEIGHT_UNITS = ("1", "length", "speed", "rate", "thrust")


def weight_tuple(name: str, values: Any, n: int) -> tuple[float, ...]:
    """``values`` as ``n`` finite non-negative floats; ValueError naming ``name`` otherwise."""
    try:
        vals = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} numbers, got {values!r}") from None
    if len(vals) != n:
        raise ValueError(f"{name} must have {n} entries, got {len(vals)}")
    for i, v in enumerate(vals):
        check_positive(f"{name}[{i}]", v, allow_zero=True)
    return vals


def _weight_number(name: str, value: Any) -> float:
    """One weight from JSON data: a real number (not text, not a bool), finite, >= 0."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    return check_positive(name, value, allow_zero=True)


# weights
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ResidualScales:
    """The characteristic size of each kind of residual at one stand-off and drone (the weight
    scaling rule of the module docstring): ``length`` [m], ``speed`` [m/s], ``rate`` [rad/s],
    ``thrust`` [N]."""

    length: float
    speed: float
    rate: float
    thrust: float

    @classmethod
    def of(cls, d_ref: float, params: QuadrotorParams) -> "ResidualScales":
        """Lengths by the stand-off, speeds and rates by Froude scaling of it, thrust by the
        drone's hover thrust."""
        d = check_positive("d_ref", d_ref)
        return cls(length=d, speed=math.sqrt(GRAVITY * d), rate=math.sqrt(GRAVITY / d), thrust=params.weight)

    @classmethod
    def reference(cls) -> "ResidualScales":
        """The sizes at the conditions the weight sets were tuned at (the paper's)."""
        return cls.of(REFERENCE_D_REF, get_preset(REFERENCE_DRONE))

    def factor(self, unit: str, reference: "ResidualScales") -> float:
        """The weight factor (reference size / size)^2 of a residual of ``unit``; exactly 1 for
        equal sizes."""
        check_choice("weight unit", unit, WEIGHT_UNITS)
        if unit == "1":
            return 1.0
        return (getattr(reference, unit) / getattr(self, unit)) ** 2


@dataclass(frozen=True)
class LSQWeights:
    """Diagonal least-squares weights in named blocks (the one shape of every controller).

    A subclass declares its blocks as fields - a float default for a block weighted by one number
    (repeated over the block's rows), a tuple default for one weight per row - and lays them out
    with ``STAGE`` and ``TERMINAL``: ``(field, rows)`` in the order of the stage and terminal
    residuals. :meth:`terminal_vector` is ``terminal_factor`` times the terminal layout. The block
    named ``INPUTS`` must be positive: Gauss-Newton needs a positive-definite input block
    (R + B^T P B > 0 in HPIPM's Riccati recursion), a zero input weight can leave the QP singular.
    ``UNITS`` names each block's residual unit (one of :data:`WEIGHT_UNITS`, or a tuple of them per
    row) for :meth:`scaled`.
    """

    terminal_factor: float = 1.5

    STAGE: ClassVar[tuple[tuple[str, int], ...]] = ()
    TERMINAL: ClassVar[tuple[tuple[str, int], ...]] = ()
    INPUTS: ClassVar[str] = "inputs"
    UNITS: ClassVar[Mapping[str, str | tuple[str, ...]]] = {}

    def __post_init__(self) -> None:
        check_field_types(self, "weights.")
        rows = dict(self.STAGE) | dict(self.TERMINAL)
        for f in fields(self):
            if f.name == "terminal_factor":
                continue
            value, name = getattr(self, f.name), f"weights.{f.name}"
            if isinstance(f.default, tuple):
                object.__setattr__(self, f.name, weight_tuple(name, value, rows[f.name]))
            else:
                object.__setattr__(self, f.name, check_positive(name, value, allow_zero=True))
        object.__setattr__(self, "terminal_factor",
                           check_positive("weights.terminal_factor", self.terminal_factor, allow_zero=True))
        for i, v in enumerate(np.atleast_1d(getattr(self, self.INPUTS))):
            if v == 0:
                raise ValueError(f"weights.{self.INPUTS}[{i}] must be positive (a zero input weight makes "
                                 f"the QP singular), got {float(v)!r}")

    @classmethod
    def from_mapping(cls, data: Any, *, base: "LSQWeights | None" = None, source: str = "weights") -> "LSQWeights":
        """Weights from plain data (a JSON object: field -> number, or list of numbers for a
        per-row block). Fields left out keep ``base``'s values (default: the class defaults), so a
        file may change one block. Checked before anything is built, one line naming the field and
        value: an unknown field, a list of the wrong length, a scalar for a block or a list for a
        scalar, text or a bool for a number, a negative or non-finite value. ``source`` prefixes
        the message (the file's name)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{source}: must be a JSON object of weight fields, got {type(data).__name__}")
        base = cls() if base is None else base
        if not isinstance(base, cls):
            raise ValueError(f"{source}: base weights must be {cls.__name__}, got {type(base).__name__}")
        valid = {f.name: f for f in fields(cls)}
        values: dict[str, Any] = {}
        for key, value in data.items():
            if key not in valid:
                raise ValueError(f"{source}: unknown field {key!r} (= {value!r}) for {cls.__name__}; "
                                 f"valid: {', '.join(valid)}")
            current = getattr(base, key)
            label = f"{source}: {key}"
            if isinstance(current, tuple):
                if not isinstance(value, (list, tuple)) or len(value) != len(current):
                    raise ValueError(f"{label} must be a list of {len(current)} numbers, got {value!r}")
                values[key] = tuple(_weight_number(f"{label}[{i}]", v) for i, v in enumerate(value))
            else:
                values[key] = _weight_number(label, value)
        try:
            return dataclasses.replace(base, **values)
        except ValueError as exc:   # the class's own checks (a zero input weight)
            raise ValueError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path: Any, *, base: "LSQWeights | None" = None) -> "LSQWeights":
        """Weights from a JSON file (never code: plain JSON, see :meth:`from_mapping`); a missing
        or malformed file is a one-line ValueError naming it."""
        import json
        from pathlib import Path
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise ValueError(f"weights file {str(p)!r}: cannot read: {exc.strerror or exc}") from None
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"weights file {str(p)!r}: not valid JSON: {exc}") from None
        return cls.from_mapping(data, base=base, source=f"weights file {str(p)!r}")

    def to_dict(self) -> dict[str, Any]:
        """Every field as plain JSON data (lists for per-row blocks): what :meth:`load` reads."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}

    def scaled(self, scales: ResidualScales, reference: ResidualScales | None = None) -> "LSQWeights":
        """These weights, read as weights at the ``reference`` conditions (default: the paper's,
        :meth:`ResidualScales.reference`), for residuals of the sizes ``scales``: each block times
        (reference size / size)^2 of its unit (module docstring). Equal sizes give these weights
        exactly (every factor is 1.0; a class without ``UNITS`` is usable there, and refused with
        the missing block named elsewhere - an unscaled block would silently change its weight
        relative to the others)."""
        ref = ResidualScales.reference() if reference is None else reference
        if scales == ref:
            return self
        changes: dict[str, Any] = {}
        for f in fields(self):
            if f.name == "terminal_factor":
                continue
            if f.name not in self.UNITS:
                raise ValueError(f"{type(self).__name__}.UNITS has no unit for weights.{f.name} (needed to "
                                 f"scale the weights away from the reference conditions)")
            unit, value = self.UNITS[f.name], getattr(self, f.name)
            if isinstance(value, tuple):
                units = (unit,) * len(value) if isinstance(unit, str) else tuple(unit)
                if len(units) != len(value):
                    raise ValueError(f"{type(self).__name__}.UNITS[{f.name!r}] must have {len(value)} "
                                     f"entries, got {unit!r}")
                changes[f.name] = tuple(v * scales.factor(u, ref) for v, u in zip(value, units))
            else:
                if not isinstance(unit, str):
                    raise ValueError(f"{type(self).__name__}.UNITS[{f.name!r}] must be one unit, got {unit!r}")
                changes[f.name] = value * scales.factor(unit, ref)
        return dataclasses.replace(self, **changes)

    def _vector(self, layout: tuple[tuple[str, int], ...]) -> np.ndarray:
        parts = []
        for name, n in layout:
            value = getattr(self, name)
            parts.append(np.asarray(value, dtype=float) if isinstance(value, tuple) else np.full(n, value))
        return np.concatenate(parts)

    def stage_vector(self) -> np.ndarray:
        """The stage residual's weights as a vector."""
        return self._vector(self.STAGE)

    def terminal_vector(self) -> np.ndarray:
        """The terminal residual's weights as a vector, times ``terminal_factor``."""
        return self.terminal_factor * self._vector(self.TERMINAL)
