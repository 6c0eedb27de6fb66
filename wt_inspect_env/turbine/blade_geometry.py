"""Parametric wind-turbine blades: chord, twist and relative thickness given along the span.

A :class:`BladeShape` is a table of span stations (radius from the rotor centre [m]) with the
chord [m], the aerodynamic twist [deg] and the relative thickness t/c at each; between stations
the values are interpolated linearly (as the tables of reference turbines are meant to be read).

Section (:func:`section_contour`): at t/c = 1 a circle (the cylindrical root of a real blade), at
t/c <= ``AEROFOIL_TC`` a NACA four-digit-like aerofoil of that thickness with a small camber, and
a blend of the two in between (the root-to-aerofoil transition). The contour is a closed loop of
points ``(x, y)`` in chord units, counter-clockwise: the leading edge at ``x = 0``, the trailing edge
at ``x = 1``, the cambered (suction) side at ``y > 0``. The shape is aerofoil-*like* (what an
inspection camera and a clearance check need: rounded nose, thin trailing edge, the right chord,
thickness and twist), not a specific aerodynamic profile.

Placement (:func:`blade_grid`): the section is placed in the plane normal to the blade's span
direction ``radial`` with its pitch axis (``pitch_axis`` of the chord from the leading edge, 0.5
for the circle, blended to ``pitch_axis`` for the aerofoil) on the span line. At twist 0 the chord
lies in the rotor plane, the leading edge towards ``chord = axis x radial`` (the rotor turns about
``-axis``, so that edge leads) and the suction side faces ``+axis``; a positive twist turns the
leading edge towards ``+axis`` (right-handed about ``-radial``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..util.validation import check_field_types, check_range, check_unknown_options

AEROFOIL_TC = 0.40        # at or below this relative thickness the section is a pure aerofoil
CAMBER = 0.02             # maximum camber of the aerofoil (chord units), at 40 % chord
CAMBER_AT = 0.4


@dataclass(frozen=True)
class BladeShape:
    """Span table of a blade (stations as radius from the rotor centre, metres; twist in degrees).

    ``span`` must increase strictly; ``chord`` > 0; ``thickness`` (t/c) in (0, 1]; all four tables
    of equal length (at least two stations). ``pitch_axis``: chord fraction from the leading edge
    about which the aerofoil sections are twisted (the circular root is centred).
    """

    span: tuple[float, ...]
    chord: tuple[float, ...]
    twist_deg: tuple[float, ...]
    thickness: tuple[float, ...]
    pitch_axis: float = 0.25

    def __post_init__(self) -> None:
        check_field_types(self, "blade ")
        n = None
        for name in ("span", "chord", "twist_deg", "thickness"):
            raw = getattr(self, name)
            try:
                arr = np.asarray(raw, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"blade {name} must be a list of numbers, got {raw!r}") from None
            if arr.ndim != 1 or len(arr) < 2 or not np.all(np.isfinite(arr)):
                raise ValueError(f"blade {name} must be a list of at least 2 finite numbers, got {raw!r}")
            if n is not None and len(arr) != n:
                raise ValueError(f"blade {name} has {len(arr)} values but span has {n}: the chord, twist_deg "
                                 "and thickness tables must have one value per span station")
            n = len(arr) if n is None else n
            object.__setattr__(self, name, tuple(float(v) for v in arr))
        span = np.asarray(self.span)
        if np.any(np.diff(span) <= 0) or span[0] <= 0:
            raise ValueError(f"blade span must be positive and strictly increasing, got {list(self.span)!r}")
        if min(self.chord) <= 0:
            raise ValueError(f"blade chord must be positive, got {list(self.chord)!r}")
        if min(self.thickness) <= 0 or max(self.thickness) > 1:
            raise ValueError(f"blade thickness (t/c) must lie in (0, 1], got {list(self.thickness)!r}")
        object.__setattr__(self, "pitch_axis", check_range("blade pitch_axis", self.pitch_axis, 0.05, 0.95))

    @classmethod
    def from_value(cls, value: Any) -> "BladeShape":
        """From an instance or a mapping of the fields (e.g. parsed JSON)."""
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            check_unknown_options("blade", value.keys(), ["span", "chord", "twist_deg", "thickness", "pitch_axis"])
            missing = [k for k in ("span", "chord", "twist_deg", "thickness") if k not in value]
            if missing:
                raise ValueError(f"blade {missing[0]} is missing: a blade shape needs span, chord, twist_deg and "
                                 f"thickness tables of one value per span station (got {sorted(value)})")
            return cls(**dict(value))
        raise ValueError(f"blade must be a dict with span, chord, twist_deg and thickness, got {value!r}")

    @property
    def root(self) -> float:
        """Span position [m] of the first station (the blade root)."""
        return self.span[0]

    @property
    def tip(self) -> float:
        """Span position [m] of the last station (the tip)."""
        return self.span[-1]

    @property
    def length(self) -> float:
        """Blade length [m] from root to tip station."""
        return self.span[-1] - self.span[0]

    @property
    def max_chord(self) -> float:
        """Largest chord [m] over the stations."""
        return max(self.chord)

    @property
    def max_thickness(self) -> float:
        """Largest absolute thickness [m] (chord x t/c) over the stations."""
        return float(max(c * t for c, t in zip(self.chord, self.thickness)))

    def at(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Chord, twist [deg] and t/c at radii ``r`` (linear interpolation of the table)."""
        r = np.asarray(r, dtype=np.float64)
        return (np.interp(r, self.span, self.chord), np.interp(r, self.span, self.twist_deg),
                np.interp(r, self.span, self.thickness))

    def scaled(self, length: float) -> "BladeShape":
        """The geometrically similar blade (span, chord) of the given length, root radius scaled too."""
        k = length / self.length
        return BladeShape(tuple(k * s for s in self.span), tuple(k * c for c in self.chord), self.twist_deg,
                          self.thickness, self.pitch_axis)

    def stations(self, step: float) -> np.ndarray:
        """Radii of the mesh rings: every table station plus enough between them to be <= ``step``."""
        out = [np.array([self.span[0]])]
        for a, b in zip(self.span[:-1], self.span[1:]):
            n = max(1, math.ceil((b - a) / step - 1e-9))
            out.append(np.linspace(a, b, n + 1)[1:])
        return np.concatenate(out)


