"""Ordering: the exact shortest tour over surfaces with two end nodes each (Held-Karp).

The problem (the paper's TSP with the "enter and leave a surface at its two ends" constraint):
every surface ``k`` has two end nodes (0 = root, 1 = tip) with stand-off positions
``ends[k, 0]`` and ``ends[k, 1]``. A tour starts at ``start``, visits every surface once, entering
at one end and leaving at the other, and moves between surfaces in straight lines. Its cost is the
sum of those moves (the surface traversals add the same constant to every tour). Direct moves
between ``forbidden`` pairs (opposite faces of a blade) are not allowed.

The paper enumerates all tours (n! 2^n: 4.7e11 for 12 surfaces). Dynamic programming over subsets
is exact and needs O(2^n n^2) work: ``dp[S, u]`` is the cheapest way to start, visit exactly the
surfaces in ``S`` and stand at exit node ``u`` (node ``2k + e`` = end ``e`` of surface ``k``;
entering at node ``v`` means leaving at ``v ^ 1``). Layers of equal ``|S|`` are computed with
vectorised (min, +) products, so 12 surfaces take a few milliseconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_EXACT_SURFACES = 16   # 2^16 x 32 states; beyond this the exact DP is too large to be useful


@dataclass(frozen=True)
class TourSolution:
    """An optimal tour: ``stops[i] = (surface, entry_end)``; ``cost`` excludes surface lengths."""

    stops: tuple[tuple[int, int], ...]
    cost: float

    @property
    def exit_node(self) -> int:
        """Node (``2 * surface + end``) where the tour finishes; -1 for an empty tour."""
        if not self.stops:
            return -1
        k, entry = self.stops[-1]
        return 2 * k + (1 - entry)


def _check_instance(ends: np.ndarray, start: np.ndarray, forbidden: np.ndarray | None) -> tuple:
    ends = np.asarray(ends, dtype=np.float64)
    if ends.ndim != 3 or ends.shape[1:] != (2, 3):
        raise ValueError(f"ends must have shape (n, 2, 3), got {ends.shape}")
    n = len(ends)
    if n > MAX_EXACT_SURFACES:
        raise ValueError(f"ends: {n} surfaces exceed the exact solver's limit of {MAX_EXACT_SURFACES}")
    start = np.asarray(start, dtype=np.float64).reshape(3)
    forb = np.zeros((n, n), dtype=bool) if forbidden is None else np.asarray(forbidden, dtype=bool)
    if forb.shape != (n, n):
        raise ValueError(f"forbidden must have shape ({n}, {n}), got {forb.shape}")
    if not (np.all(np.isfinite(ends)) and np.all(np.isfinite(start))):
        raise ValueError("ends and start must be finite")
    return ends, start, forb | forb.T


class HeldKarp:
    """The DP table of one instance: optimal costs to finish at each node, and the tours."""

    def __init__(self, ends: np.ndarray, start: np.ndarray | None, forbidden: np.ndarray | None = None, *,
                 start_cost: np.ndarray | None = None) -> None:
        """``start_cost`` (optional, ``(2n,)``) replaces the straight distances from ``start`` to the
        entry nodes, e.g. a one-hot 0/inf vector for tours that must begin at one given node."""
        ends, start, forb = _check_instance(ends, np.zeros(3) if start is None else start, forbidden)
        self.n = n = len(ends)
        nodes = ends.reshape(2 * n, 3)
        if start_cost is None:
            if start is None:
                raise ValueError("HeldKarp needs start or start_cost")
            self.start_cost = np.linalg.norm(nodes - start, axis=1)
        else:
            sc = np.asarray(start_cost, dtype=np.float64)
            if sc.shape != (2 * n,) or np.any(np.isnan(sc)):
                raise ValueError(f"start_cost must have shape ({2 * n},) without NaN, got {sc.shape}")
            self.start_cost = sc
        D = np.linalg.norm(nodes[:, None] - nodes[None], axis=2)       # exit node -> entry node
        surf = np.arange(2 * n) // 2
        blocked = forb[surf[:, None], surf[None, :]] | (surf[:, None] == surf[None, :])
        D[blocked] = np.inf
        self.move_cost = D
        full = 1 << n
        self.dp = np.full((full, 2 * n), np.inf)
        self.parent = np.full((full, 2 * n), -1, dtype=np.int64)
        if n == 0:
            return
        masks = np.arange(full, dtype=np.int64)
        pop = np.zeros(full, dtype=np.int64)
        for k in range(n):
            pop += (masks >> k) & 1
        for k in range(n):
            for e in (0, 1):                      # enter at end e, leave at end 1 - e
                self.dp[1 << k, 2 * k + 1 - e] = self.start_cost[2 * k + e]
                self.parent[1 << k, 2 * k + 1 - e] = -1
        for size in range(2, n + 1):
            layer = masks[pop == size]
            for k in range(n):
                T = layer[((layer >> k) & 1) == 1]
                prev = self.dp[T ^ (1 << k)]                              # (|T|, 2n)
                tot = prev[:, :, None] + D[None, :, 2 * k:2 * k + 2]     # (|T|, 2n, 2)
                best = np.argmin(tot, axis=1)                             # (|T|, 2)
                val = np.take_along_axis(tot, best[:, None, :], axis=1)[:, 0, :]
                for e in (0, 1):
                    self.dp[T, 2 * k + 1 - e] = val[:, e]
                    self.parent[T, 2 * k + 1 - e] = best[:, e]

    @property
    def end_costs(self) -> np.ndarray:
        """``(2n,)`` optimal cost of visiting everything and finishing at each exit node."""
        return self.dp[(1 << self.n) - 1]

    def tour(self, exit_node: int) -> TourSolution:
        """The optimal tour that finishes at ``exit_node``."""
        mask = (1 << self.n) - 1
        cost = float(self.dp[mask, exit_node])
        if not np.isfinite(cost):
            raise ValueError(f"no feasible tour ends at node {exit_node}")
        stops = []
        u = exit_node
        while mask:
            k = u // 2
            stops.append((k, 1 - (u & 1)))
            prev = int(self.parent[mask, u])
            mask ^= 1 << k
            u = prev
        return TourSolution(stops=tuple(reversed(stops)), cost=cost)


def solve_tour(ends: np.ndarray, start: np.ndarray, forbidden: np.ndarray | None = None) -> TourSolution | None:
    """Exact optimal open tour from ``start``; ``None`` if the forbidden moves leave no tour."""
    hk = HeldKarp(ends, start, forbidden)
    if hk.n == 0:
        return TourSolution(stops=(), cost=0.0)
    costs = hk.end_costs
    u = int(np.argmin(costs))
    return hk.tour(u) if np.isfinite(costs[u]) else None


def tour_cost(ends: np.ndarray, start: np.ndarray, stops: tuple[tuple[int, int], ...] | list) -> float:
    """Cost of a given tour (start leg + moves between surfaces; surface lengths excluded)."""
    ends = np.asarray(ends, dtype=np.float64)
    pos = np.asarray(start, dtype=np.float64)
    total = 0.0
    for k, entry in stops:
        total += float(np.linalg.norm(ends[k, entry] - pos))
        pos = ends[k, 1 - entry]
    return total
