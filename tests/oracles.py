"""Test oracles shared by several test files (imported as ``from oracles import ...``, like
``closed_loop``)."""
from __future__ import annotations

import numpy as np

from wt_inspect_env.planner.clearance import closest_points_on_triangles


def brute_distance(points, tris, chunk=400):
    """Distance of each point to the nearest of *all* triangles, exhaustively (chunks of points x
    all triangles; no spatial search)."""
    points, tris = np.asarray(points, dtype=float), np.asarray(tris, dtype=float)
    out = []
    for s in range(0, len(points), chunk):
        P = points[s:s + chunk]
        Pr = np.repeat(P, len(tris), axis=0)
        T = np.tile(tris, (len(P), 1, 1))
        d = np.linalg.norm(Pr - closest_points_on_triangles(Pr, T[:, 0], T[:, 1], T[:, 2]), axis=1)
        out.append(d.reshape(len(P), len(tris)).min(axis=1))
    return np.concatenate(out)