def _blend(tc: float) -> float:
    """Weight of the circle in the section (1 at t/c = 1, 0 at or below AEROFOIL_TC)."""
    return float(np.clip((tc - AEROFOIL_TC) / (1.0 - AEROFOIL_TC), 0.0, 1.0))


def section_contour(tc: float, n_half: int) -> np.ndarray:
    """Closed counter-clockwise contour ``(2 n_half - 2, 2)`` in chord units (see module docstring):
    upper side from the leading edge to the trailing edge, then the lower side back."""
    beta = np.linspace(0.0, math.pi, n_half)
    x = 0.5 * (1.0 - np.cos(beta))                          # cosine spacing: dense at both edges
    w = _blend(tc)
    t_af = min(tc, AEROFOIL_TC) if w < 1.0 else AEROFOIL_TC
    yt = 5.0 * t_af * (0.2969 * np.sqrt(x) - 0.1260 * x - 0.3516 * x ** 2 + 0.2843 * x ** 3 - 0.1036 * x ** 4)
    m, p = CAMBER * (1.0 - w), CAMBER_AT
    yc = np.where(x < p, m / p ** 2 * (2 * p * x - x ** 2), m / (1 - p) ** 2 * ((1 - 2 * p) + 2 * p * x - x ** 2))
    yr = 0.5 * np.sin(beta)                                 # the circle of diameter 1 (chord)
    upper = (1.0 - w) * (yc + yt) + w * yr
    lower = (1.0 - w) * (yc - yt) - w * yr
    # counter-clockwise in (x, y): along the lower side from the LE to the TE, then back on the upper
    xs = np.concatenate([x, x[-2:0:-1]])
    ys = np.concatenate([lower, upper[-2:0:-1]])
    return np.stack([xs, ys], axis=1)


def pitch_axis_at(shape: BladeShape, tc: float) -> float:
    """Pitch-axis chord fraction of a section of relative thickness ``tc``: 0.5 for the circle, blended
    to the shape's ``pitch_axis`` for the aerofoil."""
    return 0.5 * _blend(tc) + shape.pitch_axis * (1.0 - _blend(tc))


def contour_half_points(shape: BladeShape, step: float) -> int:
    """Points per side of every section contour (see :func:`blade_grid`)."""
    return max(13, math.ceil(2.2 * shape.max_chord / step / 2.0) + 2)


def blade_grid_size(shape: BladeShape, step: float) -> tuple[int, int]:
    """``(rings, contour points)`` of :func:`blade_grid` (for triangle counts before meshing)."""
    return len(shape.stations(step)), 2 * contour_half_points(shape, step) - 2


def blade_grid(shape: BladeShape, center: np.ndarray, axis: np.ndarray, radial: np.ndarray,
               step: float) -> tuple[np.ndarray, np.ndarray]:
    """Surface points ``(n_rings, n_contour, 3)`` of one blade and the radii of its rings.

    Rings at :meth:`BladeShape.stations`; each ring is the contour of the local section, placed
    and twisted as the module docstring says. ``n_contour`` is the same for every ring (so rings
    join into quads) and keeps contour points at most ``step`` apart on the widest section, with
    at least 24 points so that the normals turn smoothly round the leading edge.
    """
    radii = shape.stations(step)
    chord_dir = np.cross(axis, radial)
    n_half = contour_half_points(shape, step)
    rings = []
    c_all, tw_all, tc_all = shape.at(radii)
    for r, c, tw, tc in zip(radii, c_all, tw_all, tc_all):
        xy = section_contour(float(tc), n_half)
        xp = pitch_axis_at(shape, float(tc))
        th = math.radians(float(tw))
        le = math.cos(th) * chord_dir + math.sin(th) * axis       # towards the leading edge
        up = -math.sin(th) * chord_dir + math.cos(th) * axis      # towards the suction side
        pts = center + r * radial + (((xp - xy[:, 0]) * c)[:, None] * le) + ((xy[:, 1] * c)[:, None] * up)
        rings.append(pts)
    return np.stack(rings), radii
