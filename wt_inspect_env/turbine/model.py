"""The wind-turbine model: a validated spec, the triangle mesh built from it, and mesh loading.

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

Meshing: every face is a regular grid of at most ``mesh_step`` cells, each split along a diagonal
into two right-angle triangles, wound so that their normals point out of the blade. Vertices of
neighbouring faces coincide exactly, so every blade (four long faces + root and tip caps) is a
closed surface. Only the four long faces are *inspected* (``blade_*`` arrays); the caps are part of
:attr:`TurbineMesh.mesh` (for collision, occlusion and export) but not of the inspection target.

Face labels (``triangle_face``): 0 front (+axis), 1 back (-axis), 2 edge towards +chord
(``chord = axis x radial``), 3 edge towards -chord. ``triangle_surface = 4 * blade + face``. The
planner does not use these labels (it clusters by geometry, so it also works on loaded meshes);
tests use them to check the clustering.

Realistic turbines: ``TurbineSpec(blade=BladeShape(...))`` replaces the cuboid by a parametric
blade (chord, twist and relative thickness along the span, circle-to-aerofoil sections; see
:mod:`.blade_geometry`; its face labels are the suction side 0, pressure side 1, leading edge 2 and
trailing edge 3, from the design's twist), ``tower_top_radius`` tapers the tower and
``nacelle_radius``/``nacelle_length`` add a nacelle; ``TurbineSpec(preset="nrel-5mw")`` is the NREL
5-MW reference turbine (:mod:`.turbine_presets`, with its sources).

Loading (:func:`load_turbine_mesh`): STL/OBJ/PLY/GLB through trimesh, with unit, up-axis and
ground options (:class:`MeshLoadOptions`); the blades are told from tower, hub and nacelle by
shape, or by face lists.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..util.atomic_io import write_bytes_atomic
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
CYLINDER_SECTIONS = 24        # facets around the tower and hub cylinders
FACE_NAMES = ("front", "back", "edge+", "edge-")
EXPORT_FORMATS = ("stl", "obj")


# --------------------------------------------------------------------------- small geometry helpers
def rotation_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Right-handed rotation by ``angle_rad`` about the unit vector ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * K + (1.0 - math.cos(angle_rad)) * (K @ K)


def triangle_normals_areas(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals from the winding (right-hand rule) and areas of ``(N, 3, 3)`` triangles."""
    cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    areas = 0.5 * norm
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = cross / norm[:, None]
    return normals, areas


def touching_pairs(tris: np.ndarray, tol: float | None = None) -> np.ndarray:
    """Index pairs ``(i, j)``, ``i < j``, of triangles that share a vertex position (within ``tol``).

    Purely geometric (a KD-tree on vertex positions), so it works on triangle soups read from STL
    files as well as on indexed meshes. ``tol`` defaults to 1e-3 of the median edge length.
    """
    flat = np.asarray(tris, dtype=np.float64).reshape(-1, 3)
    if tol is None:
        edges = np.linalg.norm(tris[:, [1, 2, 0]] - tris, axis=2)
        tol = 1e-3 * float(np.median(edges)) if edges.size else 0.0
    pairs = cKDTree(flat).query_pairs(max(tol, 1e-12), output_type="ndarray")
    # each vertex also touches the other two vertices of its own triangle only if they coincide
    # (degenerate); those give i == j and are dropped.
    t = pairs // 3
    t = t[t[:, 0] != t[:, 1]]
    t.sort(axis=1)
    return np.unique(t, axis=0) if len(t) else np.zeros((0, 2), dtype=np.int64)


def components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component label of each of ``n`` nodes linked by ``pairs`` (labels 0..k-1)."""
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) \
        else coo_matrix((n, n))
    _, labels = connected_components(g, directed=False)
    return labels.astype(np.int64)


def _grid_triangles(P: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Split the grid of points ``P (n1+1, n2+1, 3)`` into right-angle triangles facing ``outward``."""
    p00, p10 = P[:-1, :-1], P[1:, :-1]
    p11, p01 = P[1:, 1:], P[:-1, 1:]
    t1 = np.stack([p00, p10, p11], axis=-2)      # right angle at p10
    t2 = np.stack([p00, p11, p01], axis=-2)      # right angle at p01
    tris = np.stack([t1, t2], axis=2).reshape(-1, 3, 3)
    n, _ = triangle_normals_areas(tris[:1])
    if float(n[0] @ outward) < 0:
        tris = tris[:, [0, 2, 1]]
    return tris


