"""Clustering: group blade triangles into inspection surfaces from their geometry alone.

Two blade triangles belong to the same surface when they touch (share a vertex position) and
their outward normals differ by less than ``angle_deg``; surfaces are the connected components of
that relation. Nothing here reads the builder's labels, so a mesh loaded from a file is clustered
the same way. On the cuboid blades this yields the four long faces of each blade: faces of one
blade meet at 90 deg, and equal-normal faces of different blades (e.g. the three front faces) do
not touch (the spec keeps the blade roots apart).

Each surface is then summarised by its centroids: the area-weighted mean normal, the centre line
(through the area-weighted mean of the centroids, along the long principal axis of the face) and
its two end nodes. An end node sits at the centre of the end row of triangles (the mean
projection of the triangles touching that end), i.e. half a mesh cell in from the blade's root or
tip, the first and last inspection points of the paper's "centre line through the triangle
centres". Components much smaller than the largest (``min_area_fraction``, e.g. blade caps in a
loaded file) are not inspection surfaces and are reported as ignored.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..turbine import TurbineMesh, area_moments, components, touching_pairs


@dataclass(frozen=True, eq=False)
class Surface:
    """One inspection surface of one rotor configuration (arrays in world coordinates)."""

    id: int
    triangles: np.ndarray      # indices into the turbine's blade_* arrays
    blade: int                 # geometric blade (touching component) the surface belongs to
    normal: np.ndarray         # area-weighted mean outward unit normal
    root: np.ndarray           # centre-line end node near the rotor centre
    tip: np.ndarray            # centre-line end node away from the rotor centre
    width: float               # extent of the face across its centre line
    area: float
    trim: tuple[float, float] = (0.0, 0.0)   # metres the planner moved root / tip inwards (clearance)

    @property
    def ends(self) -> np.ndarray:
        """``(2, 3)``: end node 0 = root, end node 1 = tip."""
        return np.stack([self.root, self.tip])

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.tip - self.root))

    @property
    def elevation_deg(self) -> float:
        """Angle of the normal above the horizontal plane (negative: looks down)."""
        return math.degrees(math.asin(float(np.clip(self.normal[2], -1.0, 1.0))))


def describe_surface(turbine: TurbineMesh, triangles: np.ndarray, surface_id: int, blade: int) -> Surface:
    """Normal, centre line and end nodes of the given blade triangles in ``turbine``'s pose."""
    idx = np.asarray(triangles, dtype=np.int64)
    tris = turbine.blade_vertices[idx]
    cent = turbine.blade_centroids[idx]
    area = turbine.blade_areas[idx]
    n = area @ turbine.blade_normals[idx]
    n /= np.linalg.norm(n)
    # centre line through the face's centroid along its long principal axis (exact area moments)
    mean, M, _ = area_moments(tris)
    P = np.eye(3) - np.outer(n, n)
    e = np.linalg.eigh(P @ M @ P)[1][:, -1]
    if (mean - turbine.rotor_center) @ e < 0:  # orient root -> tip (away from the rotor centre)
        e = -e
    tv = (tris - mean) @ e                      # (k, 3) vertex projections on the centre line
    t_lo, t_hi = tv.min(), tv.max()
    tol = 1e-6 * max(t_hi - t_lo, 1.0)
    tc = cent @ e - mean @ e
    at_root = tv.min(axis=1) <= t_lo + tol
    at_tip = tv.max(axis=1) >= t_hi - tol
    t_root = float(np.average(tc[at_root], weights=area[at_root]))
    t_tip = float(np.average(tc[at_tip], weights=area[at_tip]))
    across = np.cross(n, e)
    va = (tris - mean) @ across
    return Surface(id=surface_id, triangles=idx, blade=int(blade), normal=n,
                   root=mean + t_root * e, tip=mean + t_tip * e,
                   width=float(va.max() - va.min()), area=float(area.sum()))


def cluster_surfaces(turbine: TurbineMesh, *, angle_deg: float = 20.0,
                     min_area_fraction: float = 0.05) -> tuple[list[Surface], np.ndarray]:
    """Inspection surfaces of ``turbine`` (ids ordered by their first triangle) and the ignored
    triangle indices (components smaller than ``min_area_fraction`` of the largest one)."""
    tris = turbine.blade_vertices
    normals = turbine.blade_normals
    m = len(tris)
    pairs = touching_pairs(tris)
    blade_of = components(m, pairs)
    similar = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) >= math.cos(
        math.radians(angle_deg))
    labels = components(m, pairs[similar])
    n_lab = int(labels.max()) + 1
    area = np.bincount(labels, weights=turbine.blade_areas, minlength=n_lab)
    first = np.full(n_lab, m, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(m))
    keep = np.flatnonzero(area >= min_area_fraction * area.max())
    keep = keep[np.argsort(first[keep])]
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(n_lab + 1))
    surfaces = []
    for sid, lab in enumerate(keep):
        idx = order[bounds[lab]:bounds[lab + 1]]
        surfaces.append(describe_surface(turbine, idx, sid, int(blade_of[idx[0]])))
    ignored = np.flatnonzero(~np.isin(labels, keep))
    return surfaces, ignored
