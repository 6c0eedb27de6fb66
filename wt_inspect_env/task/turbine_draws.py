"""Random turbines: the one home of how a turbine and its stopped-rotor pose are drawn.

A campaign draws one turbine per episode, the multi-turbine vector environment one per world and
redraw; both call :meth:`TurbineDistribution.draw` so that "a random turbine" means the same thing
everywhere. A draw is one of three kinds: a ``generated`` turbine (tower height, blade length and
width uniform in their ranges, the paper's cuboid blades), the ``nrel-5mw`` preset as published, or
the preset scaled geometrically (``nrel-5mw-scaled``: every length of the preset times a factor);
plus a rotor azimuth. Every draw takes the same number of variates whatever its kind, so the k-th
draw of a stream does not depend on the kinds drawn before it (a campaign's episode k does not
depend on its earlier episodes' turbines), and the order of the variates is fixed (the campaign's
published draws rely on it).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..util.validation import check_unknown_options

# [lo, hi] of the generated turbines' dimensions [m]: around the paper's V100 (tower 95 m, blades
# 49 m x 4 m) down to a small 2 MW class machine.
SIZE_RANGES: Mapping[str, tuple[float, float]] = {"tower_height": (80.0, 130.0), "blade_length": (35.0, 60.0),
                                                  "blade_width": (2.5, 4.5)}

# The kinds of turbine and the probability of each by default.
TURBINE_KINDS: Mapping[str, float] = {"generated": 0.5, "nrel-5mw": 0.15, "nrel-5mw-scaled": 0.35}

NREL_SCALE_RANGE = (0.6, 0.95)   # 0.6: 54 m hub, 37 m blades (tips 16 m above ground); 0.95: 85 m hub

# The preset's lengths that a scaled variant multiplies (its blade follows blade_length geometrically).
NREL_SCALED_LENGTHS = ("tower_height", "tower_radius", "tower_top_radius", "hub_radius", "overhang",
                       "nacelle_radius", "nacelle_length")

# The NREL 5-MW's reported sizes (hub height, blade length, largest chord) [m], as the campaign lists them.
NREL_SIZES: Mapping[str, float] = {"tower_height": 90.0, "blade_length": 61.5, "blade_width": 4.652}

ROTOR_AZIMUTH_RANGE_DEG = (0.0, 120.0)   # three blades: every stopped pose is one of these


def nrel_turbine(scale: float) -> dict[str, Any]:
    """TurbineSpec fields of the NREL 5-MW preset scaled by ``scale`` (1: the preset itself)."""
    if scale == 1.0:
        return {"preset": "nrel-5mw"}
    from ..turbine.presets import NREL_5MW_HUB_RADIUS, NREL_5MW_TIP_RADIUS, get_turbine_preset
    preset = get_turbine_preset("nrel-5mw")
    return {"preset": "nrel-5mw", **{k: scale * float(preset[k]) for k in NREL_SCALED_LENGTHS},
            "blade_length": scale * (NREL_5MW_TIP_RADIUS - NREL_5MW_HUB_RADIUS)}


@dataclass(frozen=True)
class TurbineDraw:
    """One drawn turbine: its kind, the preset's scale (None for a generated one), its
    :class:`~wt_inspect_env.turbine.spec.TurbineSpec` fields without the pose, its reported sizes
    and its rotor azimuth."""

    kind: str
    scale: float | None
    spec: dict
    sizes: dict
    rotor_azimuth_deg: float

    def turbine_option(self) -> dict[str, Any]:
        """The env's ``turbine=`` option of this draw (the spec with its rotor azimuth)."""
        return {**self.spec, "rotor_azimuth_deg": self.rotor_azimuth_deg}

    def to_info(self) -> dict[str, Any]:
        """Flat, typed fields for an env's info (scale NaN for a generated turbine, so every draw
        has the same types and batches into arrays)."""
        return {"kind": self.kind, "scale": math.nan if self.scale is None else float(self.scale),
                **{k: float(v) for k, v in self.sizes.items()}, "rotor_azimuth_deg": self.rotor_azimuth_deg}


