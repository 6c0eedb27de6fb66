"""Clustering: group blade triangles into inspection surfaces from their geometry alone.

Blades are the connected parts of the blade triangles (touching = sharing a vertex position).
Each blade's surface is split into four *sectors* by the direction of the normal within the
blade's cross-section: the two sides (on an aerofoil the suction and pressure side) and the two
edges (leading and trailing edge). The section frame is found from the mesh, not from labels:
along the blade's long axis, in bins of a few mesh cells, the area-weighted fourfold mean of the
normals' in-section angles (``arg sum w exp(4 i psi)``; a rectangle's or an aerofoil's section
gives its chord direction modulo 90 deg) - so on a twisted blade the frame turns with the twist;
bins without a direction (a circular root) take their nearest neighbour's; sector k is the
quarter of normal angles within 45 deg of ``psi0 + k 90 deg``. Surfaces are the connected
components of touching triangles in the same sector. Triangles whose normal leans more than
``angle_deg`` out of the section plane face the root or tip (caps) and belong to no surface.
Nothing here reads the builder's labels, so a mesh loaded from a file is clustered the same way.
On the cuboid blades this yields the four long faces of each blade (their normals lie exactly on
the four sector centres).

Each surface is then summarised: the area-weighted mean normal, and the centre line with its two
end nodes. A flat face keeps the paper's straight "centre line through the triangle centres"
(through the face's area centroid along its long principal axis; an end node sits at the centre
of the end row of triangles, half a mesh cell in from the root or tip). A curved surface (an
aerofoil side, twisted) gets a polyline: in bins about one metre long along its long axis, the
point where the line through the bin's area centroid along the bin's mean normal meets the
outermost triangle, with that mean normal - so path normals turn with the twist. Components much
smaller than the largest (``min_area_fraction``) are not inspection surfaces and are reported as
ignored.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..turbine.mesh import TurbineMesh, area_moments, components, touching_pairs
from .clearance import closest_points_on_triangles


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
    line: np.ndarray | None = None           # (m, 3) centre-line nodes root -> tip (None: root, tip)
    line_normals: np.ndarray | None = None   # (m, 3) unit normal at each node (None: normal)

    @property
    def nodes(self) -> np.ndarray:
        """``(m, 3)`` centre-line nodes from root to tip (two for a flat face)."""
        return np.stack([self.root, self.tip]) if self.line is None else self.line

    @property
    def node_normals(self) -> np.ndarray:
        """``(m, 3)`` the normal at each node (constant on a flat face, turning with a twist)."""
        return np.stack([self.normal, self.normal]) if self.line_normals is None else self.line_normals

    @property
    def end_normals(self) -> np.ndarray:
        """``(2, 3)``: normal at the root and at the tip."""
        nn = self.node_normals
        return np.stack([nn[0], nn[-1]])

    @property
    def elevation_range_deg(self) -> tuple[float, float]:
        """Lowest and highest elevation of the node normals above the horizontal."""
        el = np.degrees(np.arcsin(np.clip(self.node_normals[:, 2], -1.0, 1.0)))
        return float(el.min()), float(el.max())

    @property
    def ends(self) -> np.ndarray:
        """``(2, 3)``: end node 0 = root, end node 1 = tip."""
        return np.stack([self.root, self.tip])

    @property
    def length(self) -> float:
        """Length [m] of the surface's centre line (through its nodes)."""
        return float(np.linalg.norm(np.diff(self.nodes, axis=0), axis=1).sum())

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
    normals = turbine.blade_normals[idx]
    n = area @ normals
    if np.linalg.norm(n) < 1e-6 * area.sum():
        raise ValueError(f"surface {surface_id}: its normals cancel out (a closed tube?), so it has no "
                         "inspection direction")
    n /= np.linalg.norm(n)
    mean, M, _ = area_moments(tris)
    P = np.eye(3) - np.outer(n, n)
    planar = bool(np.all(normals @ n > 1.0 - 1e-9))
    # long axis: in the face's plane for a flat face, of the whole surface for a curved one
    e = np.linalg.eigh(P @ M @ P if planar else M)[1][:, -1]
    if (mean - turbine.rotor_center) @ e < 0:  # orient root -> tip (away from the rotor centre)
        e = -e
    across = np.cross(n, e)
    va = (tris - mean) @ across
    width = float(va.max() - va.min())
    tv = (tris - mean) @ e                      # (k, 3) vertex projections on the centre line
    t_lo, t_hi = tv.min(), tv.max()
    if planar:
        tol = 1e-6 * max(t_hi - t_lo, 1.0)
        tc = cent @ e - mean @ e
        at_root = tv.min(axis=1) <= t_lo + tol
        at_tip = tv.max(axis=1) >= t_hi - tol
        t_root = float(np.average(tc[at_root], weights=area[at_root]))
        t_tip = float(np.average(tc[at_tip], weights=area[at_tip]))
        return Surface(id=surface_id, triangles=idx, blade=int(blade), normal=n,
                       root=mean + t_root * e, tip=mean + t_tip * e, width=width, area=float(area.sum()))
    u = (cent - mean) @ e
    n_bins = int(np.clip(math.ceil((t_hi - t_lo) / CURVED_NODE_SPACING), 2, 400))
    edges = np.linspace(u.min(), u.max(), n_bins + 1)
    which = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, n_bins - 1)
    pts, nrm = [], []
    for b in range(n_bins):
        sel = which == b
        if not sel.any():
            continue
        w = area[sel]
        c_b = w @ cent[sel] / w.sum()
        n_b = w @ normals[sel]
        n_b /= np.linalg.norm(n_b)
        # the outermost triangle along n_b near the bin's axis; meet its plane along n_b
        k = np.flatnonzero(sel)
        off = cent[k] - c_b
        lateral = np.linalg.norm(off - np.outer(off @ n_b, n_b), axis=1)
        near = k[lateral <= lateral.min() + 0.5 * max(width, 1e-9)]
        j = near[np.argmax((cent[near] - c_b) @ n_b)]
        nj = normals[j]
        denom = float(n_b @ nj)
        h = float((cent[j] - c_b) @ nj) / denom if abs(denom) > 1e-6 else float((cent[j] - c_b) @ n_b)
        x = c_b + h * n_b
        # snap onto the surface: the closest point of the bin's triangles
        tb = tris[k]
        cp = closest_points_on_triangles(np.repeat(x[None], len(k), axis=0), tb[:, 0], tb[:, 1], tb[:, 2])
        pts.append(cp[np.argmin(np.linalg.norm(cp - x, axis=1))])
        nrm.append(n_b)
    line, line_n = np.array(pts), np.array(nrm)
    return Surface(id=surface_id, triangles=idx, blade=int(blade), normal=n, root=line[0], tip=line[-1],
                   width=width, area=float(area.sum()), line=line, line_normals=line_n)


