"""Figures of an evaluation (matplotlib, Agg backend; written atomically as PNG, or PDF / SVG with
``figure_format``: the names below then end in ``.pdf`` / ``.svg``).

Per wind speed, from the first seed of every controller (the paper shows its 4 m/s runs):

* ``trajectories_w{W}.png`` - 3-D drone trajectories around the turbine, one panel per mission
  phase (phase 2 is flown around the turned rotor), the stand-off reference dashed;
* ``distance_w{W}.png`` - top: horizontal distance to the inspection point over time with d_ref
  and the SM band (d_ref +- margin); bottom: clearance of the drone's centre to the turbine mesh
  with d_min (the two distances are different things: a drone can hold 7 m to the point and pass
  2 m from a blade edge);
* ``centering_w{W}.png`` - the heading function h over time (CM is its mean, in the legend);
* ``coverage_w{W}.png`` - per-triangle coverage map: the blade faces unfolded into flat strips
  (root left, tip right), every triangle coloured by the number of camera frames that saw it,
  never-seen mission triangles red, blade triangles outside the mission grey;
* ``energy_w{W}.png`` - electrical power of the rotors over time (the harness's energy model)
  and the energy used so far minus hovering for as long, with each run's energy and path length
  in the legend.

Runs recorded before the clearance and energy arrays existed are left out of those panels.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from wt_inspect_env.util.figure_io import DEFAULT_FIGURE_FORMAT, check_figure_format, save_and_close  # noqa: E402

from .registry import display_name  # noqa: E402
from .report import order_controllers  # noqa: E402
from .runner import RunResult  # noqa: E402

MAX_LINE_POINTS = 6000   # per curve: 110k samples draw no better than 6k and cost 20x the time
COLORS = {"nmpc": "tab:orange", "pampc": "tab:green", "vtnmpc": "tab:blue", "vtnmpc-dob": "tab:purple",
          "vtnmpc-plus": "tab:red",
          "vtnmpc-later": "tab:cyan"}


def _color(name: str, i: int) -> str:
    return COLORS.get(name, f"C{(i + 4) % 10}")


def _thin(n: int) -> np.ndarray:
    return np.arange(0, n, max(1, n // MAX_LINE_POINTS))


def _save(fig: plt.Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` (its suffix is the format) and free it."""
    return save_and_close(fig, path, path.suffix.lstrip("."), bbox_inches="tight")


def _equal_axes(ax, pts: np.ndarray) -> None:
    lo, hi = pts.min(0), pts.max(0)
    pad = np.maximum(0.02 * max(float(np.max(hi - lo)), 1e-6) - (hi - lo) / 2, 0.0)   # flat sets get a slab
    lo, hi = lo - pad, hi + pad
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)


def trajectories(runs: Sequence[RunResult], path: Path, title: str) -> Path:
    """3-D view of the runs' flown paths around the blades, one panel per phase; saved to ``path``."""
    tri = runs[0].arrays["blade_triangles"]
    n_phase = len(tri)
    fig = plt.figure(figsize=(6.5 * n_phase, 6.5))
    for ph in range(n_phase):
        ax = fig.add_subplot(1, n_phase, ph + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri[ph], facecolor="0.75", edgecolor="0.6", linewidth=0.1, alpha=0.35))
        pts = [tri[ph].reshape(-1, 3)]
        for i, r in enumerate(runs):
            a = r.arrays
            sel = np.flatnonzero(a["phase"] == ph + 1)
            if not len(sel):
                continue
            sel = sel[_thin(len(sel))]
            p = a["position"][sel]
            ax.plot(*p.T, color=_color(r.spec.controller, i), lw=1.0, label=display_name(r.spec.controller))
            pts.append(p)
            if i == 0:
                ref = a["ideal_position"][sel]
                ax.plot(*ref.T, "k--", lw=0.6, label="stand-off reference")
        _equal_axes(ax, np.concatenate(pts))
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):   # the rotor plane is thin: few ticks on short axes
            axis.set_major_locator(matplotlib.ticker.MaxNLocator(nbins=5, min_n_ticks=2))
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_title(f"phase {ph + 1}" + (" (rotor turned)" if ph else ""))
        if ph == 0:
            ax.legend(loc="upper left", fontsize=8)
    fig.suptitle(title)
    return _save(fig, path)


