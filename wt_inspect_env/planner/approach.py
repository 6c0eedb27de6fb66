"""The approach from a far start to the path's first stand-off pose, clear of the structure.

A drone may start up to tens of metres from the first pose, on any side of the turbine - behind a
blade, below the hub. A straight approach through the structure holds the drone against its MPC's
clearance constraint while the reference waits for it, until the reference stalls (in the
committed campaign three NREL 5-MW missions ended so at 0 % coverage). The router gives the
reference a polyline instead: the straight segment if it keeps the clearance, otherwise the
shortest detour through one or two via points that does, found by the planner's own transit
router (:class:`~.clearance.Clearance`, the same detour frame and offsets) around the whole mesh
of the rotor position the mission starts in, and above the ground.

The clearance asked for is d_min plus a margin, but never more than the start and the first pose
themselves have (each is where it is: the first pose clears d_min by the planner's guarantee, a
start is wherever the drone was put); below that the route could not begin or end.
"""
from __future__ import annotations

import numpy as np

from .clearance import Clearance, DistanceField, NoRouteError, detour_frame, detour_offsets

#: how much more than d_min [m] the approach route keeps where the start and the first pose allow:
#: the drone follows its moving pose with a lag, and the MPCs keep d_min plus their own back-off.
APPROACH_MARGIN = 0.5


class ApproachRouter:
    """Routes approaches around one rotor position's mesh (``triangles``) and above the ground at
    z = ``floor``; ``d_min``: the flight's minimum distance to the structure; ``standoff``: the
    stand-off distance (it sets the sampling step and the detour offsets, as in the planner)."""

    def __init__(self, triangles: np.ndarray, rotor_axis: np.ndarray, d_min: float, standoff: float,
                 floor: float = 0.0) -> None:
        self.field = DistanceField(triangles)
        self.d_min, self.floor = float(d_min), float(floor)
        self.step = standoff / 28.0           # the planner's default check step
        self.frame = detour_frame(rotor_axis)
        self.offsets = detour_offsets(standoff)

    def clearance_of(self, points: np.ndarray) -> np.ndarray:
        """Distance of each point to the structure or the ground, whichever is nearer."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        cap = self.d_min + APPROACH_MARGIN + self.step
        return np.minimum(self.field.distance(pts, cap), pts[:, 2] - self.floor)

    def __call__(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """A polyline (2 to 4 points) from ``start`` to ``goal`` that keeps
        min(d_min + margin, the start's and the goal's own clearance) from the structure and the
        ground; the straight segment if no such detour is found (the clearance constraint and the
        reference's stall rule then apply, as before there was a router)."""
        start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        ends = self.clearance_of(np.stack([start, goal]))
        want = min(self.d_min + APPROACH_MARGIN, float(ends.min()))
        clearance = want - self.step / 2.0 - 1e-6       # Clearance asks for clearance + step / 2
        straight = np.stack([start, goal])
        if clearance <= 0.0:
            return straight
        clr = Clearance(self.field, clearance, self.step, self.frame, self.offsets, floor=self.floor)
        try:
            return clr.route(start, goal)
        except NoRouteError:
            return straight
