"""The inspection plan: clustering -> rotor positions -> exact ordering -> collision-free path.

Phases (the paper's section "Automated Inspection Framework", generalised): a surface is
*inspectable* at a rotor position if a level camera can see it there (normal elevation within
``[-max_down_deg, max_up_deg]``) and its stand-off along the whole centre line is at least
``clearance`` from the turbine. Phase 1 inspects, with the rotor as found, every surface
inspectable there; the others (on the paper's inverted Y, the two faces looking 60 deg down, whose
stand-offs would also lie inside the other lower blade) wait for a rotor turn. Between phases the
drone waits at a *hold point* outside the volume swept by the blades (its last stand-off if that
is already outside, else that stand-off moved along the rotor axis to the front faces' stand-off
plane), the rotor turns, and the next phase inspects, on the turned rotor, the waiting surfaces
inspectable there (points of later phases are in world coordinates on the rotated blades).

Rotor positions: with ``rotor_turn_deg`` a number, one turn by that angle (the paper's 120 deg);
a waiting surface not inspectable after it is an error. With ``rotor_turn_deg=None`` the planner
chooses: no turn if everything is inspectable as found, else the fewest turns (one, or two, e.g.
for the upright Y at azimuth 60 deg, where one lower blade's downward edge and the other's need
different positions) and, among the candidate angles (multiples of ``rotor_turn_step_deg`` in
(-180, 180]), those with the least total flight, each surface inspected at the first position that
allows it. :attr:`InspectionPlan.rotor_positions` says which surface is inspected at which rotor
position.

"Stand-off clear" allows trimming: where only the ends of a surface's stand-off line come too
close to the turbine (the root of a back face passing behind a large hub), the centre line's end
nodes move inwards to where it clears, by at most ``max_end_trim`` (default a quarter of the
stand-off); ``Surface.trim`` and the summary's ``trimmed_m`` say by how much.

Ordering is exact for the whole multi-phase problem: phase 1 is one Held-Karp table from the
start; for every way a phase can finish (each exit node of its table) the retreat to that exit's
hold point and the next phase's Held-Karp table from there are added, and the cheapest chain is
kept (dynamic programming over phases). Costs are straight-line distances between stand-off
positions, as in the paper; ``tour_length`` is that objective plus the surface lengths (the
distance flown along stand-offs if every move were straight), ``path_length`` is the length of the
actual stand-off path (wraps swing round blade edges, transits may detour).

Labels of path samples: ``surface`` is the surface id while a surface's centre line is inspected
and ``-1`` on every transition (take-off climb, wraps round blade edges, transits, the retreats
before the turns); ``phase`` is the rotor position the sample belongs to: 1 up to and including
the first hold point, 2 after the first turn, and so on (a transition therefore carries the phase
of the surface it approaches, except a retreat, which happens before its turn).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..turbine.mesh import TurbineMesh, rotation_matrix
from ..util.atomic_io import atomic_path
from .clearance import Clearance, DistanceField, detour_frame, detour_offsets
from .clustering import Surface, cluster_surfaces, describe_surface
from .config import PlannerConfig
from .ordering import HeldKarp, TourSolution
from .path import Piece, offset_direction, resample, surface_piece, transit_piece, wrap_corner, wrap_piece

CSV_HEADER = "x,y,z,nx,ny,nz,surface,phase,s"
OPPOSITE_COS = math.cos(math.radians(150.0))   # normals further apart than 150 deg: opposite faces
ADJACENT_COS = 0.5                              # |n_a . n_b| below this: faces meeting at an edge
KIND_NAMES = ("surface", "wrap", "transit")
_BAND_EDGE_DEG = 1e-9                           # a face exactly on the band edge is in it (turned normals round)


@dataclass(frozen=True)
class TourStop:
    """One surface of the tour: its id, the phase it is inspected in and the end it is entered at."""

    surface: int
    phase: int
    entry: str        # "root" or "tip"


@dataclass(frozen=True)
class RotorPosition:
    """One rotor position of a plan: phase number, turn from the rotor as found (right-handed about
    the rotor axis, in (-180, 180]) and the surfaces inspected there, in tour order."""

    phase: int
    turn_deg: float
    surfaces: tuple[int, ...]


@dataclass(eq=False)
class InspectionPlan:
    """Result of :func:`plan_inspection` (arrays have one row per path sample)."""

    points: np.ndarray            # (K, 3) inspection points
    normals: np.ndarray           # (K, 3) outward unit normals
    surface: np.ndarray           # (K,) surface id, -1 on transitions
    phase: np.ndarray             # (K,) 1, 2, ... (rotor position, see rotor_positions)
    s: np.ndarray                 # (K,) arc length of the inspection point (non-decreasing)
    standoff_points: np.ndarray   # (K, 3) drone stand-off positions
    standoff_s: np.ndarray        # (K,) arc length of the stand-off path (increasing)
    kind: np.ndarray              # (K,) 0 surface, 1 wrap round a blade edge, 2 transit
    tour: tuple[TourStop, ...]
    tour_length: float
    surfaces: tuple[Surface, ...]             # geometry in phase 1 (ids index this tuple)
    surfaces_phase2: dict[int, Surface]       # geometry of the surfaces inspected after a turn, there
    surface_phase: np.ndarray                 # (n_surfaces,) phase each surface is inspected in
    turbines: tuple[TurbineMesh, ...]         # the turbine at each rotor position (index 0 = phase 1)
    rotor_positions: tuple[RotorPosition, ...]
    standoff: float
    config: PlannerConfig
    start: np.ndarray
    hold_points: tuple[np.ndarray, ...]       # where the drone waits for each rotor turn
    ignored_triangles: np.ndarray             # blade triangles in no surface (e.g. caps of a file)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_surfaces(self) -> int:
        """Number of surfaces the plan inspects."""
        return len(self.surfaces)

    @property
    def n_phases(self) -> int:
        """Number of rotor positions (phases) of the plan."""
        return len(self.rotor_positions)

    @property
    def turbine_phase1(self) -> TurbineMesh:
        """The turbine as it stands at the start (first rotor position)."""
        return self.turbines[0]

    @property
    def turbine_phase2(self) -> TurbineMesh | None:
        """The turbine after the first rotor turn (``None`` if the plan needs none)."""
        return self.turbines[1] if len(self.turbines) > 1 else None

    @property
    def hold_point(self) -> np.ndarray | None:
        """Where the drone waits for the first rotor turn (``None`` without a turn)."""
        return self.hold_points[0] if self.hold_points else None

    @property
    def rotor_turns_deg(self) -> tuple[float, ...]:
        """The turns between consecutive phases (what the operator does at each hold)."""
        t = [r.turn_deg for r in self.rotor_positions]
        return tuple(float((b - a + 180.0) % 360.0 - 180.0) if (b - a) % 360.0 != 180.0 else 180.0
                     for a, b in zip(t[:-1], t[1:]))

    @property
    def path_length(self) -> float:
        """Length of the stand-off (drone) path."""
        return float(self.standoff_s[-1])

    def surface_geometry(self, surface_id: int) -> Surface:
        """Geometry of a surface in the rotor configuration it is inspected in."""
        return self.surfaces_phase2.get(surface_id, self.surfaces[surface_id])

    def turbine(self, phase: int) -> TurbineMesh:
        """The turbine at the rotor position of ``phase`` (1-based)."""
        if not 1 <= int(phase) <= len(self.turbines):
            raise ValueError(f"phase must lie in [1, {len(self.turbines)}], got {phase!r}")
        return self.turbines[int(phase) - 1]

    def min_clearance(self, cap: float | None = None) -> float:
        """Exact smallest distance from the path's stand-off positions to the turbine of their
        phase (capped at ``cap``, default the stand-off distance)."""
        cap = self.standoff if cap is None else cap
        best = cap
        for ph in range(1, self.n_phases + 1):
            sel = self.phase == ph
            if sel.any():
                d = DistanceField(self.turbine(ph).all_triangles).distance(self.standoff_points[sel], cap)
                best = min(best, float(d.min()))
        return best

    def to_csv(self, path: str | Path) -> Path:
        """Write ``x,y,z,nx,ny,nz,surface,phase,s`` (atomically)."""
        data = np.column_stack([self.points, self.normals, self.surface, self.phase, self.s])
        fmt = ["%.6f"] * 6 + ["%d", "%d", "%.6f"]
        with atomic_path(path) as tmp:
            np.savetxt(tmp, data, fmt=fmt, delimiter=",", header=CSV_HEADER, comments="")
        return Path(path)

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {
            "surfaces": self.n_surfaces,
            "surfaces_phase1": int(np.sum(self.surface_phase == 1)),
            "surfaces_phase2": int(np.sum(self.surface_phase == 2)),
            "tour": [{"surface": t.surface, "phase": t.phase, "entry": t.entry} for t in self.tour],
            "tour_length_m": round(self.tour_length, 4),
            "path_length_m": round(self.path_length, 4),
            "inspection_length_m": round(float(sum(self.surface_geometry(i).length
                                                   for i in range(self.n_surfaces))), 4),
            "samples": int(len(self.points)),
            "spacing_m": self.config.spacing,
            "standoff_m": self.standoff,
            "rotor_turn_deg": self.rotor_turns_deg[0] if self.rotor_turns_deg else None,
            "rotor_positions": [{"phase": r.phase, "turn_deg": r.turn_deg, "surfaces": list(r.surfaces)}
                                for r in self.rotor_positions],
            "trimmed_m": {i: [round(float(t), 4) for t in self.surface_geometry(i).trim]
                          for i in range(self.n_surfaces) if any(self.surface_geometry(i).trim)},
            "plan_time_s": round(self.timings.get("total", float("nan")), 6),
            "timings_s": {k: round(v, 6) for k, v in self.timings.items()},
        }


# --------------------------------------------------------------------------- helpers
def _forbidden(geo: list[Surface]) -> np.ndarray:
    """Opposite faces of one blade: a straight move between them would pass through the blade."""
    n = np.array([g.normal for g in geo]).reshape(-1, 3)
    blade = np.array([g.blade for g in geo])
    return (n @ n.T < OPPOSITE_COS) & (blade[:, None] == blade[None, :])


def _standoff_ends(geo: list[Surface], d: float, mode: str) -> np.ndarray:
    if not geo:
        return np.zeros((0, 2, 3))
    return np.stack([g.ends + d * offset_direction(g.end_normals, mode) for g in geo])


def _along(g: Surface) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes, node normals and their arc length along the centre line."""
    nodes, nn = g.nodes, g.node_normals
    return nodes, nn, np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(nodes, axis=0), axis=1))]