def distance(runs: Sequence[RunResult], path: Path, title: str) -> Path:
    """The runs' distance to the inspection point (and clearance, where recorded) over time; saved to
    ``path``."""
    r0 = runs[0]
    d_ref, margin = r0.d_ref, r0.safety_margin
    with_clearance = [r for r in runs if "clearance" in r.arrays]
    if with_clearance:
        fig, (ax, axc) = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True)
    else:
        fig, ax = plt.subplots(figsize=(11, 4))
    t_max = max(float(r.arrays["t"][-1]) for r in runs)
    ax.axhspan(d_ref - margin, d_ref + margin, color="0.9", label=f"SM band ±{margin:g} m")
    ax.axhline(d_ref, color="k", lw=0.8, ls="--", label=f"d_ref = {d_ref:g} m")
    for i, r in enumerate(runs):
        a = r.arrays
        sel = _thin(len(a["t"]))
        d = np.where(a["inspecting"][sel], a["distance"][sel], np.nan)
        ax.plot(a["t"][sel], d, color=_color(r.spec.controller, i), lw=0.8,
                label=f"{display_name(r.spec.controller)} (SM {100 * r.metrics['safety_sm']:.1f} %)")
    ax.set_xlim(0, t_max)
    lo = min(d_ref - 2 * margin, *(np.nanmin(np.where(r.arrays["inspecting"], r.arrays["distance"], np.nan))
                                   for r in runs))
    hi = max(d_ref + 2 * margin, *(np.nanmax(np.where(r.arrays["inspecting"], r.arrays["distance"], np.nan))
                                   for r in runs))
    ax.set_ylim(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
    if not with_clearance:
        ax.set_xlabel("time [s]")
    ax.set_ylabel("horizontal distance to the inspection point [m]")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(title)
    if with_clearance:
        _clearance_panel(axc, runs)
    return _save(fig, path)


def _clearance_panel(ax, runs: Sequence[RunResult]) -> None:
    """Clearance of the drone's centre to the turbine mesh over time (window minima, so thinning
    does not hide a close pass), d_min dashed."""
    d_mins = sorted({v for r in runs if np.isfinite(v := float(r.metrics.get("d_min_m", np.nan)))})
    for d_min in d_mins:
        ax.axhline(d_min, color="k", lw=0.8, ls="--", label=f"d_min = {d_min:g} m")
    hi = 0.0
    for i, r in enumerate(runs):
        a = r.arrays
        if "clearance" not in a:
            continue
        sel = _thin(len(a["t"]))
        c = _window_min(a["clearance"].astype(float))
        ax.plot(a["t"][sel], c, color=_color(r.spec.controller, i), lw=0.8,
                label=f"{display_name(r.spec.controller)} (min {r.metrics.get('clearance_min_m', np.nan):.2f} m, "
                      f"{r.metrics.get('time_below_d_min_s', np.nan):.1f} s below d_min)")
        if np.isfinite(c).any():
            hi = max(hi, float(np.nanpercentile(c, 99)))
    ax.set_ylim(0.0, max(hi, *d_mins, 1.0) * 1.15)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("clearance to the turbine [m]")
    ax.legend(fontsize=8, loc="upper right")


def _window_mean(values: np.ndarray) -> np.ndarray:
    """Mean of each thinning window of :func:`_thin` (a 100 Hz power signal drawn at 6k points)."""
    step = max(1, len(values) // MAX_LINE_POINTS)
    n = len(_thin(len(values)))
    pad = np.full(n * step, np.nan)
    pad[:len(values)] = values[:n * step]
    return np.nanmean(pad.reshape(n, step), axis=1)


def energy(runs: Sequence[RunResult], path: Path, title: str) -> Path:
    """Electrical power over time, and the energy used so far minus what hovering would have used
    in the same time (trapezoid over the recorded samples): most of a mission's energy is holding
    the drone up, so the totals of two controllers draw as one line while their difference to
    hover separates them. The legend's numbers are the run's metrics (every control step)."""
    fig, (axp, axe) = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    for i, r in enumerate(runs):
        a = r.arrays
        if "power" not in a:
            continue
        t, P = a["t"].astype(float), a["power"].astype(float)
        sel = _thin(len(t))
        color = _color(r.spec.controller, i)
        m = r.metrics
        axp.plot(t[sel], _window_mean(P), color=color, lw=0.8,
                 label=f"{display_name(r.spec.controller)} (mean {m.get('mean_power_w', np.nan):.0f} W)")
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (P[1:] + P[:-1]) * np.diff(t))]) / 3600.0
        hover = float(m.get("hover_power_w", np.nan))
        above = cum - (hover if np.isfinite(hover) else 0.0) * (t - t[0]) / 3600.0
        axe.plot(t[sel], above[sel], color=color, lw=1.0,
                 label=f"{display_name(r.spec.controller)}: {m.get('energy_wh', np.nan):.2f} Wh, "
                       f"path {m.get('path_length_m', np.nan):.0f} m")
    hover = sorted({v for r in runs if "power" in r.arrays
                    and np.isfinite(v := float(r.metrics.get("hover_power_w", np.nan)))})
    for h in hover:
        axp.axhline(h, color="k", lw=0.8, ls="--", label=f"hover power {h:.0f} W")
    axp.set_ylabel("electrical power [W]")
    axp.legend(fontsize=8, loc="upper right")
    axp.set_title(title)
    axe.set_xlim(0, max(float(r.arrays["t"][-1]) for r in runs))
    axe.set_xlabel("time [s]")
    axe.axhline(0.0, color="k", lw=0.6)
    axe.set_ylabel("energy used minus hovering\nfor the same time [Wh]")
    axe.legend(fontsize=8, loc="upper right")
    return _save(fig, path)


