"""The inspection plan: clustering -> two-phase exact ordering -> collision-free path.

Phases (the paper's section "Automated Inspection Framework"): surfaces a level camera can
inspect with the rotor as it is (normal elevation within ``[-max_down_deg, max_up_deg]`` and the
stand-off along the whole centre line at least ``clearance`` from the turbine) form phase 1; the
others (on the inverted Y, the two faces looking 60 deg down, whose stand-offs would also lie
inside the other lower blade) are deferred. A deferred surface that is still not inspectable after
the turn is an error (e.g. the upright Y at azimuth 60 deg needs two turns). After
phase 1 the drone waits at a *hold point* outside the volume swept by the blades (its last
stand-off if that is already outside, else that stand-off moved along the rotor axis to the front
faces' stand-off plane), the rotor turns by ``rotor_turn_deg`` and phase 2 inspects the deferred
surfaces on the turned rotor (points of phase 2 are in world coordinates on the rotated blades).

"Stand-off clear" allows trimming: where only the ends of a surface's stand-off line come too
close to the turbine (the root of a back face passing behind a large hub), the centre line's end
nodes move inwards to where it clears, by at most ``max_end_trim`` (default a quarter of the stand-off); ``Surface.trim`` and the
summary's ``trimmed_m`` say by how much.

Ordering is exact for the whole two-phase problem: for every way phase 1 can finish (each exit
node of the full Held-Karp table) the retreat to its hold point and the optimal phase-2 tour from
there are added, and the cheapest total is kept. Costs are straight-line distances between
stand-off positions, as in the paper; ``tour_length`` is that objective plus the surface lengths
(the distance flown along stand-offs if every move were straight), ``path_length`` is the length
of the actual stand-off path (wraps swing round blade edges, transits may detour).

Labels of path samples: ``surface`` is the surface id while a surface's centre line is inspected
and ``-1`` on every transition (take-off climb, wraps round blade edges, transits, the retreat
before the turn); ``phase`` is the rotor configuration the sample belongs to: 1 up to and including
the hold point, 2 after the turn (a transition therefore carries the phase of the surface it
approaches, except the retreat, which happens before the turn).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic_io import atomic_path
from ..turbine import TurbineMesh
from .clearance import Clearance, DistanceField
from .clustering import Surface, cluster_surfaces, describe_surface
from .config import PlannerConfig
from .ordering import HeldKarp, TourSolution, solve_tour
from .path import Piece, offset_direction, resample, surface_piece, transit_piece, wrap_corner, wrap_piece

CSV_HEADER = "x,y,z,nx,ny,nz,surface,phase,s"
OPPOSITE_COS = math.cos(math.radians(150.0))   # normals further apart than 150 deg: opposite faces
ADJACENT_COS = 0.5                              # |n_a . n_b| below this: faces meeting at an edge
KIND_NAMES = ("surface", "wrap", "transit")


@dataclass(frozen=True)
class TourStop:
    """One surface of the tour: its id, the phase it is inspected in and the end it is entered at."""

    surface: int
    phase: int
    entry: str        # "root" or "tip"


@dataclass(eq=False)
class InspectionPlan:
    """Result of :func:`plan_inspection` (arrays have one row per path sample)."""

    points: np.ndarray            # (K, 3) inspection points
    normals: np.ndarray           # (K, 3) outward unit normals
    surface: np.ndarray           # (K,) surface id, -1 on transitions
    phase: np.ndarray             # (K,) 1 or 2
    s: np.ndarray                 # (K,) arc length of the inspection point (non-decreasing)
    standoff_points: np.ndarray   # (K, 3) drone stand-off positions
    standoff_s: np.ndarray        # (K,) arc length of the stand-off path (increasing)
    kind: np.ndarray              # (K,) 0 surface, 1 wrap round a blade edge, 2 transit
    tour: tuple[TourStop, ...]
    tour_length: float
    surfaces: tuple[Surface, ...]             # geometry in phase 1 (ids index this tuple)
    surfaces_phase2: dict[int, Surface]       # geometry of the deferred surfaces on the turned rotor
    surface_phase: np.ndarray                 # (n_surfaces,) phase each surface is inspected in
    turbine_phase1: TurbineMesh
    turbine_phase2: TurbineMesh               # the rotor turned by config.rotor_turn_deg
    standoff: float
    config: PlannerConfig
    start: np.ndarray
    hold_point: np.ndarray | None             # where the drone waits for the rotor turn
    ignored_triangles: np.ndarray             # blade triangles in no surface (e.g. caps of a file)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_surfaces(self) -> int:
        return len(self.surfaces)

    @property
    def path_length(self) -> float:
        """Length of the stand-off (drone) path."""
        return float(self.standoff_s[-1])

    def surface_geometry(self, surface_id: int) -> Surface:
        """Geometry of a surface in the rotor configuration it is inspected in."""
        return self.surfaces_phase2.get(surface_id, self.surfaces[surface_id])

    def turbine(self, phase: int) -> TurbineMesh:
        return self.turbine_phase1 if phase == 1 else self.turbine_phase2

    def min_clearance(self, cap: float | None = None) -> float:
        """Exact smallest distance from the path's stand-off positions to the turbine of their
        phase (capped at ``cap``, default the stand-off distance)."""
        cap = self.standoff if cap is None else cap
        best = cap
        for ph in (1, 2):
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
            "rotor_turn_deg": self.config.rotor_turn_deg,
            "trimmed_m": {i: [round(float(t), 4) for t in self.surface_geometry(i).trim]
                          for i in range(self.n_surfaces) if any(self.surface_geometry(i).trim)},
            "plan_time_s": round(self.timings.get("total", float("nan")), 6),
            "timings_s": {k: round(v, 6) for k, v in self.timings.items()},
        }


# --------------------------------------------------------------------------- helpers
def _frame(axis: np.ndarray) -> np.ndarray:
    """Rows: rotor axis, vertical, lateral (axis x up): the directions detours are tried along."""
    up = np.array([0.0, 0.0, 1.0])
    lat = np.cross(axis, up)
    if np.linalg.norm(lat) < 1e-6:
        lat = np.cross(axis, [1.0, 0.0, 0.0])
    return np.stack([axis, up, lat / np.linalg.norm(lat)])


def _forbidden(geo: list[Surface]) -> np.ndarray:
    """Opposite faces of one blade: a straight move between them would pass through the blade."""
    n = np.array([g.normal for g in geo]).reshape(-1, 3)
    blade = np.array([g.blade for g in geo])
    return (n @ n.T < OPPOSITE_COS) & (blade[:, None] == blade[None, :])


def _standoff_ends(geo: list[Surface], d: float, mode: str) -> np.ndarray:
    if not geo:
        return np.zeros((0, 2, 3))
    return np.stack([g.ends + d * offset_direction(g.normal, mode) for g in geo])


def _inspectable(clr: Clearance, g: Surface, d: float, mode: str, max_trim: float) -> Surface | str:
    """``g`` (with its ends trimmed inwards if needed) if its stand-off line is clear, else why not.

    The stand-off of a surface is the centre line shifted by a constant vector, so clear points of
    the stand-off line map one-to-one to points of the centre line. The line is sampled finely
    (``h`` at most a quarter of the check step); the clear part must be one run that reaches to
    within ``max_trim`` of both ends. Samples must clear ``clearance + check_step/2 + h``, so the
    resampled path on the trimmed line passes :meth:`Clearance.polyline_clear` as well.
    """
    e = _standoff_ends([g], d, mode)[0]
    if clr.polyline_clear(e):
        return g
    length = float(np.linalg.norm(e[1] - e[0]))
    h = min(clr.step / 4.0, max(length, 1e-9) / 8.0)
    n = max(2, math.ceil(length / h) + 1)
    tau = np.linspace(0.0, 1.0, n)
    pts = e[0] + tau[:, None] * (e[1] - e[0])
    dist = clr.field.distance(pts, clr.required + h + 1e-6)
    ok = dist >= clr.required + h
    dmin = float(clr.field.distance(pts, d).min())
    blocked = (f"standoff {d!r} m puts the drone {dmin:.2f} m from the turbine (clearance "
               f"{clr.clearance} m + check_step/2 required)")
    if not ok.any():
        return blocked
    i0, i1 = int(np.argmax(ok)), int(n - 1 - np.argmax(ok[::-1]))
    trim = (tau[i0] * length, (1.0 - tau[i1]) * length)
    if not ok[i0:i1 + 1].all() or max(trim) > max_trim:
        return (f"{blocked}; its clear part would need {trim[0]:.2f} m (root) and {trim[1]:.2f} m (tip) "
                f"trimmed from the ends, more than max_end_trim {max_trim!r} m" if ok[i0:i1 + 1].all()
                else f"{blocked} away from the ends of its centre line")
    root, tip = g.root + tau[i0] * (g.tip - g.root), g.root + tau[i1] * (g.tip - g.root)
    return dataclasses.replace(g, root=root, tip=tip,
                               trim=(float(g.trim[0] + trim[0]), float(g.trim[1] + trim[1])))


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
def plan_inspection(turbine: TurbineMesh, config: PlannerConfig | None = None, **options: Any) -> InspectionPlan:
    """Plan the two-phase inspection of ``turbine``; ``options`` override ``config`` fields."""
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

    # 2. phases, stand-offs, clearance ----------------------------------------------------
    elev = np.array([s.elevation_deg for s in surfaces])
    in_band = (elev >= -cfg.max_down_deg) & (elev <= cfg.max_up_deg)
    rotor = _RotorGeometry(turbine)
    frame = _frame(turbine.rotor_axis)
    offsets = tuple(d * f for f in (0.5, 1.0, 2.0, 4.0))
    clr1 = Clearance(DistanceField(turbine.all_triangles), cfg.clearance, cfg.check_step, frame, offsets)
    # phase 1: normal within the level camera's band and the stand-off clear of the turbine
    why1: dict[int, str] = {}
    geo1: dict[int, Surface] = {}
    for sf in surfaces:
        r = _inspectable(clr1, sf, d, mode, cfg.end_trim_limit) if in_band[sf.id] else \
            f"normal elevation {elev[sf.id]:.1f} deg"
        if isinstance(r, str):
            why1[sf.id] = r
        else:
            geo1[sf.id] = r
    ids1 = sorted(geo1)
    ids2 = [s.id for s in surfaces if s.id not in geo1]
    if not ids1:
        raise ValueError("no surface can be inspected before the rotor turn (normal elevations "
                         f"{np.round(elev, 1).tolist()} deg; standoff {d} m, clearance {cfg.clearance} m)")
    turbine2 = turbine.rotated(cfg.rotor_turn_deg)
    clr2 = Clearance(DistanceField(turbine2.all_triangles), cfg.clearance, cfg.check_step, frame, offsets) \
        if ids2 else None
    geo2: dict[int, Surface] = {}
    for i in ids2:
        g = describe_surface(turbine2, surfaces[i].triangles, i, surfaces[i].blade)
        if not -cfg.max_down_deg <= g.elevation_deg <= cfg.max_up_deg:
            r: Surface | str = (f"its normal elevation is {g.elevation_deg:.1f} deg after the turn, outside "
                                f"[-max_down_deg, max_up_deg] = [-{cfg.max_down_deg}, {cfg.max_up_deg}]")
        else:
            r = _inspectable(clr2, g, d, mode, cfg.end_trim_limit)
        if isinstance(r, str):
            raise ValueError(f"surface {i} cannot be inspected before the rotor turn ({why1[i]}) nor after "
                             f"rotor_turn_deg {cfg.rotor_turn_deg!r}: {r}")
        geo2[i] = r
    G1 = [geo1[i] for i in ids1]
    G2 = [geo2[i] for i in ids2]
    F1, F2 = _forbidden(G1), _forbidden(G2)
    E1 = _standoff_ends(G1, d, mode)
    E2 = _standoff_ends(G2, d, mode)
    start = np.asarray(cfg.start, dtype=np.float64) if cfg.start is not None else _default_start(turbine, rotor, d)
    if not clr1.is_clear(start[None]):
        raise ValueError(f"start {np.round(start, 3).tolist()} is closer than clearance "
                         f"{cfg.clearance} m (+ check_step/2) to the turbine")
    t2 = time.perf_counter()

    # 3. exact ordering of both phases ----------------------------------------------------
    hk = HeldKarp(E1, start, F1)
    end_costs = hk.end_costs
    best: tuple[float, int, np.ndarray | None, TourSolution | None] | None = None
    for u in np.argsort(end_costs):
        if not np.isfinite(end_costs[u]):
            break
        if not ids2:
            best = (float(end_costs[u]), int(u), None, None)
            break
        q_u = E1.reshape(-1, 3)[u]
        hold = rotor.hold_point(q_u, cfg.clearance, d)
        sol2 = solve_tour(E2, hold, F2)
        if sol2 is None:
            continue
        total = float(end_costs[u]) + float(np.linalg.norm(hold - q_u)) + sol2.cost
        if best is None or total < best[0]:
            best = (total, int(u), hold, sol2)
    if best is None:
        raise ValueError("no feasible tour: every order needs a direct move between opposite faces")
    move_cost, u_best, hold, sol2 = best
    sol1 = hk.tour(u_best)
    lengths = sum(g.length for g in G1) + sum(g.length for g in G2)
    tour_length = move_cost + lengths
    stops = [(ids1[k], e, 1) for k, e in sol1.stops]
    if sol2 is not None:
        stops += [(ids2[k], e, 2) for k, e in sol2.stops]
    t3 = time.perf_counter()

    # 4. path -----------------------------------------------------------------------------
    pieces: list[Piece] = []
    pos = start
    prev: tuple[Surface, int, int] | None = None      # (surface geometry, exit end, phase)
    prev_n = geo1[stops[0][0]].normal if stops[0][2] == 1 else geo2[stops[0][0]].normal
    for sid, entry, ph in stops:
        g = geo1[sid] if ph == 1 else geo2[sid]
        clr = clr1 if ph == 1 else clr2
        if ph == 2 and prev is not None and prev[2] == 1:
            route = clr1.route(pos, hold)                   # retreat before the rotor turn
            pieces.append(transit_piece(route, prev_n, prev_n, 1, d, mode, cfg.check_step))
            pos, prev = hold, None
        a, b = g.ends[entry], g.ends[1 - entry]
        qa = a + d * offset_direction(g.normal, mode)
        piece = None
        if prev is not None and prev[0].blade == g.blade and prev[1] == entry \
                and abs(float(prev[0].normal @ g.normal)) < ADJACENT_COS:
            pa = prev[0].ends[prev[1]]
            corner = wrap_corner(pa, prev[0].normal, a, g.normal)
            if corner is not None and np.linalg.norm(corner - pa) <= prev[0].width \
                    and np.linalg.norm(a - corner) <= g.width:
                piece = wrap_piece(pa, prev[0].normal, a, g.normal, corner, ph, d, mode, cfg.check_step)
                if not clr.is_clear(piece.q):
                    piece = None
        if piece is None:
            piece = transit_piece(clr.route(pos, qa), prev_n, g.normal, ph, d, mode, cfg.check_step)
        pieces.append(piece)
        pieces.append(surface_piece(sid, a, b, g.normal, ph, d, mode))
        pos = b + d * offset_direction(g.normal, mode)
        prev, prev_n = (g, 1 - entry, ph), g.normal
    sp = resample(pieces, cfg.spacing, d, mode)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sp.points, axis=0), axis=1))]
    s_q = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(sp.standoff_points, axis=0), axis=1))]
    t4 = time.perf_counter()

    surface_phase = np.ones(len(surfaces), dtype=np.int64)
    surface_phase[ids2] = 2
    return InspectionPlan(
        points=sp.points, normals=sp.normals, surface=sp.surface, phase=sp.phase, s=s,
        standoff_points=sp.standoff_points, standoff_s=s_q, kind=sp.kind,
        tour=tuple(TourStop(sid, ph, "root" if e == 0 else "tip") for sid, e, ph in stops),
        tour_length=float(tour_length), surfaces=tuple(geo1.get(sf.id, sf) for sf in surfaces), surfaces_phase2=geo2,
        surface_phase=surface_phase, turbine_phase1=turbine, turbine_phase2=turbine2, standoff=d,
        config=cfg, start=start, hold_point=hold, ignored_triangles=ignored,
        timings={"cluster": t1 - t0, "setup": t2 - t1, "order": t3 - t2, "path": t4 - t3, "total": t4 - t0})
