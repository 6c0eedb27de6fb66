"""Figure of a plan: one 3-D view per phase (rotor position), surfaces coloured by id, the drone's stand-off path.

Uses matplotlib's Agg canvas directly (no pyplot, no global backend switch), so it works headless
and does not interfere with other figures of the calling process.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from ..atomic_io import atomic_path
from .plan import InspectionPlan


def _surface_colors(n: int) -> np.ndarray:
    from matplotlib import colormaps
    cmap = colormaps["tab20"] if n > 10 else colormaps["tab10"]
    return np.array([cmap(i % cmap.N) for i in range(n)])


def plan_figure(plan: InspectionPlan) -> Figure:
    """Build the figure (one panel per rotor position)."""
    phases = list(range(1, plan.n_phases + 1))
    fig = Figure(figsize=(6.5 * len(phases), 8.0), dpi=110)
    FigureCanvasAgg(fig)
    colors = _surface_colors(plan.n_surfaces)
    for col, ph in enumerate(phases):
        ax = fig.add_subplot(1, len(phases), col + 1, projection="3d")
        turb = plan.turbine(ph)
        tri_color = np.tile([0.75, 0.75, 0.75, 0.35], (turb.n_blade_triangles, 1))
        for sid in range(plan.n_surfaces):
            geo = plan.surface_geometry(sid) if plan.surface_phase[sid] == ph else plan.surfaces[sid]
            c = colors[sid].copy()
            c[3] = 0.9 if plan.surface_phase[sid] == ph else 0.25
            tri_color[geo.triangles] = c
        ax.add_collection3d(Poly3DCollection(turb.blade_vertices, facecolors=tri_color, edgecolors="none"))
        if len(turb.cap_vertices):
            ax.add_collection3d(Poly3DCollection(turb.cap_vertices, facecolors=(0.6, 0.6, 0.6, 0.4)))
        obs = np.asarray(turb.obstacle_mesh.triangles)
        if len(obs):
            ax.add_collection3d(Poly3DCollection(obs, facecolors=(0.55, 0.55, 0.6, 0.15), edgecolors="none"))
        sel = np.flatnonzero(plan.phase == ph)
        q = plan.standoff_points[sel]
        segs = np.stack([q[:-1], q[1:]], axis=1)
        sid = plan.surface[sel][1:]
        seg_col = np.where(sid[:, None] >= 0, colors[np.maximum(sid, 0)], [[0.1, 0.1, 0.1, 0.8]])
        widths = np.where(sid >= 0, 2.2, 1.0)
        ax.add_collection3d(Line3DCollection(segs, colors=seg_col, linewidths=widths))
        if ph == 1:
            ax.scatter(*plan.start, color="green", s=40, label="take-off")
        if ph <= len(plan.hold_points):
            ax.scatter(*plan.hold_points[ph - 1], color="red", s=40, label="hold for rotor turn")
        for stop in plan.tour:
            if stop.phase != ph:
                continue
            g = plan.surface_geometry(stop.surface)
            mid = 0.5 * (g.root + g.tip) + 2.0 * g.normal
            ax.text(*mid, str(stop.surface), fontsize=8, color="black")
        # true scale: limits from the data, box aspect from their ranges
        pts = np.concatenate([turb.all_triangles.reshape(-1, 3), plan.standoff_points, plan.start[None]])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        pad = 0.03 * float((hi - lo).max())
        lo, hi = lo - pad, hi + pad
        lo[2] = max(lo[2], 0.0)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(tuple(hi - lo))
        for axis, rng in zip((ax.xaxis, ax.yaxis, ax.zaxis), hi - lo):
            axis.set_major_locator(MaxNLocator(max(2, int(8 * rng / (hi - lo).max()))))
        # look at the rotor's front, from the right and a little above
        f = plan.turbine_phase1.rotor_axis
        ax.view_init(elev=15, azim=float(np.degrees(np.arctan2(f[1], f[0]))) - 35.0)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        n_ph = int(np.sum(plan.surface_phase == ph))
        title = f"phase {ph}: {n_ph} surfaces"
        if ph > 1:
            title += f" (rotor turned {plan.rotor_positions[ph - 1].turn_deg:g} deg)"
        ax.set_title(title)
        if ax.get_legend_handles_labels()[0]:      # the last phase has neither take-off nor hold point
            ax.legend(loc="upper left", fontsize=8)
    fig.suptitle(f"Inspection plan: {plan.n_surfaces} surfaces, tour {plan.tour_length:.1f} m "
                 f"(stand-off path {plan.path_length:.1f} m, d_ref {plan.standoff:g} m); "
                 "coloured: inspection, black: transitions")
    fig.tight_layout()
    return fig


def save_plan_figure(plan: InspectionPlan, path: str | Path) -> Path:
    """Render the plan to a PNG file (atomically)."""
    fig = plan_figure(plan)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return Path(path)