def _window_min(values: np.ndarray) -> np.ndarray:
    """Minimum of each thinning window of :func:`_thin` (NaN-aware), so thinning a curve for
    drawing does not hide a short heading dip."""
    step = max(1, len(values) // MAX_LINE_POINTS)
    n = len(_thin(len(values)))
    pad = np.full(n * step, np.nan)
    pad[:len(values)] = values[:n * step]
    blocks = pad.reshape(n, step)
    ok = np.isfinite(blocks)
    out = np.where(ok, blocks, np.inf).min(axis=1)
    return np.where(ok.any(axis=1), out, np.nan)


def centering(runs: Sequence[RunResult], path: Path, title: str) -> Path:
    """The runs' heading function h (1 = point centred in the image) over time; saved to ``path``."""
    fig, ax = plt.subplots(figsize=(11, 4))
    lo = 1.0
    for i, r in enumerate(runs):
        a = r.arrays
        sel = _thin(len(a["t"]))
        h = _window_min(np.where(a["inspecting"], a["heading"], np.nan))
        ax.plot(a["t"][sel], h, color=_color(r.spec.controller, i), lw=0.8,
                label=f"{display_name(r.spec.controller)} (CM {100 * r.metrics['centering_cm']:.2f} %)")
        if np.isfinite(h).any():
            lo = min(lo, float(np.nanpercentile(h, 0.5)))
    ax.set_ylim(max(-1.0, lo - 0.05 * (1 - lo) - 1e-3), 1.0 + 0.05 * (1 - lo) + 1e-3)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("heading function h (1 = point centred)")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(title)
    return _save(fig, path)


def _blade_layout(a: dict[str, np.ndarray], spec_env: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(triangle_blade, triangle_face, rotor_center)`` from the run file, or - for files written
    before they were stored - from the turbine rebuilt from the run's options (same numbering)."""
    if "triangle_face" in a:
        return a["triangle_blade"], a["triangle_face"], a["rotor_center"]
    from wt_inspect_env.turbine.loading import load_turbine_mesh
    from wt_inspect_env.turbine.mesh import build_turbine
    from wt_inspect_env.turbine.spec import TurbineSpec
    mesh = spec_env.get("turbine_mesh")
    turb = load_turbine_mesh(mesh) if mesh else build_turbine(TurbineSpec(**(spec_env.get("turbine") or {})))
    return turb.triangle_blade, turb.triangle_face, turb.rotor_center


def unfold(tri: np.ndarray, blade: np.ndarray, face: np.ndarray, rotor_center: np.ndarray,
           keep: np.ndarray, gap: float) -> tuple[np.ndarray, list[tuple[float, str]]]:
    """2-D coordinates (M, 3, 2) of every blade triangle, each (blade, face) laid flat as a strip:
    x = distance from the rotor centre along the blade, y = across the face, strips stacked.
    Only strips with a ``keep`` triangle get a place (others stay NaN). Returns the label
    positions too."""
    out = np.full(tri.shape[:2] + (2,), np.nan)
    labels: list[tuple[float, str]] = []
    y0 = 0.0
    for b in np.unique(blade):
        for f in np.unique(face[blade == b]):
            sel = np.flatnonzero((blade == b) & (face == f))
            if not np.any(keep[sel]):
                continue
            v = tri[sel].astype(float)
            c = v.reshape(-1, 3).mean(0)
            e1 = c - rotor_center
            e1 /= np.linalg.norm(e1)
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]).sum(0)
            e2 = np.cross(n, e1)
            e2 /= max(np.linalg.norm(e2), 1e-12)
            x = (v - rotor_center) @ e1
            y = (v - c) @ e2
            y = y - y.min() + y0
            out[sel] = np.stack([x, y], axis=-1)
            labels.append((float(y.min() + y.max()) / 2, f"blade {b} face {f}"))
            y0 = float(y.max()) + gap
    return out, labels