def _points_at(g: Surface, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre-line points and (renormalised, linearly interpolated) normals at arc lengths ``x``."""
    nodes, nn, s = _along(g)
    P = np.stack([np.interp(x, s, nodes[:, j]) for j in range(3)], axis=1)
    N = np.stack([np.interp(x, s, nn[:, j]) for j in range(3)], axis=1)
    return P, N / np.linalg.norm(N, axis=1, keepdims=True)


def _cut(g: Surface, x0: float, x1: float) -> Surface:
    """``g`` with its centre line cut to the arc-length interval ``[x0, x1]`` (trim recorded)."""
    nodes, nn, s = _along(g)
    inner = (s > x0 + 1e-9) & (s < x1 - 1e-9)
    P, N = _points_at(g, np.array([x0, x1]))
    trim = (float(g.trim[0] + max(x0, 0.0)), float(g.trim[1] + max(s[-1] - x1, 0.0)))
    if g.line is None:
        return dataclasses.replace(g, root=P[0], tip=P[1], trim=trim)
    line = np.concatenate([P[:1], nodes[inner], P[1:]])
    ln = np.concatenate([N[:1], nn[inner], N[1:]])
    return dataclasses.replace(g, root=line[0], tip=line[-1], line=line, line_normals=ln, trim=trim)


def _inspectable(clr: Clearance, g: Surface, d: float, mode: str, max_trim: float) -> Surface | str:
    """``g`` (with its ends trimmed inwards if needed) if its stand-off line is clear, else why not.

    The stand-off follows the centre line node by node (``p + d offset(n)``), so clear stand-off
    points map to centre-line points by arc length. The line is first checked at half the check
    step of centre-line arc length (the stand-off moves at most a few percent faster where the
    normals turn with a twist); if only stretches within ``max_trim`` (+ one step) of its ends
    fail, those are resampled finely (``h`` = a quarter of the check step) and cut where the
    samples clear ``clearance + check_step/2 + h``; the cut line is checked again as the path
    will be.
    """
    length = g.length
    n_c = max(2, math.ceil(length / (0.5 * clr.step)) + 1)
    x = np.linspace(0.0, length, n_c)
    P, N = _points_at(g, x)
    pts_c = P + d * offset_direction(N, mode)
    ok_c = clr.distances(pts_c) >= clr.required
    if ok_c.all():
        return g
    dmin = float(clr.field.distance(pts_c[~ok_c], d).min())
    blocked = (f"standoff {d!r} m puts the drone {dmin:.2f} m from the turbine (clearance "
               f"{clr.clearance} m + check_step/2 required)")
    bad = x[~ok_c]
    reach = max_trim + clr.step
    if max_trim <= 0 or not np.all((bad <= reach) | (bad >= length - reach)) or length <= 2 * reach:
        return (f"{blocked} away from the ends of its centre line" if max_trim > 0 else
                f"{blocked}; trimming its ends is off (max_end_trim {max_trim!r} m)")
    h = clr.step / 4.0
    cuts = []
    for end, sign in ((0.0, 1.0), (length, -1.0)):
        xs = end + sign * np.arange(0.0, reach + h / 2, h)
        Pe, Ne = _points_at(g, xs)
        ok = clr.field.distance(Pe + d * offset_direction(Ne, mode), clr.required + h + 1e-6) >= clr.required + h
        if not ok.any():
            return blocked
        cuts.append(float(abs(xs[int(np.argmax(ok))] - end)))
    if max(cuts) > max_trim:
        return (f"{blocked}; its clear part would need {cuts[0]:.2f} m (root) and {cuts[1]:.2f} m (tip) "
                f"trimmed from the ends, more than max_end_trim {max_trim!r} m")
    trimmed = _cut(g, cuts[0], length - cuts[1])
    xt = np.linspace(0.0, trimmed.length, max(2, math.ceil(trimmed.length / (0.5 * clr.step)) + 1))
    Pt, Nt = _points_at(trimmed, xt)
    if not clr.is_clear(Pt + d * offset_direction(Nt, mode)):   # pragma: no cover - by construction
        return f"{blocked} away from the ends of its centre line"
    return trimmed


def _wrap_deg(angle: float) -> float:
    """Angle in (-180, 180]."""
    w = (float(angle) + 180.0) % 360.0 - 180.0
    return 180.0 if w == -180.0 else w


class _Position:
    """A candidate rotor position: the turned turbine, its clearance checker (built on first use)
    and, per surface on demand, its trimmed geometry there or why it is not inspectable."""

    def __init__(self, turbine: TurbineMesh, surfaces: list[Surface], turn_deg: float, cfg: PlannerConfig,
                 frame: np.ndarray, offsets: tuple[float, ...], redescribe: bool = True) -> None:
        self.turn = turn_deg
        self.turbine = turbine if turn_deg == 0.0 else turbine.rotated(turn_deg)
        self._surfaces, self._cfg, self._frame, self._offsets = surfaces, cfg, frame, offsets
        # the rotor turn is rigid, so a surface's description turns with it; re-describing it on the
        # turned mesh gives the same up to rounding, at a cost per curved surface (done for the one
        # position of a fixed turn, whose plans stay bit-identical to earlier versions)
        self._redescribe = redescribe
        self._R = rotation_matrix(turbine.rotor_axis, math.radians(turn_deg))
        self._c = turbine.rotor_center
        self._clr: Clearance | None = None
        self._checked: dict[int, Surface | str] = {}

    @property
    def clr(self) -> Clearance:
        if self._clr is None:
            c = self._cfg
            self._clr = Clearance(DistanceField(self.turbine.all_triangles), c.clearance, c.check_step,
                                  self._frame, self._offsets)
        return self._clr

    def check(self, sid: int) -> Surface | str:
        if sid not in self._checked:
            c, s0 = self._cfg, self._surfaces[sid]
            if self.turn == 0.0:
                g = s0
            elif self._redescribe:
                g = describe_surface(self.turbine, s0.triangles, sid, s0.blade)
            else:
                g = self._turned(s0)
            lo, hi = g.elevation_range_deg
            if lo < -c.max_down_deg - _BAND_EDGE_DEG or hi > c.max_up_deg + _BAND_EDGE_DEG:
                el = f"{g.elevation_deg:.1f}" if g.line is None else f"{lo:.1f}..{hi:.1f}"
                self._checked[sid] = (f"normal elevation {el} deg, outside [-max_down_deg, "
                                      f"max_up_deg] = [-{c.max_down_deg}, {c.max_up_deg}]")
            else:
                self._checked[sid] = _inspectable(self.clr, g, c.standoff, c.standoff_mode, c.end_trim_limit)
        return self._checked[sid]

    def _turned(self, s0: Surface) -> Surface:
        R, c = self._R, self._c

        def pt(v: np.ndarray | None) -> np.ndarray | None:
            return None if v is None else (v - c) @ R.T + c

        def vec(v: np.ndarray | None) -> np.ndarray | None:
            return None if v is None else v @ R.T

        return dataclasses.replace(s0, normal=vec(s0.normal), root=pt(s0.root), tip=pt(s0.tip),
                                   line=pt(s0.line), line_normals=vec(s0.line_normals))

    def inspectable(self, sids: list[int]) -> list[int]:
        return [i for i in sids if isinstance(self.check(i), Surface)]


class _RotorGeometry:
    """Extent of the blades about the rotor centre: what the blades sweep when the rotor turns."""

    def __init__(self, turbine: TurbineMesh) -> None:
        v = np.concatenate([turbine.blade_vertices, turbine.cap_vertices]).reshape(-1, 3) - turbine.rotor_center
        a = v @ turbine.rotor_axis
        self.center = turbine.rotor_center
        self.axis = turbine.rotor_axis
        self.half_thickness = float(np.abs(a).max())
        self.tip_radius = float(np.linalg.norm(v - np.outer(a, self.axis), axis=1).max())

    def hold_point(self, q: np.ndarray, clearance: float, standoff: float) -> np.ndarray:
        rel = q - self.center
        a = float(rel @ self.axis)
        radial = float(np.linalg.norm(rel - a * self.axis))
        if abs(a) >= self.half_thickness + clearance or radial >= self.tip_radius + clearance:
            return q.copy()
        return q + (self.half_thickness + standoff - a) * self.axis


def _default_start(turbine: TurbineMesh, rotor: _RotorGeometry, standoff: float) -> np.ndarray:
    axis_h = turbine.rotor_axis.copy()
    axis_h[2] = 0.0
    axis_h = axis_h / np.linalg.norm(axis_h) if np.linalg.norm(axis_h) > 1e-6 else turbine.rotor_axis
    start = turbine.rotor_center + (rotor.half_thickness + standoff) * axis_h
    start[2] = float(turbine.all_triangles[..., 2].min())
    return start


# --------------------------------------------------------------------------- planner
@dataclass
class _Chain:
    """The optimal tour chained over phases (see the module docstring)."""

    cost: float
    tours: list[TourSolution]
    holds: list[np.ndarray]


class _FromAnyEntry:
    """One phase's tours from an arbitrary start: ``T[w, v]``, the cheapest way to enter first at
    node ``w`` and finish at exit node ``v`` (the start leg excluded), one Held-Karp table per
    entry node. The best tour from a point ``p`` is then ``min_w |p - node_w| + T[w, v]``, so a
    phase is tabled once however many hold points it may start from."""

    def __init__(self, ends: np.ndarray, forbidden: np.ndarray) -> None:
        self.nodes = ends.reshape(-1, 3)
        m = len(self.nodes)
        self.tables = []
        for w in range(m):
            one_hot = np.full(m, np.inf)
            one_hot[w] = 0.0
            self.tables.append(HeldKarp(ends, None, forbidden, start_cost=one_hot))
        self.T = np.stack([t.end_costs for t in self.tables]) if m else np.zeros((0, 0))

    def costs_from(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(2n,)`` best cost to finish at each exit node starting from ``p``, and the entry used."""
        tot = np.linalg.norm(self.nodes - p, axis=1)[:, None] + self.T
        w = np.argmin(tot, axis=0)
        return tot[w, np.arange(tot.shape[1])], w

    def tour(self, p: np.ndarray, exit_node: int) -> TourSolution:
        cost, w = self.costs_from(p)
        sol = self.tables[int(w[exit_node])].tour(exit_node)
        return TourSolution(stops=sol.stops, cost=float(cost[exit_node]))


def _chain(E: list[np.ndarray], F: list[np.ndarray], hk1: HeldKarp, rotor: "_RotorGeometry",
           cfg: PlannerConfig, keys: list[Any] | None = None,
           cache: dict[Any, _FromAnyEntry] | None = None) -> _Chain | None:
    """Exact multi-phase ordering: DP over phases; phase k starts at the hold point of the exit
    node of phase k-1 it follows (all exit nodes tried). ``keys[k]`` names phase k's instance so
    that its table is reused from ``cache`` across the candidate rotor positions."""
    costs = hk1.end_costs
    layers: list[tuple[_FromAnyEntry, np.ndarray, np.ndarray]] = []
    for k in range(1, len(E)):
        prev_nodes = E[k - 1].reshape(-1, 3)
        if cache is not None and keys is not None:
            if keys[k] not in cache:
                cache[keys[k]] = _FromAnyEntry(E[k], F[k])
            table = cache[keys[k]]
        else:
            table = _FromAnyEntry(E[k], F[k])
        holds = np.array([rotor.hold_point(q, cfg.clearance, cfg.standoff) for q in prev_nodes])
        retreat = np.linalg.norm(holds - prev_nodes, axis=1)
        new = np.full(2 * len(E[k]), np.inf)
        parent = np.full(2 * len(E[k]), -1, dtype=np.int64)
        for u in np.argsort(costs, kind="stable"):
            if not np.isfinite(costs[u]):
                break
            tot = costs[u] + retreat[u] + table.costs_from(holds[u])[0]
            better = tot < new
            new[better] = tot[better]
            parent[better] = u
        layers.append((table, parent, holds))
        costs = new
    v = int(np.argmin(costs))
    if not np.isfinite(costs[v]):
        return None
    total = float(costs[v])
    tours: list[TourSolution] = []
    hold_list: list[np.ndarray] = []
    for table, parent, holds in reversed(layers):
        u = int(parent[v])
        tours.append(table.tour(holds[u], v))
        hold_list.append(holds[u])
        v = u
    tours.append(hk1.tour(v))
    return _Chain(total, tours[::-1], hold_list[::-1])


def plan_inspection(turbine: TurbineMesh, config: PlannerConfig | None = None, **options: Any) -> InspectionPlan:
    """Plan the inspection of ``turbine`` (rotor positions, order, path); ``options`` override
    ``config`` fields."""
    if not isinstance(turbine, TurbineMesh):
        raise ValueError(f"turbine must be a TurbineMesh, got {type(turbine).__name__}")
    if config is not None and not isinstance(config, PlannerConfig):
        raise ValueError(f"config must be a PlannerConfig, got {type(config).__name__}")
    cfg = PlannerConfig.from_options(options, base=config) if (options or config is None) else config
    d, mode = cfg.standoff, cfg.standoff_mode
    t0 = time.perf_counter()

    # 1. clustering -----------------------------------------------------------------------
    surfaces, ignored = cluster_surfaces(turbine, angle_deg=cfg.cluster_angle_deg)
    t1 = time.perf_counter()

    # 2. rotor positions: what is inspectable where -----------------------------------------
    rotor = _RotorGeometry(turbine)
    frame = detour_frame(turbine.rotor_axis)
    offsets = detour_offsets(d)
    positions: dict[float, _Position] = {}

    def position(turn: float) -> _Position:
        turn = _wrap_deg(turn) if turn != 0.0 else 0.0
        if turn not in positions:
            positions[turn] = _Position(turbine, surfaces, turn, cfg, frame, offsets,
                                        redescribe=cfg.rotor_turn_deg is not None)
        return positions[turn]

    here = position(0.0)
    all_ids = [sf.id for sf in surfaces]
    ids1 = here.inspectable(all_ids)
    waiting = [i for i in all_ids if i not in ids1]
    if not ids1:
        elev = [round(sf.elevation_deg, 1) for sf in surfaces]
        raise ValueError("no surface can be inspected before the rotor turn (normal elevations "
                         f"{elev} deg; standoff {d} m, clearance {cfg.clearance} m)")
    start = np.asarray(cfg.start, dtype=np.float64) if cfg.start is not None else _default_start(turbine, rotor, d)
    if not here.clr.is_clear(start[None]):
        raise ValueError(f"start {np.round(start, 3).tolist()} is closer than clearance "
                         f"{cfg.clearance} m (+ check_step/2) to the turbine")
    G1 = [here.check(i) for i in ids1]
    E1 = _standoff_ends(G1, d, mode)
    hk1 = HeldKarp(E1, start, _forbidden(G1))
    t_setup = time.perf_counter()

    tables: dict[Any, _FromAnyEntry] = {}

    def groups_for(turns: tuple[float, ...]) -> list[list[int]] | None:
        """Surfaces per phase when each is inspected at the first position allowing it; ``None``
        if some remain or a turn would inspect nothing."""
        left, groups = list(waiting), [ids1]
        for turn in turns:
            got = position(turn).inspectable(left)
            if not got:
                return None
            groups.append(got)
            left = [i for i in left if i not in got]
        return groups if not left else None

    def evaluate(turns: tuple[float, ...]) -> tuple[float, tuple[float, ...], list[list[int]], _Chain] | None:
        groups = groups_for(turns)
        if groups is None:
            return None
        geo = [[position(t).check(i) for i in g] for t, g in zip((0.0, *turns), groups)]
        E = [E1] + [_standoff_ends(g, d, mode) for g in geo[1:]]
        F = [np.zeros((0, 0))] + [_forbidden(g) for g in geo[1:]]
        keys = [None] + [(t, tuple(g)) for t, g in zip(turns, groups[1:])]
        chain = _chain(E, F, hk1, rotor, cfg, keys, tables)
        return None if chain is None else (chain.cost, turns, groups, chain)

    def key(r: tuple) -> tuple:
        return (round(r[0], 6), len(r[1]), sum(abs(t) for t in r[1]), [-t for t in r[1]])

    if cfg.rotor_turn_deg is not None:
        turn = _wrap_deg(cfg.rotor_turn_deg) if cfg.rotor_turn_deg != 0.0 else 0.0
        if waiting:
            there = position(turn)
            for i in waiting:
                why = there.check(i)
                if isinstance(why, str):
                    before = "" if why == here.check(i) else f" ({here.check(i)})"
                    raise ValueError(f"surface {i} cannot be inspected before the rotor turn{before} "
                                     f"nor after rotor_turn_deg {cfg.rotor_turn_deg!r}: {why}; rotor_turn_deg=None "
                                     "lets the planner choose the rotor positions")
        best = evaluate((turn,) if waiting else ())
    else:
        grid = [_wrap_deg(k * cfg.rotor_turn_step_deg) for k in range(1, math.ceil(360.0 / cfg.rotor_turn_step_deg))]
        grid = sorted({t for t in grid if t != 0.0})
        best = evaluate(()) if not waiting else None
        if waiting:
            results = [r for t in grid if (r := evaluate((t,))) is not None]
            if not results:
                useful = [t for t in grid if position(t).inspectable(waiting)]
                results = [r for a in useful for b in useful if a != b and (r := evaluate((a, b))) is not None]
            if not results:
                never = [i for i in waiting if not any(position(t).inspectable([i]) for t in grid)]
                if never:
                    raise ValueError(f"surface {never[0]} cannot be inspected at any rotor position (as found: "
                                     f"{here.check(never[0])}; turns tried every {cfg.rotor_turn_step_deg:g} deg)")
                raise ValueError(f"surfaces {waiting} need more than two rotor turns (turns tried every "
                                 f"{cfg.rotor_turn_step_deg:g} deg)")
            best = min(results, key=key)
    if best is None:
        raise ValueError("no feasible tour: every order needs a direct move between opposite faces")
    move_cost, turns, groups, chain = best
    turn_list = (0.0, *turns)
    geo: dict[int, Surface] = {}
    stops: list[tuple[int, int, int]] = []
    for ph, (t, g, sol) in enumerate(zip(turn_list, groups, chain.tours), start=1):
        for i in g:
            geo[i] = position(t).check(i)
        stops += [(g[k], e, ph) for k, e in sol.stops]
    tour_length = move_cost + sum(geo[i].length for i in geo)
    t2 = time.perf_counter()

    # 3. path -----------------------------------------------------------------------------
    pieces: list[Piece] = []
    pos = start
    prev: tuple[Surface, int, int] | None = None      # (surface geometry, exit end, phase)
    prev_n = geo[stops[0][0]].end_normals[stops[0][1]]
    cur_phase = 1
    for sid, entry, ph in stops:
        g = geo[sid]
        clr = position(turn_list[ph - 1]).clr
        if ph != cur_phase:
            hold = chain.holds[ph - 2]
            route = position(turn_list[cur_phase - 1]).clr.route(pos, hold)   # retreat before the turn
            pieces.append(transit_piece(route, prev_n, prev_n, cur_phase, d, mode, cfg.check_step))
            pos, prev, cur_phase = hold, None, ph
        a, b = g.ends[entry], g.ends[1 - entry]
        na, nb = g.end_normals[entry], g.end_normals[1 - entry]
        qa = a + d * offset_direction(na, mode)
        piece = None
        if prev is not None and prev[0].blade == g.blade and prev[1] == entry \
                and abs(float(prev[0].normal @ g.normal)) < ADJACENT_COS:
            pa, npa = prev[0].ends[prev[1]], prev[0].end_normals[prev[1]]
            corner = wrap_corner(pa, npa, a, na)
            if corner is not None and np.linalg.norm(corner - pa) <= prev[0].width \
                    and np.linalg.norm(a - corner) <= g.width:
                piece = wrap_piece(pa, npa, a, na, corner, ph, d, mode, cfg.check_step)
                if not clr.is_clear(piece.q):
                    piece = None
        if piece is None:
            piece = transit_piece(clr.route(pos, qa), prev_n, na, ph, d, mode, cfg.check_step)
        pieces.append(piece)
        nodes, nn = (g.nodes, g.node_normals) if entry == 0 else (g.nodes[::-1], g.node_normals[::-1])
        pieces.append(surface_piece(sid, nodes, nn, ph, d, mode))
        pos = b + d * offset_direction(nb, mode)
        prev, prev_n = (g, 1 - entry, ph), nb
    sp = resample(pieces, cfg.spacing, d, mode)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sp.points, axis=0), axis=1))]
    s_q = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sp.standoff_points, axis=0), axis=1))]
    t3 = time.perf_counter()

    surface_phase = np.ones(len(surfaces), dtype=np.int64)
    for ph, g in enumerate(groups, start=1):
        surface_phase[g] = ph
    rotor_positions = tuple(RotorPosition(ph, float(t), tuple(sid for sid, _, p in stops if p == ph))
                            for ph, t in enumerate(turn_list, start=1))
    return InspectionPlan(
        points=sp.points, normals=sp.normals, surface=sp.surface, phase=sp.phase, s=s,
        standoff_points=sp.standoff_points, standoff_s=s_q, kind=sp.kind,
        tour=tuple(TourStop(sid, ph, "root" if e == 0 else "tip") for sid, e, ph in stops),
        tour_length=float(tour_length), surfaces=tuple(geo[sf.id] if surface_phase[sf.id] == 1 else sf
                                                       for sf in surfaces),
        surfaces_phase2={i: geo[i] for i in geo if surface_phase[i] > 1},
        surface_phase=surface_phase, turbines=tuple(position(t).turbine for t in turn_list),
        rotor_positions=rotor_positions, standoff=d, config=cfg, start=start,
        hold_points=tuple(chain.holds), ignored_triangles=ignored,
        # "order" includes checking the candidate rotor positions (done on demand during the search)
        timings={"cluster": t1 - t0, "setup": t_setup - t1, "order": t2 - t_setup, "path": t3 - t2,
                 "total": t3 - t0})