CURVED_NODE_SPACING = 1.0   # [m] centre-line node spacing on curved surfaces
SECTION_BIN_CELLS = 3.0     # section-frame bins are this many median edge lengths long


def blade_sectors(tris: np.ndarray, normals: np.ndarray, areas: np.ndarray, rotor_center: np.ndarray,
                  cap_angle_deg: float) -> np.ndarray:
    """Sector 0..3 of each triangle of one blade (-1: faces the root or tip), see the module
    docstring; sector 0 is the direction the fourfold mean points to in the first bin that has
    one, and a sector keeps its side of the blade along a twisted span."""
    mean, M, _ = area_moments(tris)
    e = np.linalg.eigh(M)[1][:, -1]
    if (mean - rotor_center) @ e < 0:
        e = -e
    b1 = np.cross(e, [0.0, 0.0, 1.0]) if abs(e[2]) < 0.9 else np.cross(e, [1.0, 0.0, 0.0])
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(e, b1)
    ne = normals @ e
    npp = normals - np.outer(ne, e)
    psi = np.arctan2(npp @ b2, npp @ b1)
    cap = np.abs(ne) > math.sin(math.radians(cap_angle_deg))
    w = areas * np.einsum("ij,ij->i", npp, npp) * ~cap
    u = (tris.mean(axis=1) - mean) @ e
    edge = float(np.median(np.linalg.norm(tris - tris[:, [1, 2, 0]], axis=2)))
    span = float(u.max() - u.min())
    n_bins = int(np.clip(round(span / max(SECTION_BIN_CELLS * edge, 1e-9)), 1, 200))
    edges = np.linspace(u.min(), u.max(), n_bins + 1)
    which = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, n_bins - 1)
    z = np.bincount(which, weights=w * np.cos(4 * psi), minlength=n_bins) + \
        1j * np.bincount(which, weights=w * np.sin(4 * psi), minlength=n_bins)
    strength = np.abs(z) / np.maximum(np.bincount(which, weights=w, minlength=n_bins), 1e-300)
    good = np.flatnonzero(strength > 0.2)
    if len(good) == 0:            # a round blade has no section frame: one fixed frame for it all
        psi0_bins = np.zeros(n_bins)
    else:
        ang = np.angle(z) / 4.0
        # nearest bin with a direction for those without one, then unwrap modulo 90 deg
        nearest = good[np.argmin(np.abs(np.arange(n_bins)[:, None] - good[None, :]), axis=1)]
        a = ang[nearest]
        q = math.pi / 2.0
        for i in range(1, n_bins):
            a[i] = a[i - 1] + ((a[i] - a[i - 1] + q / 2.0) % q - q / 2.0)
        start = good[0]
        a -= a[start] - ang[start]
        psi0_bins = a
    centres = 0.5 * (edges[:-1] + edges[1:])
    psi0 = np.interp(u, centres, psi0_bins) if n_bins > 1 else np.full(len(u), psi0_bins[0])
    sector = np.mod(np.round((psi - psi0) / (math.pi / 2.0)), 4).astype(np.int64)
    sector[cap] = -1
    return sector