def coverage_map(runs: Sequence[RunResult], path: Path, title: str) -> Path:
    """Per-triangle coverage, the blade faces unfolded into strips (root left, tip right)."""
    from matplotlib.collections import PolyCollection
    n = len(runs)
    cmap = plt.get_cmap("viridis")
    vmax = max(1, max(int(np.max(r.arrays["coverage_counts"], initial=1)) for r in runs))
    a0 = runs[0].arrays
    tri = a0["blade_triangles"][0]
    blade, face, rc = _blade_layout(a0, dict(runs[0].spec.env_options))
    keep = np.zeros(len(tri), bool)
    keep[a0["inspected"]] = True
    span = float(np.ptp(((tri - rc) @ np.array([1.0, 0.0, 0.0])).ravel())) or 1.0
    flat, labels = unfold(tri, blade, face, rc, keep, gap=0.02 * span)
    shown = np.isfinite(flat[:, 0, 0])
    lo, hi = np.nanmin(flat.reshape(-1, 2), 0), np.nanmax(flat.reshape(-1, 2), 0)
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9)
    fig, axes = plt.subplots(1, n, figsize=(5.0 * n + 1.5, min(12.0, max(2.5, 5.0 * aspect + 1.0))), squeeze=False)
    for i, (ax, r) in enumerate(zip(axes[0], runs)):
        a = r.arrays
        ins, counts = a["inspected"], a["coverage_counts"]
        colors = np.tile([0.85, 0.85, 0.85, 1.0], (len(tri), 1))
        seen = counts > 0
        colors[ins[seen]] = cmap(np.log1p(counts[seen]) / np.log1p(vmax))
        colors[ins[~seen]] = [0.85, 0.1, 0.1, 1.0]
        ax.add_collection(PolyCollection(flat[shown], facecolors=colors[shown], edgecolors="k", linewidths=0.05))
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel("distance from the rotor centre [m]")
        ax.set_yticks([y for y, _ in labels], [t for _, t in labels] if i == 0 else [], fontsize=7)
        ax.set_title(f"{display_name(r.spec.controller)}: {int(np.count_nonzero(seen))}/{len(ins)} seen "
                     f"({100 * r.metrics['coverage']:.1f} %)", fontsize=10)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=matplotlib.colors.LogNorm(1, vmax + 1))
    fig.colorbar(sm, ax=list(axes[0]), shrink=0.8, label="frames that saw the triangle (red: never; grey: not in "
                                                        "this mission)")
    fig.suptitle(title)
    return _save(fig, path)


def make_figures(results: Sequence[RunResult], out_dir: str | Path, scenario: str,
                 figure_format: str = DEFAULT_FIGURE_FORMAT) -> list[Path]:
    """All figures for ``results`` (runs must carry their arrays) in ``figure_format`` (png, pdf,
    svg); returns the written paths."""
    ext = "." + check_figure_format(figure_format)
    out = Path(out_dir)
    written: list[Path] = []
    winds = sorted({r.spec.wind for r in results})
    for wind in winds:
        runs = []
        for c in order_controllers(r.spec.controller for r in results):
            mine = sorted((r for r in results if r.spec.wind == wind and r.spec.controller == c),
                          key=lambda r: r.spec.seed)
            if mine and mine[0].arrays:
                runs.append(mine[0])
        if not runs:
            continue
        tag = f"w{wind:g}"
        ttl = f"{scenario}, mean wind {wind:g} m/s (seed {runs[0].spec.seed})"
        written += [trajectories(runs, out / f"trajectories_{tag}{ext}", f"Trajectories: {ttl}"),
                    distance(runs, out / f"distance_{tag}{ext}", f"Distance to the inspection point, clearance to the "
                             f"turbine: {ttl}"),
                    centering(runs, out / f"centering_{tag}{ext}", f"Centering: {ttl}"),
                    coverage_map(runs, out / f"coverage_{tag}{ext}", f"Coverage map: {ttl}")]
        if any("power" in r.arrays for r in runs):
            written.append(energy(runs, out / f"energy_{tag}{ext}", f"Energy: {ttl}"))
    return written
