"""Transit routing where no one- or two-via detour exists: the free-space grid search."""
from __future__ import annotations

import math

import numpy as np
import pytest
from oracles import brute_distance

from wt_inspect_env.planner.clearance import Clearance, DistanceField, NoRouteError, polyline_length, sample_polyline


def _quad(corners):
    a, b, c, d = (np.asarray(x, float) for x in corners)
    return [np.stack([a, b, c]), np.stack([a, c, d])]


def _box(lo, hi):
    """The six faces of an axis-aligned box, as triangles."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    faces = [[(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],
             [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)],
             [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],
             [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],
             [(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)],
             [(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)]]
    return np.array([t for f in faces for t in _quad(f)])


def _clearance(tris, offsets=(0.5,), clearance=1.0, step=0.25):
    return Clearance(DistanceField(tris), clearance, step, np.eye(3), offsets)


def test_a_wall_the_short_detours_cannot_pass_is_routed_around_clear_of_it():
    """A 10 x 10 m wall between the two ends; detours of at most 0.5 m cannot pass it, the grid
    search does, and the route keeps the required clearance against brute force."""
    wall = np.array(_quad([(0, -5, -5), (0, 5, -5), (0, 5, 5), (0, -5, 5)]))
    clr = _clearance(wall)
    qa, qb = np.array([-3.0, 0.0, 0.0]), np.array([3.0, 0.0, 0.0])
    route = clr.route(qa, qb)
    np.testing.assert_array_equal(route[0], qa)
    np.testing.assert_array_equal(route[-1], qb)
    pts = sample_polyline(route, 0.05)
    assert brute_distance(pts, wall).min() >= clr.clearance - 1e-9
    # around the nearest edge: the shortest way is over 2 x hypot(3, 5 + 1) = 13.4 m
    assert 2 * math.hypot(3.0, 5.0 + clr.clearance) - 1e-6 <= polyline_length(route) <= 20.0


@pytest.mark.slow
@pytest.mark.unit
def test_an_enclosed_end_has_no_route():
    """The start inside a closed box: no path, and the error names both ends."""
    box = _box((-4, -4, -4), (4, 4, 4))
    clr = _clearance(box)
    with pytest.raises(NoRouteError, match=r"no collision-free transit from \[0.0, 0.0, 0.0\] to \[12.0"):
        clr.route(np.zeros(3), np.array([12.0, 0.0, 0.0]))
    assert clr.grid_route(np.zeros(3), np.array([12.0, 0.0, 0.0])) is None


def test_the_ground_bounds_the_grid_search():
    """With a floor, the route may not dip under the wall to pass it."""
    wall = np.array(_quad([(0, -30, 0), (0, 30, 0), (0, 30, 4), (0, -30, 4)]))
    clr = Clearance(DistanceField(wall), 1.0, 0.25, np.eye(3), (0.5,), floor=0.0)
    route = clr.route(np.array([-3.0, 0.0, 2.0]), np.array([3.0, 0.0, 2.0]))
    pts = sample_polyline(route, 0.05)
    assert pts[:, 2].min() >= 1.0 + 0.125 - 1e-9          # required clearance above the ground
    assert pts[:, 2].max() >= 4.0 + 1.0 - 1e-9             # it went over the wall
