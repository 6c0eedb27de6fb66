"""Missions: which part of the planned path an environment flies, and which triangles count.

* ``full``: the paper's mission. The planner's whole path from the first inspected surface on (the
  take-off climb from the ground is skipped: the drone starts hovering at the first stand-off
  pose), every phase (one per rotor position: two for the paper's turn, one to three when the
  planner chooses, ``rotor_turn_deg=None``), every blade triangle the planner assigned to a surface.
* ``blade``: the four long faces of one blade (``blade_index`` 0 = the highest blade, the upright
  one of the inverted Y, whose faces are all inspectable in phase 1). The planner's optimal tour
  interleaves blades, so this task is planned on its own: a turbine whose only inspected blade is
  the chosen one, the other blades turned into obstacles (so transitions still avoid them).
  Surfaces of the chosen blade that need the rotor turn are left out (documented in ``surfaces``).
* ``surface``: one surface's centre line, the ``surface_index``-th phase-1 surface of the full
  tour.

Coverage always counts triangles by their index in the full turbine's blade arrays
(``inspected``), so it is comparable across tasks and survives the rotor turn.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import trimesh

from ..planner import InspectionPlan, PlannerConfig, plan_inspection
from ..planner.clearance import DistanceField
from ..turbine.loading import load_turbine_mesh
from ..turbine.mesh import TurbineMesh, build_turbine
from ..util.validation import check_unknown_options
from .env_config import EnvConfig
from .reference import standoff_poses


@dataclass(frozen=True)
class Mission:
    """The path an environment follows and the geometry it is judged on."""

    task: str
    plan: InspectionPlan
    points: np.ndarray          # (K, 3) inspection points
    normals: np.ndarray         # (K, 3)
    s: np.ndarray               # (K,) arc length, starts at 0
    phase: np.ndarray           # (K,) 1 or 2
    surface: np.ndarray         # (K,) planner surface id (-1 on transitions)
    turbines: tuple[TurbineMesh, ...]   # full turbine in each phase the path visits (index 0 = phase 1)
    inspected: np.ndarray       # indices of the blade triangles that count for coverage
    surfaces: tuple[int, ...]   # planner surface ids inspected by this mission

    def working_volume(self, margin: float) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned box the drone must stay in: turbine and path bounds grown by ``margin``
        (the ground is a collision anyway)."""
        pts = [t.mesh.bounds for t in self.turbines] + [np.stack([self.points.min(0), self.points.max(0)])]
        lo = np.min([b[0] for b in pts], axis=0) - margin
        hi = np.max([b[1] for b in pts], axis=0) + margin
        lo[2] = -1.0
        return lo, hi

    def clearance_shortfall(self, standoff: float, d_min: float) -> np.ndarray:
        """Per path sample, how far inside ``d_min`` of its phase's turbine the ideal stand-off pose
        lies (0 where it clears d_min) [m]: the distance the clearance constraint keeps the drone
        from that pose, which the closed-loop reference allows for (see :mod:`.reference`)."""
        ideal = standoff_poses(self.points, self.normals, standoff)
        out = np.zeros(len(ideal))
        for ph in np.unique(self.phase):
            sel = self.phase == ph
            field = DistanceField(self.turbines[int(ph) - 1].all_triangles)
            out[sel] = d_min - field.distance(ideal[sel], d_min)
        return out


def _turbine(cfg: EnvConfig) -> TurbineMesh:
    if cfg.turbine_mesh is not None:
        return load_turbine_mesh(cfg.turbine_mesh)
    return build_turbine(cfg.turbine)


def _slice(plan: InspectionPlan, sel: np.ndarray) -> tuple[np.ndarray, ...]:
    s = plan.s[sel]
    return plan.points[sel], plan.normals[sel], s - s[0], plan.phase[sel], plan.surface[sel]