def _cylinder(base: np.ndarray, axis: np.ndarray, radius: float, length: float,
              ring_step: float, sections: int = CYLINDER_SECTIONS, top_radius: float | None = None) -> np.ndarray:
    """Closed cylinder, or frustum tapering to ``top_radius`` (side in rings of at most
    ``ring_step``, fan caps), outward wound triangles."""
    axis = axis / np.linalg.norm(axis)
    e1 = np.cross(axis, [0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.cross(axis, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    n_rings = max(1, math.ceil(length / ring_step))
    h = np.linspace(0.0, length, n_rings + 1)
    ang = 2.0 * np.pi * (np.arange(sections + 1) % sections) / sections
    ring = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2                   # (S+1, 3) unit
    r_top = radius if top_radius is None else top_radius
    rad = radius + (r_top - radius) * h / length                                    # (R+1,)
    P = base + h[:, None, None] * axis + rad[:, None, None] * ring[None]            # (R+1, S+1, 3)
    # _grid_triangles decides the winding from the first cell, whose outward direction is ring[0]
    # turned by half a section: close enough, and the side grid is uniformly wound.
    side = _grid_triangles(P, outward=ring[0])
    bottom_c, top_c = base, base + length * axis
    b0, b1 = P[0, :-1], P[0, 1:]
    t0, t1 = P[-1, :-1], P[-1, 1:]
    bottom = np.stack([np.broadcast_to(bottom_c, b0.shape), b1, b0], axis=1)
    top = np.stack([np.broadcast_to(top_c, t0.shape), t0, t1], axis=1)
    nb, _ = triangle_normals_areas(bottom[:1])
    if float(nb[0] @ axis) > 0:
        bottom = bottom[:, [0, 2, 1]]
    nt, _ = triangle_normals_areas(top[:1])
    if float(nt[0] @ axis) < 0:
        top = top[:, [0, 2, 1]]
    return np.concatenate([side, bottom, top])


def _soup_to_trimesh(tris: np.ndarray) -> trimesh.Trimesh:
    """Indexed trimesh of a triangle soup, coincident vertices merged, face order kept."""
    n = len(tris)
    mesh = trimesh.Trimesh(vertices=tris.reshape(-1, 3), faces=np.arange(3 * n).reshape(n, 3),
                           process=True)
    if len(mesh.faces) != n:  # pragma: no cover - trimesh would have to drop faces
        raise RuntimeError(f"trimesh changed the face count {n} -> {len(mesh.faces)}")
    return mesh


# --------------------------------------------------------------------------- the spec
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


# --------------------------------------------------------------------------- the mesh
class TurbineMesh:
    """A turbine as triangles: inspected blade faces, blade caps, and obstacles (hub + tower).

    Blade triangle ``i`` is the same physical triangle in every rotated copy (:meth:`rotated`), so
    coverage counted by index survives the rotor turn. ``mesh`` lists the blade triangles first
    (faces ``0..M-1`` are ``blade_vertices``), then the caps, then the obstacles.
    """

    def __init__(self, *, blade_vertices: np.ndarray, triangle_blade: np.ndarray,
                 triangle_face: np.ndarray, triangle_surface: np.ndarray,
                 cap_vertices: np.ndarray, cap_blade: np.ndarray, obstacle_mesh: trimesh.Trimesh,
                 rotor_center: np.ndarray, rotor_axis: np.ndarray, spec: TurbineSpec | None = None,
                 rotor_turn_deg: float = 0.0) -> None:
        bv = np.ascontiguousarray(blade_vertices, dtype=np.float64)
        if bv.ndim != 3 or bv.shape[1:] != (3, 3) or len(bv) == 0:
            raise ValueError(f"blade_vertices must have shape (M, 3, 3) with M > 0, got {bv.shape}")
        normals, areas = triangle_normals_areas(bv)
        if not np.all(areas > 0):
            raise ValueError(f"blade_vertices has {int(np.sum(~(areas > 0)))} degenerate triangles")
        self.blade_vertices = bv
        self.blade_normals = normals
        self.blade_areas = areas
        self.blade_centroids = bv.mean(axis=1)
        m = len(bv)
        self.triangle_blade = np.asarray(triangle_blade, dtype=np.int64).reshape(m)
        self.triangle_face = np.asarray(triangle_face, dtype=np.int64).reshape(m)
        self.triangle_surface = np.asarray(triangle_surface, dtype=np.int64).reshape(m)
        self.cap_vertices = np.asarray(cap_vertices, dtype=np.float64).reshape(-1, 3, 3)
        self.cap_blade = np.asarray(cap_blade, dtype=np.int64).reshape(len(self.cap_vertices))
        self.obstacle_mesh = obstacle_mesh
        self.rotor_center = check_array("rotor_center", rotor_center, (3,)).copy()
        axis = check_array("rotor_axis", rotor_axis, (3,))
        if np.linalg.norm(axis) < 1e-9:
            raise ValueError(f"rotor_axis must be non-zero, got {axis!r}")
        self.rotor_axis = axis / np.linalg.norm(axis)
        self.spec = spec
        self.rotor_turn_deg = float(rotor_turn_deg)
        for arr in (self.blade_vertices, self.blade_normals, self.blade_areas, self.blade_centroids,
                    self.triangle_blade, self.triangle_face, self.triangle_surface, self.cap_vertices,
                    self.cap_blade, self.rotor_center, self.rotor_axis):
            arr.setflags(write=False)

    def __repr__(self) -> str:
        return (f"TurbineMesh({len(self.blade_vertices)} blade triangles, {len(self.cap_vertices)} cap, "
                f"{len(self.obstacle_mesh.faces)} obstacle; rotor turned {self.rotor_turn_deg:g} deg)")

    @property
    def n_blade_triangles(self) -> int:
        """Number of blade triangles (those coverage counts)."""
        return len(self.blade_vertices)

    @property
    def azimuth_deg(self) -> float | None:
        """Current rotor azimuth (spec azimuth + turns), ``None`` for a loaded mesh."""
        return None if self.spec is None else self.spec.rotor_azimuth_deg + self.rotor_turn_deg

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """Everything (blades, caps, hub, tower) as one trimesh, blade triangles first."""
        parts = [self.blade_vertices, self.cap_vertices, self.obstacle_mesh.triangles]
        return _soup_to_trimesh(np.concatenate([p.reshape(-1, 3, 3) for p in parts]))

    @cached_property
    def all_triangles(self) -> np.ndarray:
        """``(N, 3, 3)`` triangles of :attr:`mesh` in the same order (for distance queries)."""
        return np.concatenate([self.blade_vertices, self.cap_vertices,
                               np.asarray(self.obstacle_mesh.triangles).reshape(-1, 3, 3)])

    def blade_solid(self, blade: int) -> trimesh.Trimesh:
        """The closed surface of one blade (its four long faces and its caps)."""
        tris = np.concatenate([self.blade_vertices[self.triangle_blade == blade],
                               self.cap_vertices[self.cap_blade == blade]])
        if len(tris) == 0:
            raise ValueError(f"blade {blade!r} has no triangles")
        return _soup_to_trimesh(tris)

    def rotated(self, angle_deg: float) -> "TurbineMesh":
        """The same turbine with the rotor turned by ``angle_deg`` about its axis (right-handed)."""
        angle = check_finite("angle_deg", angle_deg)
        R = rotation_matrix(self.rotor_axis, math.radians(angle))
        c = self.rotor_center

        def rot(v: np.ndarray) -> np.ndarray:
            return (v - c) @ R.T + c

        return TurbineMesh(
            blade_vertices=rot(self.blade_vertices), triangle_blade=self.triangle_blade,
            triangle_face=self.triangle_face, triangle_surface=self.triangle_surface,
            cap_vertices=rot(self.cap_vertices), cap_blade=self.cap_blade,
            obstacle_mesh=self.obstacle_mesh, rotor_center=c, rotor_axis=self.rotor_axis,
            spec=self.spec, rotor_turn_deg=self.rotor_turn_deg + angle)

    def export(self, path: str | Path) -> Path:
        """Write :attr:`mesh` as STL or OBJ (by suffix), atomically; returns the path."""
        path = Path(path)
        fmt = path.suffix.lower().lstrip(".")
        if fmt not in EXPORT_FORMATS:
            raise ValueError(f"export path must end in .stl or .obj, got {str(path)!r}")
        data = self.mesh.export(file_type=fmt)
        write_bytes_atomic(path, data if isinstance(data, bytes) else data.encode("utf-8"))
        return path


def build_turbine(spec: TurbineSpec | None = None, **options: Any) -> TurbineMesh:
    """Mesh the turbine of ``spec`` (default: the paper's V100); ``options`` override spec fields."""
    if spec is None:
        spec = TurbineSpec.from_options(options)
    elif not isinstance(spec, TurbineSpec):
        raise ValueError(f"spec must be a TurbineSpec, got {type(spec).__name__}")
    elif options:
        check_unknown_options("turbine", options.keys(), [f.name for f in dataclasses.fields(TurbineSpec)])
        spec = dataclasses.replace(spec, **options)
    nu, nv, nt = spec.grid
    L, w, t, r0 = spec.blade_length, spec.blade_width, spec.blade_thickness, spec.hub_radius
    axis = spec.facing
    center = spec.rotor_center
    ug = np.linspace(0.0, L, nu + 1)
    vg = np.linspace(-w / 2.0, w / 2.0, nv + 1)
    sg = np.linspace(-t / 2.0, t / 2.0, nt + 1)
    up = np.array([0.0, 0.0, 1.0])

    blades, b_lab, f_lab, caps, c_lab = [], [], [], [], []
    for k in range(N_BLADES if spec.blade is None else 0):
        radial = rotation_matrix(axis, math.radians(spec.rotor_azimuth_deg + 120.0 * k)) @ up
        chord = np.cross(axis, radial)

        def point(U: Any, V: Any, S: Any, *, radial: np.ndarray = radial, chord: np.ndarray = chord) -> np.ndarray:
            U, V, S = np.broadcast_arrays(np.asarray(U, float), np.asarray(V, float), np.asarray(S, float))
            return (center + (r0 + U)[..., None] * radial + V[..., None] * chord + S[..., None] * axis)

        U1, V1 = np.meshgrid(ug, vg, indexing="ij")
        U2, S2 = np.meshgrid(ug, sg, indexing="ij")
        V3, S3 = np.meshgrid(vg, sg, indexing="ij")
        faces = [
            _grid_triangles(point(U1, V1, sg[-1]), axis),        # 0 front
            _grid_triangles(point(U1, V1, sg[0]), -axis),        # 1 back
            _grid_triangles(point(U2, vg[-1], S2), chord),       # 2 edge +chord
            _grid_triangles(point(U2, vg[0], S2), -chord),       # 3 edge -chord
        ]
        for fi, tris in enumerate(faces):
            blades.append(tris)
            b_lab.append(np.full(len(tris), k))
            f_lab.append(np.full(len(tris), fi))
        for tris in (_grid_triangles(point(ug[0], V3, S3), -radial),
                     _grid_triangles(point(ug[-1], V3, S3), radial)):
            caps.append(tris)
            c_lab.append(np.full(len(tris), k))

    if spec.blade is not None:
        for k in range(N_BLADES):
            radial = rotation_matrix(axis, math.radians(spec.rotor_azimuth_deg + 120.0 * k)) @ up
            tris, faces, cap = _shaped_blade(spec, center, axis, radial)
            blades.append(tris)
            b_lab.append(np.full(len(tris), k))
            f_lab.append(faces)
            caps.append(cap)
            c_lab.append(np.full(len(cap), k))

    base = np.array([spec.position[0], spec.position[1], 0.0])
    tower = _cylinder(base, up, spec.tower_radius, spec.tower_height,
                      ring_step=max(2.0 * spec.mesh_step, spec.tower_height / 200.0),
                      top_radius=spec.tower_top_radius)
    hub_len = spec.overhang + t / 2.0 + 0.5 * r0
    hub = _cylinder(center - spec.overhang * axis, axis, r0, hub_len, ring_step=spec.mesh_step)
    obstacles = [tower, hub]
    if spec.nacelle_radius is not None:
        obstacles.append(_cylinder(center - spec.overhang * axis, -axis, spec.nacelle_radius, spec.nacelle_length,
                                   ring_step=spec.mesh_step))
    blade_faces = np.concatenate(blades)
    b_lab_a, f_lab_a = np.concatenate(b_lab), np.concatenate(f_lab)
    return TurbineMesh(
        blade_vertices=blade_faces, triangle_blade=b_lab_a, triangle_face=f_lab_a,
        triangle_surface=4 * b_lab_a + f_lab_a, cap_vertices=np.concatenate(caps),
        cap_blade=np.concatenate(c_lab), obstacle_mesh=_soup_to_trimesh(np.concatenate(obstacles)),
        rotor_center=center, rotor_axis=axis, spec=spec)


def _shaped_blade(spec: TurbineSpec, center: np.ndarray, axis: np.ndarray,
                  radial: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles of one parametric blade (rings of section contours, see :mod:`.blade_geometry`),
    their face labels and the root and tip caps.

    Face labels follow the cuboid's meaning, from the design (not from the mesh): each triangle's
    normal, taken in its station's twisted section frame, is 0 (suction side, within 45 deg of the
    frame's +axis), 1 (pressure side, -axis), 2 (leading edge, +chord) or 3 (trailing edge) -
    what the clustering must find without them.
    """
    from .blade_geometry import blade_grid
    shape = spec.blade_shape
    P, radii = blade_grid(shape, center, axis, radial, spec.mesh_step)
    closed = np.concatenate([P, P[:, :1]], axis=1)                     # (R, C+1, 3): contour loop closed
    mid = 0.5 * (closed[0, 0] + closed[0, 1])
    outward = mid - (center + radii[0] * radial)
    tris = _grid_triangles(closed, outward=outward - (outward @ radial) * radial)
    # labels from the design: the normal in the (chord, thickness) frame twisted at its station
    normals, _ = triangle_normals_areas(tris)
    r = (tris.mean(axis=1) - center) @ radial
    _, tw, _ = shape.at(r)
    th = np.radians(tw)
    chord_dir = np.cross(axis, radial)
    le = np.cos(th)[:, None] * chord_dir + np.sin(th)[:, None] * axis
    upn = -np.sin(th)[:, None] * chord_dir + np.cos(th)[:, None] * axis
    phi = np.degrees(np.arctan2(np.einsum("ij,ij->i", normals, upn), np.einsum("ij,ij->i", normals, le)))
    faces = np.select([np.abs(phi) <= 45.0, phi > 135.0, phi < -135.0, phi > 0], [2, 3, 3, 0], default=1)
    caps = []
    for ring, out in ((P[0], -radial), (P[-1], radial)):
        c = ring.mean(axis=0)
        nxt = np.roll(ring, -1, axis=0)
        fan = np.stack([np.broadcast_to(c, ring.shape), ring, nxt], axis=1)
        n, _ = triangle_normals_areas(fan[:1])
        if float(n[0] @ out) < 0:
            fan = fan[:, [0, 2, 1]]
        caps.append(fan)
    return tris, faces.astype(np.int64), np.concatenate(caps)


# --------------------------------------------------------------------------- loading
def area_moments(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centroid, second moment about it (3x3) and area of a set of triangles as uniform sheets.

    Exact for the triangulated region (integral of x x^T over a triangle = A/12 (sum v v^T + s s^T),
    s = sum of its vertices), so the principal axes do not depend on how a face is triangulated;
    the triangle centroids alone would tilt them, since the two triangles of a grid cell are offset
    diagonally.
    """
    tris = np.asarray(tris, dtype=np.float64)
    _, areas = triangle_normals_areas(tris)
    total = float(areas.sum())
    mean = areas @ tris.mean(axis=1) / total
    rel = tris - mean
    ssum = rel.sum(axis=1)
    w = areas / 12.0
    M = np.einsum("k,kij,kil->jl", w, rel, rel) + np.einsum("k,kj,kl->jl", w, ssum, ssum)
    return mean, M, total


UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
UP_AXES = ("z", "y", "x", "-z", "-y", "-x")
LOAD_FORMATS = ("stl", "obj", "ply", "glb", "gltf", "off")
Y_UP_FORMATS = ("glb", "gltf")          # glTF 2.0 says +Y is up
ELONGATED = 6.25      # variance ratio (largest / middle principal axis) of a blade: length >= 2.5 x width


@dataclass(frozen=True)
class MeshLoadOptions:
    """How to read a turbine mesh file (``turbine_mesh={"path": ..., "unit": "mm"}`` in ``gym.make``).

    unit
        Length unit of the file (``m``, ``cm``, ``mm``, ``in``, ``ft``) or the factor to metres.
    up_axis
        File axis that points up (``z``, ``y``, ``x`` or negated); ``None``: ``y`` for glTF/GLB
        (the glTF convention), ``z`` for everything else (STL, OBJ, PLY have none; this project's
        export is z-up). The mesh is turned so that axis becomes world +z.
    place_on_ground
        Shift the mesh vertically so that its lowest point is at z = 0 (for files whose origin is
        e.g. at the hub). Without it a mesh reaching below the ground is an error.
    blade_faces, obstacle_faces
        Face indices (in the file's order) of the inspected blades, or of everything else; when
        neither is given the parts are recognised by shape (see :func:`load_turbine_mesh`).
    rotor_center, rotor_axis
        In world coordinates after unit and up-axis conversion; estimated when not given.
    """

    path: str
    unit: str | float = "m"
    up_axis: str | None = None
    place_on_ground: bool = False
    blade_faces: Any = None
    obstacle_faces: Any = None
    rotor_center: Any = None
    rotor_axis: Any = None

    def __post_init__(self) -> None:
        check_field_types(self, "turbine_mesh ")
        put = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 - frozen dataclass setter
        if not isinstance(self.path, (str, Path)):
            raise ValueError(f"turbine_mesh path must be a file name, got {self.path!r}")
        put("path", str(self.path))
        if isinstance(self.unit, str):
            if self.unit not in UNITS:
                raise ValueError(f"unit must be one of {', '.join(UNITS)} or a factor to metres, got {self.unit!r}")
        else:
            check_positive("unit", self.unit)
        if self.up_axis is not None and self.up_axis not in UP_AXES:
            raise ValueError(f"up_axis must be one of {', '.join(UP_AXES)}, got {self.up_axis!r}")
        if not isinstance(self.place_on_ground, bool):
            raise ValueError(f"place_on_ground must be a bool, got {self.place_on_ground!r}")
        if self.blade_faces is not None and self.obstacle_faces is not None:
            raise ValueError("give blade_faces or obstacle_faces, not both")

    @classmethod
    def from_value(cls, value: Any) -> "MeshLoadOptions":
        """From a file name, a mapping of these fields (``path`` required) or an instance."""
        if isinstance(value, cls):
            return value
        if isinstance(value, (str, Path)):
            return cls(path=str(value))
        if isinstance(value, Mapping):
            check_unknown_options("turbine_mesh", value.keys(), [f.name for f in dataclasses.fields(cls)])
            if "path" not in value:
                raise ValueError(f"turbine_mesh needs a path, got {dict(value)!r}")
            return cls(**dict(value))
        raise ValueError(f"turbine_mesh must be a file name or a dict with a path, got {value!r}")

    @property
    def scale(self) -> float:
        """Metres per file unit."""
        return UNITS[self.unit] if isinstance(self.unit, str) else float(self.unit)

    def up_rotation(self, fmt: str) -> np.ndarray:
        """Rotation taking the file's up axis to world +z (the smallest such turn; 180 deg about x
        for ``-z``)."""
        up = self.up_axis or ("y" if fmt in Y_UP_FORMATS else "z")
        u = np.zeros(3)
        u["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
        z = np.array([0.0, 0.0, 1.0])
        if u @ z > 0.5:
            return np.eye(3)
        if u @ z < -0.5:
            return rotation_matrix(np.array([1.0, 0.0, 0.0]), math.pi)
        return rotation_matrix(np.cross(u, z), math.pi / 2.0)


@dataclass(frozen=True)
class MeshPart:
    """One connected part of a loaded mesh, summarised by the shape of its surface."""

    faces: np.ndarray          # indices into the file's faces
    area: float
    centroid: np.ndarray
    direction: np.ndarray      # long principal axis
    elongation: float          # variance along the long axis / along the middle axis
    z_range: tuple[float, float]
    extent: tuple[float, float, float]   # sizes along the principal axes, long first

    def describe(self) -> str:
        """One line about the part (faces, extent, tilt, height range) for logs and errors."""
        e = self.extent
        tilt = math.degrees(math.acos(min(1.0, abs(float(self.direction[2])))))
        return (f"{len(self.faces)} faces {e[0]:.3g} x {e[1]:.3g} x {e[2]:.3g} m, long axis {tilt:.0f} deg "
                f"from vertical, z {self.z_range[0]:.3g}..{self.z_range[1]:.3g} m")


def mesh_parts(tris: np.ndarray) -> list[MeshPart]:
    """Connected parts (triangles sharing vertex positions) with their principal-axis shape."""
    lab = components(len(tris), touching_pairs(tris))
    parts = []
    for k in range(int(lab.max()) + 1 if len(lab) else 0):
        idx = np.flatnonzero(lab == k)
        t = tris[idx]
        _, areas = triangle_normals_areas(t)
        if not areas.sum() > 0:
            continue
        mean, M, area = area_moments(t)
        vals, vecs = np.linalg.eigh(M)
        proj = (t.reshape(-1, 3) - mean) @ vecs
        size = proj.max(axis=0) - proj.min(axis=0)
        parts.append(MeshPart(faces=idx, area=area, centroid=mean, direction=vecs[:, -1],
                              elongation=float(vals[-1] / max(vals[-2], 1e-12 * vals[-1])),
                              z_range=(float(t[..., 2].min()), float(t[..., 2].max())),
                              extent=(float(size[2]), float(size[1]), float(size[0]))))
    return parts


def _lines_meeting_point(parts: list[MeshPart]) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares point closest to the parts' long axes, and each axis' distance from it."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for p in parts:
        P = np.eye(3) - np.outer(p.direction, p.direction)
        A += P
        b += P @ p.centroid
    if np.linalg.cond(A) > 1e8:
        raise np.linalg.LinAlgError("parallel axes")
    c = np.linalg.solve(A, b)
    res = np.array([np.linalg.norm((np.eye(3) - np.outer(p.direction, p.direction)) @ (c - p.centroid))
                    for p in parts])
    return c, res


def _find_blades(parts: list[MeshPart], name: str) -> tuple[list[MeshPart], np.ndarray]:
    """The blades among the parts: elongated, of similar area, their long axes meeting at one point
    near their inner ends (the rotor centre); the part reaching lowest, if upright, is the tower.

    Raises a one-line ``ValueError`` saying what was found and which option to give."""
    found = "; ".join(f"part {i}: {p.describe()}" for i, p in enumerate(parts))
    z0 = min(p.z_range[0] for p in parts)
    cands = [p for p in parts if p.elongation >= ELONGATED
             and not (p.z_range[0] <= z0 + 1e-6 * max(1.0, p.extent[0]) and abs(p.direction[2]) > 0.97)]
    hint = (f"{name}: found {len(parts)} connected parts ({found}) and cannot tell the blades from the tower "
            f"and hub{{}}; give blade_faces (the inspected faces' indices) or obstacle_faces, and check "
            f"unit and up_axis")
    if not cands:
        raise ValueError(hint.format(": no elongated part apart from an upright one standing lowest"))
    big = max(p.area for p in cands)
    cands = [p for p in cands if p.area >= 0.5 * big]
    while len(cands) >= 2:
        try:
            c, res = _lines_meeting_point(cands)
        except np.linalg.LinAlgError:
            break
        worst = int(np.argmax(res / np.array([p.extent[0] for p in cands])))
        if res[worst] <= 0.1 * cands[worst].extent[0]:
            inner = [float(np.linalg.norm(c - p.centroid)) for p in cands]
            if all(r >= 0.3 * p.extent[0] for r, p in zip(inner, cands)):   # c beyond the inner ends
                return cands, c
            break
        cands.pop(worst)
    if len(cands) == 1:
        return cands, np.full(3, np.nan)
    raise ValueError(hint.format(f": {len(cands)} elongated parts of similar size whose long axes "
                                 "do not meet at a rotor centre"))


def check_mesh_extent(opts: "MeshLoadOptions", raw_extent: float) -> None:
    """ValueError naming the file, the ``unit`` and the size unless the mesh (largest extent
    ``raw_extent`` in file units) is at most :data:`MAX_MESH_EXTENT` across in metres; the message
    suggests the units that would make it a turbine-sized mesh (a millimetre file read as metres
    is the common case)."""
    extent = raw_extent * opts.scale
    if extent <= MAX_MESH_EXTENT:
        return
    fits = [u for u, f in UNITS.items() if 0.1 <= raw_extent * f <= MAX_MESH_EXTENT and f < opts.scale]
    hint = (f"; if the file is in {' or '.join(fits)}, give unit=" + " / ".join(f'"{u}"' for u in fits)
            if fits else "; give the unit the file is in (unit=\"mm\", \"cm\", ... or a factor to metres)")
    raise ValueError(f"path {opts.path!r}: the mesh is {extent:.4g} m across with unit {opts.unit!r}, more than the "
                     f"{MAX_MESH_EXTENT:g} m of any turbine{hint}")


def load_turbine_mesh(path: str | Path | MeshLoadOptions | Mapping[str, Any], **options: Any) -> TurbineMesh:
    """Read a turbine from an STL/OBJ/PLY/GLB file (through trimesh; ``options``: the fields of
    :class:`MeshLoadOptions`).

    Blade (inspected) triangles are the faces listed in ``blade_faces``, or all faces not in
    ``obstacle_faces``; when neither is given they are recognised by shape: the file is split into
    connected parts, and the blades are the elongated parts of similar area whose long axes meet
    at one point beyond their inner ends (the rotor centre), not the upright part standing lowest
    (the tower); everything else (tower, hub, nacelle) is an obstacle. A mesh in which blades and
    hub are one connected part cannot be told apart that way: the error says what was found and
    which option to give. Face indices refer to the file's face order (kept as read). Blade labels
    come from geometry (touching triangles form one blade); face and surface labels are -1 (the
    planner clusters by geometry). The rotor centre and axis, needed for :meth:`TurbineMesh.rotated`,
    are estimated when not given: the axis as the direction of least spread of the blade triangles
    (oriented away from the obstacles), the centre as the least-squares meeting point of the blades'
    centre lines.
    """
    opts = MeshLoadOptions.from_value(path)
    if options:
        check_unknown_options("turbine_mesh", options.keys(), [f.name for f in dataclasses.fields(MeshLoadOptions)])
        opts = dataclasses.replace(opts, **options)
    p = Path(opts.path)
    fmt = p.suffix.lower().lstrip(".")
    if not p.is_file():
        raise ValueError(f"path {opts.path!r} is not a file")
    if fmt not in LOAD_FORMATS:
        raise ValueError(f"path {opts.path!r}: format {fmt!r} is not one of {', '.join(LOAD_FORMATS)}")
    try:
        mesh = trimesh.load(str(p), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many different types for unreadable files
        raise ValueError(f"path {opts.path!r} could not be read as a mesh: {exc}") from None
    tris = np.asarray(getattr(mesh, "triangles", np.zeros((0, 3, 3))), dtype=np.float64).reshape(-1, 3, 3)
    n = len(tris)
    if n == 0:
        raise ValueError(f"path {opts.path!r} holds no triangles")
    if n > MAX_TRIANGLES:
        raise ValueError(f"path {opts.path!r} has {n:,} triangles, more than {MAX_TRIANGLES:,}; decimate the mesh "
                         "(the planner and the coverage test work per triangle)")
    raw_extent = float(np.max(np.ptp(tris.reshape(-1, 3), axis=0))) if np.all(np.isfinite(tris)) else math.inf
    tris = (tris * opts.scale) @ opts.up_rotation(fmt).T
    if not np.all(np.isfinite(tris)):
        raise ValueError(f"path {opts.path!r} has non-finite vertex coordinates"
                         + (f" with unit {opts.unit!r}" if math.isfinite(raw_extent) else ""))
    check_mesh_extent(opts, raw_extent)
    zmin = float(tris[..., 2].min())
    if opts.place_on_ground:
        tris[..., 2] -= zmin
    elif zmin < -1e-6 * float(np.ptp(tris[..., 2]) or 1.0):
        raise ValueError(f"path {opts.path!r}: the mesh reaches z = {zmin:.4g} m, below the ground; "
                         f"give place_on_ground=True or the right up_axis (now "
                         f"{opts.up_axis or ('y' if fmt in Y_UP_FORMATS else 'z')!r}) and unit ({opts.unit!r})")
    mask = np.ones(n, dtype=bool)
    center_guess = None
    for name, idx, value in (("blade_faces", opts.blade_faces, True), ("obstacle_faces", opts.obstacle_faces, False)):
        if idx is None:
            continue
        arr = np.asarray(idx)
        if arr.dtype == bool:
            raise ValueError(f"{name} must be face indices, got a boolean array")
        arr = arr.astype(np.int64).ravel()
        if arr.size and (arr.min() < 0 or arr.max() >= n):
            raise ValueError(f"{name} must index the {n} faces of the file, got range "
                             f"[{arr.min()}, {arr.max()}]")
        mask = np.zeros(n, dtype=bool) if value else np.ones(n, dtype=bool)
        mask[arr] = value
    if opts.blade_faces is None and opts.obstacle_faces is None:
        parts = mesh_parts(tris)
        blades, center_guess = _find_blades(parts, f"path {opts.path!r}")
        mask = np.zeros(n, dtype=bool)
        mask[np.concatenate([b.faces for b in blades])] = True
    if not mask.any():
        raise ValueError("no blade triangles left (blade_faces empty or obstacle_faces covers all)")
    blade = tris[mask]
    _, areas = triangle_normals_areas(blade)
    if not np.all(areas > 0):
        raise ValueError(f"path {opts.path!r}: {int(np.sum(~(areas > 0)))} degenerate blade triangles")
    obstacle = tris[~mask]
    blade_lab = components(len(blade), touching_pairs(blade))
    cent = blade.mean(axis=1)

    if opts.rotor_axis is None:
        _, M, _ = area_moments(blade)
        axis = np.linalg.eigh(M)[1][:, 0]
        if len(obstacle):
            away = cent.mean(axis=0) - obstacle.reshape(-1, 3).mean(axis=0)
            away[2] = 0.0
            if away @ axis < 0:
                axis = -axis
        elif axis[np.argmax(np.abs(axis))] < 0:
            axis = -axis
    else:
        axis = check_array("rotor_axis", opts.rotor_axis, (3,))
    if opts.rotor_center is None:
        A, b = np.zeros((3, 3)), np.zeros(3)
        n_lines = 0
        for k in np.unique(blade_lab):
            sel = blade_lab == k
            m, M, _ = area_moments(blade[sel])
            vals, vecs = np.linalg.eigh(M)
            if vals[-1] <= 4.0 * vals[-2]:     # not elongated: no usable centre line
                continue
            d = vecs[:, -1]
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ m
            n_lines += 1
        if n_lines < 2 or np.linalg.cond(A) > 1e8:
            raise ValueError(f"rotor_center could not be estimated from the blades of {opts.path!r} "
                             f"({n_lines} usable blade axes); pass rotor_center and rotor_axis")
        center = np.linalg.solve(A, b)
    else:
        center = check_array("rotor_center", opts.rotor_center, (3,))
    obstacle_mesh = _soup_to_trimesh(obstacle) if len(obstacle) else trimesh.Trimesh()
    return TurbineMesh(
        blade_vertices=blade, triangle_blade=blade_lab, triangle_face=np.full(len(blade), -1),
        triangle_surface=np.full(len(blade), -1), cap_vertices=np.zeros((0, 3, 3)),
        cap_blade=np.zeros(0, dtype=np.int64), obstacle_mesh=obstacle_mesh,
        rotor_center=center, rotor_axis=axis, spec=None)
