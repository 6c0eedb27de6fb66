"""The learning-curve figure of a training run (from its ``evaluations.json`` and ``episodes.csv``)."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.figure_io import DEFAULT_FIGURE_FORMAT, save_and_close


def _smooth(y: np.ndarray, window: int) -> np.ndarray:
    if len(y) < 2 or window <= 1:
        return y
    window = min(window, len(y))
    c = np.cumsum(np.insert(y, 0, 0.0))
    out = np.empty_like(y, dtype=float)
    for i in range(len(y)):
        lo = max(0, i - window + 1)
        out[i] = (c[i + 1] - c[lo]) / (i + 1 - lo)
    return out


def read_evaluations(run_dir: str | Path) -> list[dict[str, Any]]:
    """A run's periodic evaluations (``evaluations.json``; none yet: an empty list)."""
    p = Path(run_dir) / "evaluations.json"
    return json.loads(p.read_text()) if p.is_file() else []


def plot_learning_curve(run_dir: str | Path, path: str | Path, target: float = 0.9,
                        fmt: str = DEFAULT_FIGURE_FORMAT) -> Path:
    """Two panels against simulator steps: periodic evaluation (coverage, SM, CM of the
    deterministic policy on the evaluation mission) and training episodes (return, SM; smoothed
    over 20 episodes). ``fmt``: png, pdf or svg (``path``'s suffix is replaced by it). Returns the
    written path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    evals = read_evaluations(run_dir)
    rows = []
    csv_file = run_dir / "episodes.csv"
    if csv_file.is_file():
        with open(csv_file, newline="") as fh:
            rows = list(csv.DictReader(fh))
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    if evals:
        x = np.array([e["env_steps"] for e in evals]) / 1e6
        for key, label in (("coverage", "coverage"), ("safety_sm", "SM"), ("centering_cm", "CM")):
            ax1.plot(x, [e["mean"][key] for e in evals], marker="o", ms=3, label=label)
    ax1.axhline(target, color="k", ls=":", lw=1, label=f"target {target:.0%}")
    ax1.set_ylabel("evaluation (deterministic)")
    ax1.set_ylim(-0.05, 1.05)
    ax1.legend(loc="lower right", fontsize=8)
    ax1.grid(alpha=0.3)
    if rows:
        x = np.array([float(r["env_steps"]) for r in rows]) / 1e6
        ret = np.array([float(r["return"]) for r in rows])
        sm = np.array([float(r["safety_sm"]) for r in rows])
        ax2.plot(x, _smooth(ret, 20), color="C0", label="episode return (smoothed)")
        ax2.set_ylabel("training episode return")
        ax2b = ax2.twinx()
        ax2b.plot(x, _smooth(sm, 20), color="C1", label="episode SM (smoothed)")
        ax2b.set_ylabel("training episode SM")
        ax2b.set_ylim(-0.05, 1.05)
        lines = ax2.get_lines() + ax2b.get_lines()
        ax2.legend(lines, [ln.get_label() for ln in lines], loc="lower right", fontsize=8)
    ax2.set_xlabel("simulator steps [millions]")
    ax2.grid(alpha=0.3)
    summary_file = run_dir / "summary.json"
    title = run_dir.name
    if summary_file.is_file():
        s = json.loads(summary_file.read_text())
        title = f"{s['algo'].upper()} on the {s['task']} task: {s['env_steps'] / 1e6:.2f} M steps, " \
                f"{s['wall_time_s'] / 60:.1f} min"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_and_close(fig, path, fmt)


def write_run_summary(out: Path, summary: Mapping[str, Any], fmt: str = DEFAULT_FIGURE_FORMAT) -> None:
    """A finished run's ``summary.json`` (atomically), then its learning curve - a figure that
    cannot be drawn is a warning, never a lost run (RL training and DAgger finish the same way)."""
    write_text_atomic(Path(out) / "summary.json", json.dumps(summary, indent=1))
    try:
        plot_learning_curve(out, Path(out) / "learning_curve.png", fmt=fmt)
    except Exception as exc:  # a figure must never lose a finished run
        print(f"warning: learning curve not drawn: {exc}", file=sys.stderr)


def draw_targets(axes, targets: Mapping[str, Mapping[str, float]], colors=("g", "tab:orange", "tab:purple")) -> None:
    """Dashed threshold lines on a (min(coverage, SM), CM) pair of axes, one colour per named target.
    Targets that share a threshold on an axis share one line, labelled with all their names (two
    lines at one height would hide the first)."""
    lines: list[dict[float, list[tuple[str, str]]]] = [{}, {}]
    for (name, t), color in zip(targets.items(), colors):
        score_min = min((t[k] for k in ("coverage", "safety_sm") if k in t), default=None)
        for i, value in enumerate((score_min, t.get("centering_cm"))):
            if value is not None:
                lines[i].setdefault(float(value), []).append((name, color))
    for ax, by_value in zip(axes, lines):
        for value, named in by_value.items():
            names = " = ".join(n for n, _ in named if n)
            label = f"{names} target" if names else "target"
            ax.axhline(value, ls="--", color=named[0][1], lw=1, label=f"{label} {value:g}")


def route_points(run_dirs: list[str | Path]) -> list[dict[str, float]]:
    """The periodic evaluations of a training route - one run or a chain of runs each resumed
    from the one before, whose ``evaluations.json`` count steps and wall time from the start of
    the route - as points ``env_steps, wall_min, coverage, safety_sm, centering_cm``."""
    points = []
    for d in run_dirs:
        if not (Path(d) / "evaluations.json").is_file():
            raise ValueError(f"route run {str(d)!r} has no evaluations.json")
        for e in read_evaluations(d):
            m = e["mean"]
            points.append({"env_steps": int(e["env_steps"]), "wall_min": float(e["wall_time_s"]) / 60.0,
                           **{k: float(m[k]) for k in ("coverage", "safety_sm", "centering_cm")}})
    return sorted(points, key=lambda q: q["wall_min"])


def plot_routes(routes: Mapping[str, list[Mapping[str, float]]], path: str | Path,
                fmt: str = DEFAULT_FIGURE_FORMAT, target: Mapping[str, float] | None = None) -> Path:
    """Routes to a policy on one time axis: min(coverage, SM) and CM of each route's evaluations
    against its training wall time (every stage counted), with the target's thresholds dashed.
    ``routes``: label -> points of :func:`route_points`. Returns the written path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for label, pts in routes.items():
        x = [q["wall_min"] for q in pts]
        axes[0].plot(x, [min(q["coverage"], q["safety_sm"]) for q in pts], "-o", ms=4, label=label)
        axes[1].plot(x, [q["centering_cm"] for q in pts], "-o", ms=4, label=label)
    if target:
        draw_targets(axes, {"": target}, ("k",))
    axes[0].set(xlabel="training wall time [min] (all stages)", ylabel="min(coverage, SM)",
                title="evaluation on the full mission, 4 m/s")
    axes[1].set(xlabel="training wall time [min] (all stages)", ylabel="CM",
                title="centering (over the part flown: a crashed evaluation is short)")
    axes[1].set_ylim(0.0, 1.02)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return save_and_close(fig, path, fmt)
