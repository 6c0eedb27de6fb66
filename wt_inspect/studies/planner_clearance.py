"""The planner's clearance over many drawn turbines (``results/planner_clearance``).

The planner promises that every stand-off pose of a mission, and the straight path between
consecutive poses, keeps at least d_min from the whole turbine of the phase it is flown in
(tower, nacelle, hub, every blade), so that the MPCs' clearance constraint never holds a drone off
the pose its reference hands out. This study checks that promise on the turbines the whole-mission
campaign draws (generated sizes, the NREL 5-MW preset and its scaled variants, any rotor azimuth;
the planner choosing the rotor turn), with nothing flown: it builds each environment's mission
exactly as ``gym.make`` does and measures the poses the closed-loop reference hands out::

    wt-inspect study planner-clearance --turbines 1000 --out results/planner_clearance --jobs 2

How a path is certified (:func:`check_mission`): the distance to a mesh is 1-Lipschitz, so on a
straight segment of length L between poses at distances d_a and d_b no point is nearer than
(d_a + d_b - L) / 2. Segments whose bound falls below d_min + margin are sampled every 1 cm and
their least sampled distance reported (a sample is exact; between samples the bound applies
again, within 5 mm). At a rotor turn the drone holds the last pose of the earlier phase while the
rotor moves, so that pose is checked against both rotor positions. Distances are exact
point-to-triangle distances (:class:`~wt_inspect_env.planner.clearance.DistanceField`, tested
against brute force over every triangle).

A turbine the planner refuses (one line naming the surface) is recorded with its reason; it is
not a failure of the promise. Work is saved per chunk of turbines (``runs/chunk_*.json``), so an
interrupted study resumes. Writes ``results.csv`` (one row per turbine), ``results.md``,
``summary.json`` and ``clearance.png`` (the least clearance of each turbine's path).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

#: turbines per saved chunk (the unit of resumption)
CHUNK = 50
#: sampling step [m] of a segment whose Lipschitz bound does not certify it
REFINE_STEP = 0.01
#: the margin [m] the planner states over d_min for its path: its samples clear d_min + check_step / 2
#: and the continuous path d_min; the study requires d_min - this tolerance for rounding
TOLERANCE = 1e-6
FIELDS = ("turbine_index", "turbine", "tower_height", "blade_length", "blade_width", "rotor_azimuth_deg",
          "refused", "phases", "samples", "path_length_m", "d_min_m", "pose_min_m", "path_min_m",
          "hold_min_m", "lowest_pose_m", "refined_segments", "plan_s")


def check_mission(poses: np.ndarray, phase: np.ndarray, fields: Sequence[Any], d_min: float) -> dict[str, Any]:
    """Least clearance of a mission's poses and of the straight path between them.

    ``poses`` (K, 3) the ideal stand-off poses in flight order, ``phase`` (K,) their phase (1-based,
    non-decreasing), ``fields[k]`` a distance field of phase k+1's turbine. Returns ``pose_min_m``
    (least pose clearance to its phase's turbine), ``path_min_m`` (least clearance of the segments,
    each against the turbine of the phase it is flown in: the later pose's), ``hold_min_m`` (least
    clearance of a rotor-turn hold pose to the turbine after the turn; inf without a turn) and
    ``refined_segments`` (segments the Lipschitz bound did not certify at ``d_min``, sampled)."""
    poses = np.asarray(poses, dtype=float)
    phase = np.asarray(phase, dtype=np.int64)
    if len(poses) != len(phase) or len(poses) == 0:
        raise ValueError(f"poses and phase must be non-empty and of one length, got {len(poses)} and {len(phase)}")
    if np.any(np.diff(phase) < 0) or phase.min() < 1 or phase.max() > len(fields):
        raise ValueError(f"phase must be non-decreasing in 1..{len(fields)}")
    cap = math.inf            # exact distances everywhere (the bound needs them, the table reports them)
    own = np.empty(len(poses))
    for k in np.unique(phase):
        sel = phase == k
        own[sel] = fields[k - 1].distance(poses[sel], cap)
    seg_phase = phase[1:]
    a, b = poses[:-1], poses[1:]
    length = np.linalg.norm(b - a, axis=1)
    d_a = own[:-1].copy()
    turn = np.flatnonzero(phase[1:] != phase[:-1])
    hold_min = math.inf
    for i in turn:       # the hold pose i, flown against the turned rotor
        d_after = float(fields[phase[i + 1] - 1].distance(poses[i:i + 1], cap)[0])
        d_a[i] = d_after
        hold_min = min(hold_min, d_after)
    bound = 0.5 * (d_a + own[1:] - length)
    weak = np.flatnonzero(bound < d_min)
    for i in weak:
        n = max(2, int(math.ceil(length[i] / REFINE_STEP)) + 1)
        pts = a[i] + np.linspace(0.0, 1.0, n)[:, None] * (b[i] - a[i])
        d = fields[seg_phase[i] - 1].distance(pts, cap)
        step = length[i] / (n - 1)
        # exact at the samples; between two samples the bound again (at most step / 2 lower)
        seg_low = float(min(d.min(), (0.5 * (d[:-1] + d[1:] - step)).min()))
        bound[i] = seg_low
    path_min = float(min(own.min(), bound.min())) if len(bound) else float(own.min())
    return {"pose_min_m": float(own.min()), "path_min_m": path_min, "hold_min_m": hold_min,
            "refined_segments": int(len(weak))}


def draws(turbines: int, seed: int) -> list[dict[str, Any]]:
    """The campaign's turbine draws (its first ``turbines`` episodes of master seed ``seed``)."""
    from ..commands.campaign import CampaignConfig, draw_episodes
    return draw_episodes(CampaignConfig(episodes=turbines, seed=seed))