def cluster_surfaces(turbine: TurbineMesh, *, angle_deg: float = 20.0,
                     min_area_fraction: float = 0.05) -> tuple[list[Surface], np.ndarray]:
    """Inspection surfaces of ``turbine`` (ids ordered by their first triangle) and the ignored
    triangle indices (caps: normals leaning more than ``angle_deg`` out of the section plane, and
    components smaller than ``min_area_fraction`` of the largest one)."""
    tris = turbine.blade_vertices
    m = len(tris)
    pairs = touching_pairs(tris)
    blade_of = components(m, pairs)
    sector = np.full(m, -1, dtype=np.int64)
    for b in np.unique(blade_of):
        sel = np.flatnonzero(blade_of == b)
        sector[sel] = blade_sectors(tris[sel], turbine.blade_normals[sel], turbine.blade_areas[sel],
                                    turbine.rotor_center, angle_deg)
    key = np.where(sector >= 0, 4 * blade_of + sector, -1)
    same = (key[pairs[:, 0]] == key[pairs[:, 1]]) & (key[pairs[:, 0]] >= 0) if len(pairs) else np.zeros(0, bool)
    labels = components(m, pairs[same] if len(pairs) else pairs)
    n_lab = int(labels.max()) + 1
    area = np.bincount(labels, weights=turbine.blade_areas * (key >= 0), minlength=n_lab)
    first = np.full(n_lab, m, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(m))
    keep = np.flatnonzero((area >= min_area_fraction * area.max()) & (area > 0))
    keep = keep[np.argsort(first[keep])]
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(n_lab + 1))
    surfaces = []
    for sid, lab in enumerate(keep):
        idx = order[bounds[lab]:bounds[lab + 1]]
        surfaces.append(describe_surface(turbine, idx, sid, int(blade_of[idx[0]])))
    ignored = np.flatnonzero(~np.isin(labels, keep))
    return surfaces, ignored