def _range(name: str, value: Any, lo_bound: float, hi_bound: float) -> tuple[float, float]:
    ok = isinstance(value, (list, tuple)) and len(value) == 2 and all(
        not isinstance(x, (bool, str)) and isinstance(x, (int, float)) and math.isfinite(x) for x in value)
    if not ok or not lo_bound <= value[0] <= value[1] <= hi_bound:
        raise ValueError(f"turbines.{name} must be [lo, hi] with {lo_bound:g} <= lo <= hi <= {hi_bound:g}, "
                         f"got {value!r}")
    return float(value[0]), float(value[1])


@dataclass(frozen=True)
class TurbineDistribution:
    """Where random turbines come from (see the module docstring); the defaults are the campaign's.

    kinds: ``{kind: weight}`` over ``generated``, ``nrel-5mw``, ``nrel-5mw-scaled`` (weights >= 0,
    not all 0). tower_height / blade_length / blade_width: ``[lo, hi]`` of a generated turbine [m].
    nrel_scale: ``[lo, hi]`` of the scaled preset's factor. rotor_azimuth_deg: ``[lo, hi]`` of the
    stopped rotor's azimuth [deg].
    """

    kinds: dict = field(default_factory=lambda: dict(TURBINE_KINDS))
    tower_height: tuple[float, float] = SIZE_RANGES["tower_height"]
    blade_length: tuple[float, float] = SIZE_RANGES["blade_length"]
    blade_width: tuple[float, float] = SIZE_RANGES["blade_width"]
    nrel_scale: tuple[float, float] = NREL_SCALE_RANGE
    rotor_azimuth_deg: tuple[float, float] = ROTOR_AZIMUTH_RANGE_DEG

    def __post_init__(self) -> None:
        if not isinstance(self.kinds, Mapping) or not self.kinds:
            raise ValueError(f"turbines.kinds must be a non-empty dict of kind: weight, got {self.kinds!r}")
        for kind, w in self.kinds.items():
            if kind not in TURBINE_KINDS:
                raise ValueError(f"turbines.kinds: unknown turbine kind or preset {kind!r}; valid: "
                                 f"{', '.join(TURBINE_KINDS)}")
            if isinstance(w, (bool, str)) or not isinstance(w, (int, float)) or not math.isfinite(w) or w < 0:
                raise ValueError(f"turbines.kinds[{kind!r}] must be a weight >= 0, got {w!r}")
        if sum(self.kinds.values()) <= 0:
            raise ValueError(f"turbines.kinds must have a positive weight, got {dict(self.kinds)!r}")
        object.__setattr__(self, "kinds", {k: float(w) for k, w in self.kinds.items()})
        for name in SIZE_RANGES:
            object.__setattr__(self, name, _range(name, getattr(self, name), 1e-3, 500.0))
        object.__setattr__(self, "nrel_scale", _range("nrel_scale", self.nrel_scale, 0.1, 2.0))
        object.__setattr__(self, "rotor_azimuth_deg",
                           _range("rotor_azimuth_deg", self.rotor_azimuth_deg, -360.0, 360.0))

    @classmethod
    def coerce(cls, value: Any) -> "TurbineDistribution":
        """A distribution from itself, a dict of its fields (e.g. a recipe's JSON) or True (the defaults)."""
        if isinstance(value, cls):
            return value
        if value is True:
            return cls()
        if not isinstance(value, Mapping):
            raise ValueError(f"turbines must be a TurbineDistribution, a dict of its fields or true, got {value!r}")
        check_unknown_options("turbines", value.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in value.items()})

    def draw(self, rng: np.random.Generator) -> TurbineDraw:
        """One turbine from ``rng``: six variates in a fixed order (sizes, kind, scale, azimuth)."""
        sizes = {name: float(rng.uniform(*getattr(self, name))) for name in SIZE_RANGES}
        kinds = list(self.kinds)
        cum = np.cumsum(list(self.kinds.values()))
        kind = kinds[min(int(np.searchsorted(cum, rng.uniform(0.0, cum[-1]), side="right")), len(kinds) - 1)]
        scale = float(rng.uniform(*self.nrel_scale))
        azimuth = float(rng.uniform(*self.rotor_azimuth_deg))
        if kind == "generated":
            return TurbineDraw(kind, None, dict(sizes), sizes, azimuth)
        scale = 1.0 if kind == "nrel-5mw" else scale
        return TurbineDraw(kind, scale, nrel_turbine(scale), {k: v * scale for k, v in NREL_SIZES.items()}, azimuth)