def planned_draws(argv: Sequence[str]) -> list[dict[str, Any]]:
    """The turbine draws the command line ``argv`` plans (what ``wt-inspect reproduce`` digests)."""
    a = build_parser().parse_args(list(argv))
    return draws(a.turbines, a.seed)


def drawn_mission(draw: Mapping[str, Any]) -> tuple[Any, Any]:
    """The environment configuration and mission of a drawn turbine, built as ``gym.make`` builds them."""
    from wt_inspect_env.task.env_config import EnvConfig
    from wt_inspect_env.task.mission import build_mission

    from ..commands.campaign import episode_options
    opts = episode_options(draw, "full", airframe_randomization=False)
    opts.update(wind="none", start_offset=(0.0, 0.0, 0.0))
    cfg = EnvConfig(**opts)
    return cfg, build_mission(cfg)


def planned_path(draw: Mapping[str, Any]) -> np.ndarray:
    """The stand-off poses the reference hands out on a drawn turbine's mission, in flight order."""
    from wt_inspect_env.task.reference import standoff_poses
    cfg, mission = drawn_mission(draw)
    return standoff_poses(mission.points, mission.normals, cfg.standoff)


def check_draw(draw: Mapping[str, Any]) -> dict[str, Any]:
    """Plan one drawn turbine as the environment does and check its mission (one table row)."""
    from wt_inspect_env.planner.clearance import DistanceField
    from wt_inspect_env.task.reference import standoff_poses
    row: dict[str, Any] = {"turbine_index": int(draw["episode"]), "turbine": draw["turbine"],
                           "tower_height": float(draw["tower_height"]), "blade_length": float(draw["blade_length"]),
                           "blade_width": float(draw["blade_width"]),
                           "rotor_azimuth_deg": float(draw["rotor_azimuth_deg"]), "refused": ""}
    t0 = time.perf_counter()
    try:
        cfg, mission = drawn_mission(draw)
    except ValueError as exc:
        row.update(refused=str(exc).splitlines()[0], plan_s=time.perf_counter() - t0)
        return row
    plan_s = time.perf_counter() - t0
    d_min = float(cfg.d_min)
    poses = standoff_poses(mission.points, mission.normals, cfg.standoff)
    fields = [DistanceField(t.all_triangles) for t in mission.turbines]
    res = check_mission(poses, mission.phase, fields, d_min)
    row.update(phases=len(mission.turbines), samples=len(poses),
               path_length_m=float(np.linalg.norm(np.diff(poses, axis=0), axis=1).sum()), d_min_m=d_min,
               lowest_pose_m=float(poses[:, 2].min()), plan_s=plan_s, **res)
    return row


