"""Turbines from mesh files.

Loading (:func:`load_turbine_mesh`): STL/OBJ/PLY/GLB through trimesh, with unit, up-axis and
ground options (:class:`MeshLoadOptions`); the blades are told from tower, hub and nacelle by
shape, or by face lists.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import trimesh

from ..util.validation import check_array, check_field_types, check_positive, check_unknown_options
from .mesh import (
    TurbineMesh,
    area_moments,
    components,
    rotation_matrix,
    soup_to_trimesh,
    touching_pairs,
    triangle_normals_areas,
)
from .spec import MAX_MESH_EXTENT, MAX_TRIANGLES

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
    obstacle_mesh = soup_to_trimesh(obstacle) if len(obstacle) else trimesh.Trimesh()
    return TurbineMesh(
        blade_vertices=blade, triangle_blade=blade_lab, triangle_face=np.full(len(blade), -1),
        triangle_surface=np.full(len(blade), -1), cap_vertices=np.zeros((0, 3, 3)),
        cap_blade=np.zeros(0, dtype=np.int64), obstacle_mesh=obstacle_mesh,
        rotor_center=center, rotor_axis=axis, spec=None)
