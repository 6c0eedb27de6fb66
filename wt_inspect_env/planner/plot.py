"""Figure of a plan: one 3-D view per phase (rotor position), surfaces coloured by id, the drone's stand-off path.

Uses matplotlib's Agg canvas directly (no pyplot, no global backend switch), so it works headless
and does not interfere with other figures of the calling process.

Readability: the faces of one blade lie a few metres apart, so labels placed at each face's
centre pile up in any 3-D view. Each surface is therefore labelled with its visit number, placed
at a span fraction of its own (faces of one blade get different fractions) on the stand-off side,
and one legend below the panels says which colour and number is which surface, where it is
entered and what the markers and black lines are.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from ..util.figure_io import DEFAULT_FIGURE_FORMAT, save_figure
from .plan import InspectionPlan


def _surface_colors(n: int) -> np.ndarray:
    from matplotlib import colormaps
    cmap = colormaps["tab20"] if n > 10 else colormaps["tab10"]
    return np.array([cmap(i % cmap.N) for i in range(n)])


def plan_figure(plan: InspectionPlan) -> Figure:
    """Build the figure (one panel per rotor position)."""
    phases = list(range(1, plan.n_phases + 1))
    fig = Figure(figsize=(6.5 * len(phases), 9.5))
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
            ax.scatter(*plan.start, color="green", s=40)
        if ph <= len(plan.hold_points):
            ax.scatter(*plan.hold_points[ph - 1], color="red", s=40)
        for pos, sid_, visit in _label_positions(plan, ph):
            ax.text(*pos, str(visit), fontsize=7, color="black", ha="center", va="center", zorder=10,
                    bbox=dict(boxstyle="round,pad=0.15", facecolor=colors[sid_], edgecolor="black",
                              linewidth=0.4, alpha=0.9))
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
    handles, labels = _legend_entries(plan, colors)
    ncol = min(4, len(handles))
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=8, frameon=True,
               title="numbers in the panels: visit order; line width: inspection (thick) or transition (thin)",
               title_fontsize=8)
    fig.suptitle(f"Inspection plan: {plan.n_surfaces} surfaces, tour {plan.tour_length:.1f} m "
                 f"(stand-off path {plan.path_length:.1f} m, d_ref {plan.standoff:g} m)")
    rows = -(-len(handles) // ncol)
    fig.tight_layout(rect=(0.0, min(0.45, 0.05 + 0.03 * rows), 1.0, 0.97))
    return fig


def _label_positions(plan: InspectionPlan, phase: int) -> list[tuple[np.ndarray, int, int]]:
    """``(position, surface id, visit number)`` of the label of every surface inspected in ``phase``.

    The k-th of the n surfaces of a blade inspected in this phase (in tour order) is labelled at
    span fraction ``0.15 + 0.7 k / (n - 1)`` of its centre line, on its stand-off path, so faces
    of one blade - a few metres apart - never share a label spot."""
    stops = [(i + 1, t) for i, t in enumerate(plan.tour) if t.phase == phase]
    by_blade: dict[int, list[int]] = {}
    for _, t in stops:
        by_blade.setdefault(int(plan.surface_geometry(t.surface).blade), []).append(t.surface)
    out = []
    for visit, t in stops:
        g = plan.surface_geometry(t.surface)
        same = by_blade[int(g.blade)]
        frac = 0.5 if len(same) == 1 else 0.15 + 0.7 * same.index(t.surface) / (len(same) - 1)
        nodes = g.nodes
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(nodes, axis=0), axis=1))])
        at = frac * cum[-1]
        k = int(min(np.searchsorted(cum, at, side="right") - 1, len(nodes) - 2))
        w = (at - cum[k]) / max(cum[k + 1] - cum[k], 1e-12)
        point = (1 - w) * nodes[k] + w * nodes[k + 1]
        out.append((point + plan.standoff * np.asarray(g.normal), t.surface, visit))
    return out


def _legend_entries(plan: InspectionPlan, colors: np.ndarray) -> tuple[list, list[str]]:
    """One legend entry per surface (colour, id, visit number, blade, end it is entered at), then
    the transitions and the markers."""
    handles: list = []
    labels: list[str] = []
    for i, t in enumerate(plan.tour):
        g = plan.surface_geometry(t.surface)
        handles.append(Line2D([], [], color=colors[t.surface], lw=4))
        labels.append(f"{i + 1}: surface {t.surface} (blade {int(g.blade)}, phase {t.phase}, from the {t.entry})")
    handles += [Line2D([], [], color=(0.1, 0.1, 0.1, 0.8), lw=1.0),
                Line2D([], [], color="green", marker="o", ls="none", ms=6),
                Line2D([], [], color="red", marker="o", ls="none", ms=6)]
    labels += ["transition between surfaces", "take-off", "hold while the rotor turns"]
    return handles, labels


def save_plan_figure(plan: InspectionPlan, path: str | Path, fmt: str = DEFAULT_FIGURE_FORMAT) -> Path:
    """Render the plan to ``path`` with the suffix of ``fmt`` (png, pdf or svg), atomically; returns
    the written path."""
    return save_figure(plan_figure(plan), path, fmt)
