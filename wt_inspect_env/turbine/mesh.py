"""The triangle mesh built from a :class:`~.spec.TurbineSpec` (:func:`build_turbine`, :class:`TurbineMesh`)
and the mesh helpers the planner shares.

Meshing: every face is a regular grid of at most ``mesh_step`` cells, each split along a diagonal
into two right-angle triangles, wound so that their normals point out of the blade. Vertices of
neighbouring faces coincide exactly, so every blade (four long faces + root and tip caps) is a
closed surface. Only the four long faces are *inspected* (``blade_*`` arrays); the caps are part of
:attr:`TurbineMesh.mesh` (for collision, occlusion and export) but not of the inspection target.

Face labels (``triangle_face``): 0 front (+axis), 1 back (-axis), 2 edge towards +chord
(``chord = axis x radial``), 3 edge towards -chord. ``triangle_surface = 4 * blade + face``. The
planner does not use these labels (it clusters by geometry, so it also works on loaded meshes);
tests use them to check the clustering.
"""
from __future__ import annotations

import dataclasses
import math
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..util.atomic_io import write_bytes_atomic
from ..util.validation import check_array, check_finite, check_unknown_options
from .spec import N_BLADES, TurbineSpec

CYLINDER_SECTIONS = 24        # facets around the tower and hub cylinders
EXPORT_FORMATS = ("stl", "obj")


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


def soup_to_trimesh(tris: np.ndarray) -> trimesh.Trimesh:
    """Indexed trimesh of a triangle soup, coincident vertices merged, face order kept."""
    n = len(tris)
    mesh = trimesh.Trimesh(vertices=tris.reshape(-1, 3), faces=np.arange(3 * n).reshape(n, 3),
                           process=True)
    if len(mesh.faces) != n:  # pragma: no cover - trimesh would have to drop faces
        raise RuntimeError(f"trimesh changed the face count {n} -> {len(mesh.faces)}")
    return mesh


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
        return soup_to_trimesh(np.concatenate([p.reshape(-1, 3, 3) for p in parts]))

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
        return soup_to_trimesh(tris)

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
        cap_blade=np.concatenate(c_lab), obstacle_mesh=soup_to_trimesh(np.concatenate(obstacles)),
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