def _chunk(draws_: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    return [check_draw(d) for d in draws_]


def build_parser(prog: str = "wt-inspect study planner-clearance") -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect study planner-clearance``."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--turbines", type=int, default=1000, metavar="N", help="turbines drawn (default 1000)")
    ap.add_argument("--seed", type=int, default=0, help="the campaign's master seed (default 0, the campaign's)")
    ap.add_argument("--out", required=True, metavar="DIR")
    ap.add_argument("--jobs", type=int, metavar="N", help="parallel chunks (default: the number of cores)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def failures(r: Mapping[str, Any]) -> list[str]:
    """Why a planned turbine breaks the promise (empty: it keeps it, or the planner refused it)."""
    if r.get("refused"):
        return []
    out = []
    for key, what in (("pose_min_m", "pose"), ("path_min_m", "path"), ("hold_min_m", "turn hold")):
        v = float(r[key])
        if v < float(r["d_min_m"]) - TOLERANCE:
            out.append(f"{what} {v:.3f} m from the turbine")
    return out


def markdown(rows: Sequence[Mapping[str, Any]], command: str) -> str:
    """results.md: how many turbines keep the promise, the least clearances, the refusals and the
    planning time."""
    from wt_inspect_env import __version__
    planned = [r for r in rows if not r["refused"]]
    refused = [r for r in rows if r["refused"]]
    bad = [r for r in planned if failures(r)]
    lines = ["# The planner's clearance on drawn turbines", "",
             f"{len(rows)} turbines drawn as the whole-mission campaign draws them (generated, NREL 5-MW and scaled "
             "NREL 5-MW, any rotor azimuth; the planner choosing the rotor turn), each planned as `gym.make` plans "
             "it; no flight. Checked: every stand-off pose the reference hands out and the straight path between "
             "consecutive poses against the whole turbine of the phase it is flown in, and every rotor-turn hold "
             "pose against the turned rotor; exact point-to-triangle distances.", "",
             f"Command: `{command}` (wt-inspect {__version__}).", "",
             f"- planned: {len(planned)}; refused by the planner: {len(refused)}",
             f"- below d_min: **{len(bad)}** of {len(planned)} planned turbines"]
    if planned:
        d_min = min(float(r["d_min_m"]) for r in planned)
        path = np.array([float(r["path_min_m"]) for r in planned])
        pose = np.array([float(r["pose_min_m"]) for r in planned])
        holds = [float(r["hold_min_m"]) for r in planned if math.isfinite(float(r["hold_min_m"]))]
        secs = np.array([float(r["plan_s"]) for r in planned])
        lines += [f"- least clearance of any pose: {pose.min():.3f} m (d_min {d_min:.2f} m)",
                  f"- least clearance of any path between poses: at least {path.min():.3f} m (a certified lower "
                  "bound: a segment of length L between poses at distances d_a and d_b clears (d_a + d_b - L) / 2, "
                  "and a segment it does not certify is sampled); "
                  f"median over the turbines {np.median(path):.3f} m",
                  f"- turbines with a rotor turn: {len(holds)}; least clearance of a hold pose to the turned rotor "
                  + (f"{min(holds):.3f} m" if holds else "-"),
                  f"- segments the Lipschitz bound did not certify (sampled every {100 * REFINE_STEP:g} cm): "
                  f"{sum(int(r['refined_segments']) for r in planned)}",
                  f"- planning time per turbine: median {np.median(secs):.2f} s, "
                  f"95th percentile {np.percentile(secs, 95):.2f} s (this machine, several turbines at once)"]
    lines.append("")
    if bad:
        lines += ["## Turbines below d_min", ""]
        lines += [f"- turbine {r['turbine_index']} ({r['turbine']}, tower {float(r['tower_height']):.1f} m, blade "
                  f"{float(r['blade_length']):.1f} m, azimuth {float(r['rotor_azimuth_deg']):.1f} deg): "
                  + "; ".join(failures(r)) for r in bad]
        lines.append("")
    if refused:
        lines += ["## Refused turbines", ""]
        reasons: dict[str, list[int]] = {}
        for r in refused:
            reasons.setdefault(r["refused"], []).append(int(r["turbine_index"]))
        lines += [f"- {len(ix)} x: {why} (turbines {', '.join(map(str, ix[:10]))}{' ...' if len(ix) > 10 else ''})"
                  for why, ix in sorted(reasons.items(), key=lambda kv: -len(kv[1]))]
        lines.append("")
    return "\n".join(lines)


def figure(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """The least path clearance of each planned turbine over its blade length, by turbine kind."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from wt_inspect_env.util.figure_io import save_and_close
    planned = [r for r in rows if not r["refused"]]
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for kind in sorted({r["turbine"] for r in planned}):
        mine = [r for r in planned if r["turbine"] == kind]
        ax.scatter([float(r["blade_length"]) for r in mine], [float(r["path_min_m"]) for r in mine], s=9,
                   label=kind, alpha=0.7)
    if planned:
        ax.axhline(min(float(r["d_min_m"]) for r in planned), color="k", ls="--", lw=1, label="d_min")
    ax.set_xlabel("blade length [m]")
    ax.set_ylabel("least clearance of the path [m]")
    ax.set_title(f"Planner clearance, {len(planned)} planned turbines")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_and_close(fig, path)


def main(argv: list[str], prog: str = "wt-inspect study planner-clearance") -> int:
    """``wt-inspect study planner-clearance``: run (or resume) the check given by ``argv``."""
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    if not 1 <= args.turbines <= 10_000:
        ap.error(f"--turbines must be in [1, 10000], got {args.turbines}")
    if args.seed < 0:
        ap.error(f"--seed must be >= 0, got {args.seed}")
    from wt_inspect_env.util.atomic_io import write_text_atomic

    from ..evaluation import prepare_out_dir
    from ..evaluation.backends import check_jobs
    try:
        jobs = check_jobs(args.jobs)
        out = prepare_out_dir(args.out)
    except ValueError as exc:
        ap.error(str(exc))
    all_draws = draws(args.turbines, args.seed)
    chunks = {f"chunk_{args.seed}_{s:05d}_{min(s + CHUNK, args.turbines):05d}.json": all_draws[s:s + CHUNK]
              for s in range(0, args.turbines, CHUNK)}
    done: dict[str, list[dict[str, Any]]] = {}
    for name in chunks:
        f = out / "runs" / name
        if f.exists():
            try:
                done[name] = json.loads(f.read_text())
            except (OSError, json.JSONDecodeError):
                print(f"warning: {f} is unreadable; planning its turbines again", file=sys.stderr)
    todo = [n for n in chunks if n not in done]

    def save(name: str, rows_: list[dict[str, Any]]) -> None:
        write_text_atomic(out / "runs" / name, json.dumps(rows_, indent=0) + "\n")
        done[name] = rows_

    from tqdm.auto import tqdm
    bar = tqdm(total=sum(len(chunks[n]) for n in todo), unit="turbine", disable=args.no_progress)
    if jobs == 1 or len(todo) <= 1:
        for name in todo:
            save(name, _chunk(chunks[name]))
            bar.update(len(chunks[name]))
    else:
        import concurrent.futures as cf
        import multiprocessing as mp
        with cf.ProcessPoolExecutor(max_workers=min(jobs, len(todo)), mp_context=mp.get_context("spawn")) as pool:
            futures = {pool.submit(_chunk, chunks[n]): n for n in todo}
            for fut in cf.as_completed(futures):
                name = futures[fut]
                save(name, fut.result())
                bar.update(len(chunks[name]))
    bar.close()
    rows = [r for n in chunks for r in done[n]]
    tmp = out / "results.csv.tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS)
        w.writeheader()
        w.writerows({k: r.get(k, "") for k in FIELDS} for r in rows)
    tmp.replace(out / "results.csv")
    command = "wt-inspect study planner-clearance " + " ".join(argv)
    write_text_atomic(out / "results.md", markdown(rows, command))
    planned = [r for r in rows if not r["refused"]]
    write_text_atomic(out / "summary.json", json.dumps(
        {"command": command, "turbines": len(rows), "planned": len(planned),
         "below_d_min": sum(bool(failures(r)) for r in planned),
         "least_path_clearance_m": min((float(r["path_min_m"]) for r in planned), default=None)}, indent=1) + "\n")
    figure(rows, out / "clearance.png")
    print(f"{len(rows)} turbines ({len(planned)} planned, {sum(bool(failures(r)) for r in planned)} below d_min); "
          f"wrote {out}/results.md")
    return 0


if __name__ == "__main__":   # pragma: no cover
    sys.exit(main(sys.argv[1:]))
