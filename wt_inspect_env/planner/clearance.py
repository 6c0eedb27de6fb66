"""Clearance: exact distances from points to the turbine, and collision-free transit routes.

:class:`DistanceField` answers "how far is each point from the nearest triangle, up to
``max_distance``" exactly, with libigl's axis-aligned bounding-box tree (a compiled, well-kept
implementation of the exact point-triangle query; the planner asks it tens of thousands of times
per plan, and an earlier KD-tree on centroids with a NumPy closest-point test made planning a
turbine take seconds). :func:`closest_points_on_triangles` (Ericson's region test, vectorised)
remains for the callers that need the closest point on a given list of triangles.

:class:`Clearance` checks sampled stand-off paths against a required clearance and finds transit
routes: the straight segment if it is clear, otherwise the shortest clear detour through one or
two via points placed around the segment along the turbine's frame axes (rotor axis, vertical,
lateral and their diagonals) at growing offsets. A path is sampled every ``step`` and each sample
must clear ``clearance + step / 2``, so the continuous path between samples clears ``clearance``.
Where no such detour exists (a pose in a pocket between a blade root and the hub, where every
frame direction leads into the structure), :meth:`Clearance.grid_route` searches a grid of free
space: the shortest 26-connected path between cells certified clear (scipy's compiled Dijkstra),
then shortened by keeping only the turns a straight clear segment cannot skip.
"""
from __future__ import annotations

import itertools

import igl
import numpy as np


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Closest point on triangle ``(a[i], b[i], c[i])`` to ``p[i]`` (all ``(K, 3)``)."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in = vb / denom
        w_in = vc / denom
        out = a + ab * v_in[:, None] + ac * w_in[:, None]                    # interior
        bc_w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[:, None],
                       b + (c - b) * bc_w[:, None], out)                      # edge BC
        ac_w = d2 / (d2 - d6)
        out = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None], a + ac * ac_w[:, None], out)  # edge AC
        out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)                                  # vertex C
        ab_v = d1 / (d1 - d3)
        out = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None], a + ab * ab_v[:, None], out)  # edge AB
        out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)                                  # vertex B
        out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)                                   # vertex A
    return out


class DistanceField:
    """Exact point-to-mesh distances (capped at a query radius) for a fixed set of triangles.

    The triangles are kept as a soup (three vertices each, no welding): the distance to a soup is
    the distance to the mesh, and a loaded mesh need not be manifold or watertight for it."""

    def __init__(self, triangles: np.ndarray) -> None:
        tris = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        if len(tris) == 0:
            raise ValueError("DistanceField needs at least one triangle")
        if not np.all(np.isfinite(tris)):
            raise ValueError("DistanceField needs finite triangle vertices")
        self._vertices = np.ascontiguousarray(tris.reshape(-1, 3))
        self._faces = np.arange(len(self._vertices), dtype=np.int64).reshape(-1, 3)
        self._tree = igl.AABB()
        self._tree.init(self._vertices, self._faces)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The closest mesh point (P, 3) and the distance (P,) of each of the (P, 3) ``points``."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if len(pts) == 0:
            return np.zeros((0, 3)), np.zeros(0)
        sq, _, c = self._tree.squared_distance(self._vertices, self._faces, pts)
        return np.asarray(c, dtype=np.float64).reshape(-1, 3), np.sqrt(np.asarray(sq, dtype=np.float64).reshape(-1))

    def distance(self, points: np.ndarray, max_distance: float) -> np.ndarray:
        """Distance of each point to the mesh, exact below ``max_distance`` (else ``max_distance``)."""
        return np.minimum(self.closest(points)[1], float(max_distance))


