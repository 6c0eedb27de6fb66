"""The turbine's validated description (:class:`TurbineSpec`): sizes, pose, blade shape, presets.

Geometry (the paper's simplified Vestas V100, section "Triangular Mesh Generation")
-------------------------------------------------------------------------------------
* The tower is a closed cylinder of ``tower_radius`` standing on the ground at ``position`` (x, y);
  its top is at the hub height ``tower_height``.
* The rotor centre is ``overhang`` in front of the tower axis, along the facing direction
  ``f = (cos facing_deg, sin facing_deg, 0)``; ``rotor_axis = f`` (the default faces +y, so the
  paper's wind along y blows across the rotor face). A hub cylinder of ``hub_radius`` runs along
  the axis from the tower axis to a little in front of the blades; hub and tower are obstacles,
  never inspected.
* Three cuboid blades ``blade_length x blade_width x blade_thickness`` start at ``hub_radius`` from
  the rotor centre. Blade k points along ``R(axis, rotor_azimuth_deg + 120 k) @ (0, 0, 1)``
  (right-handed rotation about the rotor axis), so azimuth 0 is the paper's inverted Y: blade 0
  straight up, blade 1 120 deg further (for the default axis +y: towards +x, 30 deg below
  horizontal), blade 2 at 240 deg (towards -x, 30 deg below horizontal).
* The chord (width) lies in the rotor plane, the thickness along the rotor axis: the two wide faces
  look along +-axis, the two narrow edge faces look sideways in the rotor plane. On the inverted Y
  each lower blade therefore has one narrow face looking 60 deg below horizontal: the faces the
  paper inspects in its second phase, after turning the rotor by 120 deg.

Realistic turbines: ``TurbineSpec(blade=BladeShape(...))`` replaces the cuboid by a parametric
blade (chord, twist and relative thickness along the span, circle-to-aerofoil sections; see
:mod:`.blade_geometry`; its face labels are the suction side 0, pressure side 1, leading edge 2 and
trailing edge 3, from the design's twist), ``tower_top_radius`` tapers the tower and
``nacelle_radius``/``nacelle_length`` add a nacelle; ``TurbineSpec(preset="nrel-5mw")`` is the NREL
5-MW reference turbine (:mod:`.presets`, with its sources).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..util.validation import check_array, check_field_types, check_finite, check_positive, check_unknown_options

MAX_TRIANGLES = 1_000_000     # a mesh step that would need more triangles is rejected
# Size bounds of a generated turbine [m], about 1.5x the largest built: blades of ~150 m (26 MW
# class, 310 m rotor) and hub heights of ~180 m. The planner's clearance checks grow in time and
# memory with the turbine's size (a MemoryError on huge turbines was reported in issue 17); the
# bound turns such a request into a one-line error naming the field.
MAX_BLADE_LENGTH = 200.0
MAX_TOWER_HEIGHT = 300.0
# Bounds of a loaded mesh: its largest extent [m] after the unit is applied (twice the tallest
# turbine a TurbineSpec may describe, MAX_TOWER_HEIGHT + MAX_BLADE_LENGTH) and its triangle count
# (as MAX_TRIANGLES for generated ones). Beyond them planning grows for minutes and then fails
# on a transit of kilometres - most often a file in millimetres read as metres.
MAX_MESH_EXTENT = 2.0 * (MAX_TOWER_HEIGHT + MAX_BLADE_LENGTH)
N_BLADES = 3
FACE_NAMES = ("front", "back", "edge+", "edge-")


@dataclass(frozen=True)
class TurbineSpec:
    """Dimensions and placement of the turbine (SI units, angles in degrees as the names say).

    ``preset`` (e.g. ``"nrel-5mw"``, see :mod:`.turbine_presets`) fills every field left ``None``;
    the rest of the ``None`` defaults are the paper's V100 or derived from the others, all stored
    resolved after validation: ``tower_height`` 120, ``blade_length`` 50, ``blade_width`` 3,
    ``tower_radius`` 1.5 (``tower_top_radius`` = ``tower_radius``: a cylinder; smaller: a tapered
    tower), ``blade_thickness = blade_width / 3`` (the paper), ``hub_radius = 0.7 blade_width``
    (2.1 m for the V100; must exceed ``blade_width / (2 sqrt 3)`` or neighbouring blade roots
    would intersect), ``overhang = tower_radius + hub_radius`` (horizontal distance tower axis ->
    rotor plane; must exceed ``tower_radius + blade_thickness / 2`` so a blade pointing down clears
    the tower). ``nacelle_radius`` / ``nacelle_length``: a cylindrical nacelle running back from
    the tower axis along the rotor axis (an obstacle; none by default).

    ``blade``: ``None`` for the paper's cuboid blade, or a :class:`~.blade_geometry.BladeShape`
    (or dict: span, chord, twist_deg, thickness, pitch_axis) for a parametric blade starting at
    ``hub_radius``; ``blade_length`` (if given) scales it geometrically, and ``blade_width`` /
    ``blade_thickness`` follow its largest chord and thickness (values given for them are replaced).
    """

    tower_height: float | None = None
    blade_length: float | None = None
    blade_width: float | None = None
    blade_thickness: float | None = None
    position: tuple[float, float] = (0.0, 0.0)
    rotor_azimuth_deg: float = 0.0
    facing_deg: float = 90.0
    hub_radius: float | None = None
    overhang: float | None = None
    tower_radius: float | None = None
    mesh_step: float = 1.5
    tower_top_radius: float | None = None
    nacelle_radius: float | None = None
    nacelle_length: float | None = None
    blade: Any = None
    preset: str | None = None

    def __post_init__(self) -> None:
        check_field_types(self, "turbine ")
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        if self.preset is not None:
            from .presets import get_turbine_preset
            for k, v in get_turbine_preset(self.preset).items():
                if getattr(self, k) is None:
                    put(k, v)
        for k, v in (("tower_height", 120.0), ("tower_radius", 1.5)):
            if getattr(self, k) is None:
                put(k, v)
        put("tower_height", check_positive("tower_height", self.tower_height))
        if self.tower_height > MAX_TOWER_HEIGHT:
            raise ValueError(f"tower_height must be at most {MAX_TOWER_HEIGHT:g} m (1.5x the tallest hub height "
                             f"built), got {self.tower_height!r}")
        shape = None
        if self.blade is not None:
            from .blade_geometry import BladeShape
            shape = BladeShape.from_value(self.blade)
            if self.blade_length is not None:
                check_positive("blade_length", self.blade_length)
                if abs(self.blade_length - shape.length) > 1e-9 * shape.length:
                    shape = shape.scaled(self.blade_length)
            put("blade", shape)
            put("blade_length", shape.length)
            put("blade_width", shape.max_chord)
            put("blade_thickness", shape.max_thickness)
        for k, v in (("blade_length", 50.0), ("blade_width", 3.0)):
            if getattr(self, k) is None:
                put(k, v)
        put("blade_length", check_positive("blade_length", self.blade_length))
        if self.blade_length > MAX_BLADE_LENGTH:
            raise ValueError(f"blade_length must be at most {MAX_BLADE_LENGTH:g} m (1.5x the longest blade "
                             f"built), got {self.blade_length!r}")
        put("blade_width", check_positive("blade_width", self.blade_width))
        if self.blade_width >= self.blade_length:
            raise ValueError(f"blade_width must be smaller than blade_length ({self.blade_length!r}), "
                             f"got {self.blade_width!r}")
        t = self.blade_width / 3.0 if self.blade_thickness is None else \
            check_positive("blade_thickness", self.blade_thickness)
        if t > self.blade_width:
            raise ValueError(f"blade_thickness must not exceed blade_width ({self.blade_width!r}), "
                             f"got {self.blade_thickness!r}")
        put("blade_thickness", t)
        pos = check_array("position", self.position, (2,))
        put("position", (float(pos[0]), float(pos[1])))
        put("rotor_azimuth_deg", check_finite("rotor_azimuth_deg", self.rotor_azimuth_deg))
        put("facing_deg", check_finite("facing_deg", self.facing_deg))
        put("tower_radius", check_positive("tower_radius", self.tower_radius))
        top = self.tower_radius if self.tower_top_radius is None else \
            check_positive("tower_top_radius", self.tower_top_radius)
        if top > self.tower_radius:
            raise ValueError(f"tower_top_radius must not exceed tower_radius ({self.tower_radius!r}), got {top!r}")
        put("tower_top_radius", top)
        if (self.nacelle_radius is None) != (self.nacelle_length is None):
            raise ValueError(f"give nacelle_radius and nacelle_length together, got {self.nacelle_radius!r} "
                             f"and {self.nacelle_length!r}")
        if self.nacelle_radius is not None:
            put("nacelle_radius", check_positive("nacelle_radius", self.nacelle_radius))
            put("nacelle_length", check_positive("nacelle_length", self.nacelle_length))
        min_hub = self.blade_width / (2.0 * math.sqrt(3.0))
        hub = 0.7 * self.blade_width if self.hub_radius is None else \
            check_positive("hub_radius", self.hub_radius)
        if hub <= min_hub:
            raise ValueError(f"hub_radius must exceed blade_width/(2*sqrt(3)) = {min_hub:.4g} m, or "
                             f"neighbouring blade roots intersect; got {self.hub_radius!r}")
        put("hub_radius", hub)
        min_over = self._min_overhang()
        over = self.tower_radius + hub if self.overhang is None else \
            check_positive("overhang", self.overhang)
        if over <= min_over:
            raise ValueError(f"overhang must exceed tower_radius + blade_thickness/2 = {min_over:.4g} m "
                             f"(at the height the blade passes, for a tapered tower) so that a blade "
                             f"pointing down clears the tower; got {self.overhang!r}")
        put("overhang", over)
        put("mesh_step", check_positive("mesh_step", self.mesh_step))
        if self.tip_radius >= self.tower_height:
            raise ValueError(
                f"blade_length {self.blade_length!r} is too long for tower_height {self.tower_height!r}: "
                f"the rotor (tip radius {self.tip_radius:.4g} m incl. hub_radius) would hit the ground")
        n_tri = self.n_triangles
        if n_tri > MAX_TRIANGLES:
            raise ValueError(f"mesh_step {self.mesh_step!r} would make {n_tri:,} triangles "
                             f"(limit {MAX_TRIANGLES:,}); use a larger step")

    def _min_overhang(self) -> float:
        """Smallest overhang at which a blade pointing straight down misses the tower: the largest
        tower radius at a blade station's height plus that station's half extent along the axis."""
        def tower_r(z: np.ndarray) -> np.ndarray:
            return (self.tower_radius
                    + (self.tower_top_radius - self.tower_radius) * np.clip(z / self.tower_height, 0, 1))

        hub = 0.7 * self.blade_width if self.hub_radius is None else self.hub_radius
        if self.blade is None:
            return float(tower_r(np.array(self.tower_height - hub)) + self.blade_thickness / 2.0)
        b = self.blade
        r = hub + np.asarray(b.span) - b.span[0]
        th = np.radians(np.abs(np.asarray(b.twist_deg)))
        c, tc = np.asarray(b.chord), np.asarray(b.thickness)
        half = 0.5 * c * tc * np.cos(th) + c * max(b.pitch_axis, 0.5) * np.sin(th)
        return float(np.max(tower_r(self.tower_height - r) + half))

    @property
    def blade_shape(self) -> Any:
        """The parametric blade placed on this rotor (span re-based to start at ``hub_radius``),
        ``None`` for the cuboid."""
        if self.blade is None:
            return None
        from .blade_geometry import BladeShape
        b = self.blade
        return BladeShape(tuple(self.hub_radius + x - b.span[0] for x in b.span), b.chord, b.twist_deg,
                          b.thickness, b.pitch_axis)

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> "TurbineSpec":
        """Build from a mapping (e.g. parsed JSON); unknown keys raise ``ValueError``."""
        check_unknown_options("turbine", options.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**dict(options))

    # derived quantities ------------------------------------------------------------------
    @property
    def tip_radius(self) -> float:
        """Distance from the rotor centre to the outer corners of a blade tip."""
        return math.hypot(self.hub_radius + self.blade_length, self.blade_width / 2.0)

    @property
    def facing(self) -> np.ndarray:
        """Unit horizontal rotor axis ``(cos facing, sin facing, 0)``."""
        f = math.radians(self.facing_deg)
        return np.array([math.cos(f), math.sin(f), 0.0])

    @property
    def rotor_center(self) -> np.ndarray:
        """The rotor centre [m]: the tower top, moved along the facing by the overhang."""
        return np.array([self.position[0], self.position[1], self.tower_height]) + self.overhang * self.facing

    @property
    def grid(self) -> tuple[int, int, int]:
        """Cells per blade face: (along the length, across the width, across the thickness)."""
        s = self.mesh_step
        return (math.ceil(self.blade_length / s - 1e-9), math.ceil(self.blade_width / s - 1e-9),
                math.ceil(self.blade_thickness / s - 1e-9))

    def _shape_grid(self) -> tuple[int, int]:
        from .blade_geometry import blade_grid_size
        return blade_grid_size(self.blade_shape, self.mesh_step)

    @property
    def n_blade_triangles(self) -> int:
        """Inspected triangles (four long faces, or the whole aerofoil surface, of the three blades)."""
        if self.blade is not None:
            rings, contour = self._shape_grid()
            return N_BLADES * 2 * (rings - 1) * contour
        nu, nv, nt = self.grid
        return N_BLADES * 2 * nu * (2 * nv + 2 * nt)

    @property
    def n_cap_triangles(self) -> int:
        """Number of triangles of the blades' root and tip caps."""
        if self.blade is not None:
            return N_BLADES * 2 * self._shape_grid()[1]
        nu, nv, nt = self.grid
        return N_BLADES * 2 * 2 * nv * nt

    @property
    def n_triangles(self) -> int:
        """Blade triangles incl. caps (the obstacle cylinders add a few thousand more)."""
        return self.n_blade_triangles + self.n_cap_triangles