def single_blade_turbine(turb: TurbineMesh, blade: int) -> tuple[TurbineMesh, np.ndarray]:
    """A turbine whose only inspected blade is ``blade`` (the others become obstacles), and the
    indices of its blade triangles in ``turb``."""
    keep = np.flatnonzero(turb.triangle_blade == blade)
    others = np.flatnonzero(turb.triangle_blade != blade)
    other_tris = np.concatenate([turb.blade_vertices[others], turb.cap_vertices[turb.cap_blade != blade]])
    n = len(other_tris)
    other_mesh = trimesh.Trimesh(vertices=other_tris.reshape(-1, 3), faces=np.arange(3 * n).reshape(n, 3),
                                 process=False)
    obstacles = trimesh.util.concatenate([turb.obstacle_mesh, other_mesh])
    sub = TurbineMesh(
        blade_vertices=turb.blade_vertices[keep], triangle_blade=turb.triangle_blade[keep],
        triangle_face=turb.triangle_face[keep], triangle_surface=turb.triangle_surface[keep],
        cap_vertices=turb.cap_vertices[turb.cap_blade == blade],
        cap_blade=turb.cap_blade[turb.cap_blade == blade], obstacle_mesh=obstacles,
        rotor_center=turb.rotor_center, rotor_axis=turb.rotor_axis, spec=None)
    return sub, keep


def build_mission(cfg: EnvConfig) -> Mission:
    """Plan the turbine of ``cfg`` and cut out the task's part (see the module docstring)."""
    turb = _turbine(cfg)
    check_unknown_options("planner", cfg.planner.keys(), [f.name for f in dataclasses.fields(PlannerConfig)])
    pcfg = PlannerConfig(standoff=cfg.standoff, spacing=cfg.planner_spacing, rotor_turn_deg=cfg.rotor_turn_deg,
                         **cfg.planner)
    if cfg.task == "blade":
        return _blade_mission(cfg, turb, pcfg)
    plan = plan_inspection(turb, pcfg)
    phase1_stops = [t.surface for t in plan.tour if t.phase == 1]

    if cfg.task == "full":
        first = int(np.flatnonzero(plan.surface >= 0)[0])
        sel = np.arange(first, len(plan.s))
        surfaces = tuple(t.surface for t in plan.tour)
        inspected = np.setdiff1d(np.arange(turb.n_blade_triangles), plan.ignored_triangles)
        turbines = plan.turbines                 # one per rotor position the plan uses (phase k -> k-1)
        return Mission("full", plan, *_slice(plan, sel), turbines=turbines, inspected=inspected,
                       surfaces=surfaces)

    if cfg.task == "surface":
        if cfg.surface_index >= len(phase1_stops):
            raise ValueError(f"surface_index must be below the {len(phase1_stops)} phase-1 surfaces, "
                             f"got {cfg.surface_index}")
        sid = phase1_stops[cfg.surface_index]
        sel = np.flatnonzero(plan.surface == sid)
        return Mission("surface", plan, *_slice(plan, sel), turbines=(plan.turbine_phase1,),
                       inspected=np.sort(plan.surfaces[sid].triangles), surfaces=(sid,))



def _blade_mission(cfg: EnvConfig, turb: TurbineMesh, pcfg: PlannerConfig) -> Mission:
    """One blade planned on its own (blades ranked by the height of their centroid, 0 = highest)."""
    blades = np.unique(turb.triangle_blade)
    heights = [turb.blade_centroids[turb.triangle_blade == b, 2].mean() for b in blades]
    order = blades[np.argsort(heights)[::-1]]
    if cfg.blade_index >= len(order):
        raise ValueError(f"blade_index must be below the number of blades {len(order)}, got {cfg.blade_index}")
    blade = int(order[cfg.blade_index])
    sub, keep = single_blade_turbine(turb, blade)
    sub_plan = plan_inspection(sub, pcfg)
    sel = np.flatnonzero(sub_plan.phase == 1)
    sel = sel[sel >= int(np.flatnonzero(sub_plan.surface >= 0)[0])]
    last = int(np.flatnonzero((sub_plan.surface >= 0) & (sub_plan.phase == 1))[-1])
    sel = sel[sel <= last]
    p1_surfaces = [t.surface for t in sub_plan.tour if t.phase == 1]
    inspected = np.sort(np.concatenate([keep[sub_plan.surfaces[i].triangles] for i in p1_surfaces]))
    return Mission("blade", sub_plan, *_slice(sub_plan, sel), turbines=(turb,),
                   inspected=inspected, surfaces=tuple(p1_surfaces))