def sample_polyline(poly: np.ndarray, step: float) -> np.ndarray:
    """Points along a polyline, at most ``step`` apart, including every vertex."""
    poly = np.asarray(poly, dtype=np.float64)
    out = [poly[:1]]
    for a, b in zip(poly[:-1], poly[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def polyline_length(poly: np.ndarray) -> float:
    """Length [m] of the polyline through the rows of ``poly``."""
    return float(np.linalg.norm(np.diff(poly, axis=0), axis=1).sum())


class NoRouteError(RuntimeError):
    """No collision-free transit was found between two stand-off positions."""


def detour_frame(axis: np.ndarray) -> np.ndarray:
    """Rows: rotor axis, vertical, lateral (axis x up): the directions detours are tried along."""
    up = np.array([0.0, 0.0, 1.0])
    axis = np.asarray(axis, dtype=np.float64)
    lat = np.cross(axis, up)
    if np.linalg.norm(lat) < 1e-6:
        lat = np.cross(axis, [1.0, 0.0, 0.0])
    return np.stack([axis, up, lat / np.linalg.norm(lat)])


def detour_offsets(standoff: float) -> tuple[float, ...]:
    """How far [m] detour via points are tried from the segment: half, one, two and four
    stand-offs (a stand-off clears a blade's chord from its face; four clear a rotor's hub)."""
    return tuple(standoff * f for f in (0.5, 1.0, 2.0, 4.0))


class Clearance:
    """Clearance checks and transit routing around one rotor configuration. ``floor``: the
    ground's height; a point counts as clear only that far above it too (default: no ground)."""

    def __init__(self, field: DistanceField, clearance: float, step: float, frame: np.ndarray,
                 offsets: tuple[float, ...], floor: float = -np.inf) -> None:
        self.field = field
        self.floor = float(floor)
        self.clearance = clearance
        self.step = step
        self.required = clearance + step / 2.0
        axes = np.asarray(frame, dtype=np.float64)          # rows: rotor axis, vertical, lateral
        dirs = []
        for coeffs in itertools.product((-1, 0, 1), repeat=3):
            if any(coeffs):
                v = np.asarray(coeffs, dtype=np.float64) @ axes
                dirs.append(v / np.linalg.norm(v))
        self.directions = np.array(dirs)
        self.offsets = tuple(offsets)

    def distances(self, points: np.ndarray) -> np.ndarray:
        """Distances capped just above the required clearance, and at most the height above the
        floor."""
        d = self.field.distance(points, self.required + 1e-6)
        if self.floor == -np.inf:
            return d
        return np.minimum(d, np.asarray(points, float).reshape(-1, 3)[:, 2] - self.floor)

    def is_clear(self, points: np.ndarray) -> bool:
        """Whether every point keeps the required clearance from the turbine."""
        return bool(np.all(self.distances(points) >= self.required))

    def polyline_clear(self, poly: np.ndarray) -> bool:
        """Whether the polyline keeps the required clearance, checked at samples ``step`` apart."""
        return self.is_clear(sample_polyline(poly, self.step))

    def route(self, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
        """Shortest clear polyline ``qa -> qb`` among the straight line and the candidate detours."""
        qa, qb = np.asarray(qa, float), np.asarray(qb, float)
        straight = np.stack([qa, qb])
        if self.polyline_clear(straight):
            return straight
        mid = 0.5 * (qa + qb)
        cands: list[np.ndarray] = []
        for off in self.offsets:
            for d in self.directions:
                for base in (mid, qa, qb):
                    cands.append(np.stack([qa, base + off * d, qb]))
                cands.append(np.stack([qa, qa + off * d, qb + off * d, qb]))
        lengths = np.array([polyline_length(c) for c in cands])
        # via points must themselves be clear; test them all at once before any segment
        vias = np.concatenate([c[1:-1] for c in cands])
        ok_via = self.distances(vias) >= self.required
        counts = np.array([len(c) - 2 for c in cands])
        ok = np.add.reduceat(ok_via.astype(int), np.r_[0, np.cumsum(counts)[:-1]]) == counts
        seg_cache: dict[tuple, bool] = {}

        def seg_ok(a: np.ndarray, b: np.ndarray) -> bool:
            key = (tuple(np.round(a, 9)), tuple(np.round(b, 9)))
            if key not in seg_cache:
                seg_cache[key] = self.polyline_clear(np.stack([a, b]))
            return seg_cache[key]

        for i in np.argsort(lengths, kind="stable"):
            if not ok[i]:
                continue
            c = cands[i]
            if all(seg_ok(c[j], c[j + 1]) for j in range(len(c) - 1)):
                return c
        route = self.grid_route(qa, qb)
        if route is None:
            raise NoRouteError(f"no collision-free transit from {np.round(qa, 2).tolist()} to "
                               f"{np.round(qb, 2).tolist()} with clearance {self.clearance} m")
        return route

    def grid_route(self, qa: np.ndarray, qb: np.ndarray, max_cells: int = 400_000) -> np.ndarray | None:
        """A clear polyline ``qa -> qb`` through a grid of free space, or None.

        The search box is the segment's bounding box grown by two clearances plus a quarter of the
        segment (then by twice that, then four times, until a route is found), cut into cubic cells
        of side ``h`` (at least ``step``, at most ``max_cells`` cells). A cell is free when its centre
        clears ``required + h sqrt(3) / 2``: the distance is 1-Lipschitz, so the straight segment
        between the centres of neighbouring cells (at most ``h sqrt(3)`` long) then clears
        ``required`` everywhere. ``qa`` and ``qb`` join the nearest free cells they reach in a
        clear straight line; the cell path found by Dijkstra is then shortened greedily (from
        each kept vertex, the farthest later vertex in clear sight), so the polyline is clear by
        the same sampled check as every other route."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import dijkstra
        qa, qb = np.asarray(qa, float), np.asarray(qb, float)
        if not (self.is_clear(qa[None]) and self.is_clear(qb[None])):
            return None
        base = 2.0 * self.clearance + 0.25 * float(np.linalg.norm(qb - qa))
        for grow in (1.0, 2.0, 4.0):
            lo = np.minimum(qa, qb) - grow * base
            hi = np.maximum(qa, qb) + grow * base
            h = max(self.step, float(np.cbrt(np.prod(hi - lo) / max_cells)))
            shape = np.maximum(np.ceil((hi - lo) / h).astype(int), 1)
            axes = [lo[k] + h * (np.arange(shape[k]) + 0.5) for k in range(3)]
            centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            need = self.required + h * np.sqrt(3.0) / 2.0
            free = self.field.distance(centres, need + 1e-6) >= need
            if self.floor != -np.inf:
                free &= centres[:, 2] - self.floor >= need
            fc = centres[free]
            ends = []
            for q in (qa, qb):          # the nearest free cells q sees in a clear straight line
                order = np.argsort(np.linalg.norm(fc - q, axis=1))[:64]
                ends.append(next((int(i) for i in order if self.polyline_clear(np.stack([q, fc[i]]))), None))
            if ends[0] is None or ends[1] is None:
                continue
            n = len(fc)
            index = np.full(len(centres), -1, dtype=np.int64)
            index[free] = np.arange(n)
            grid = index.reshape(shape)
            rows, cols, wts = [], [], []
            for off in itertools.product((-1, 0, 1), repeat=3):
                if off <= (0, 0, 0):        # each undirected edge once
                    continue
                src = grid[tuple(slice(max(0, -o), shape[k] - max(0, o)) for k, o in enumerate(off))]
                dst = grid[tuple(slice(max(0, o), shape[k] - max(0, -o)) for k, o in enumerate(off))]
                both = (src >= 0) & (dst >= 0)
                rows.append(src[both])
                cols.append(dst[both])
                wts.append(np.full(int(both.sum()), h * float(np.linalg.norm(off))))
            r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(wts)
            graph = coo_matrix((w, (r, c)), shape=(n, n)).tocsr()
            dist, pred = dijkstra(graph, directed=False, indices=ends[0], return_predecessors=True)
            if not np.isfinite(dist[ends[1]]):
                continue
            chain, k = [], ends[1]
            while k >= 0:
                chain.append(k)
                k = int(pred[k])
            path = np.vstack([qa, fc[chain[::-1]], qb])
            out, i = [path[0]], 0
            while i < len(path) - 1:
                j = next(j for j in range(len(path) - 1, i, -1)
                         if j == i + 1 or self.polyline_clear(np.stack([path[i], path[j]])))
                out.append(path[j])
                i = j
            route = np.array(out)
            if self.polyline_clear(route):
                return route
        return None
