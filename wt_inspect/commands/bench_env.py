"""``wt-inspect bench env``: environment steps per second on the full mission, coverage on.

A hovering policy (the hover action every step) flies the default full two-phase mission with the
paper's 4 m/s gust; episodes that end (drift out of the working volume) are reset, so resets are
part of the measurement. Memory (resident set size) is sampled at the start and the end to show it
stays flat over many steps and resets. The figure reported is the median over ``--repeats`` blocks.
``--obs-mode rgb|depth|rgbd`` measures the camera observations (rendered every step, at
``--camera-resolution``); fewer ``--steps`` suffice there.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import gymnasium as gym

from wt_inspect_env.task.env_config import OBS_MODES, EnvConfig

from .timing_reference import raw_pybullet_rate, rss_mb


def main(argv: list[str], prog: str = "wt-inspect bench env") -> int:
    """``wt-inspect bench env``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20000, help="steps per repeat (default 20000)")
    ap.add_argument("--repeats", type=int, default=5, help="timed blocks (default 5)")
    ap.add_argument("--task", default="full", choices=["full", "blade", "surface"])
    ap.add_argument("--obs-mode", default="state", choices=list(OBS_MODES),
                    help="observation mode (default state; the image modes render the gimbal camera every step)")
    ap.add_argument("--camera-resolution", default="84x84", help="WxH of the image modes (default 84x84)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        print(f"{prog}: --steps and --repeats must be positive, got {args.steps}, {args.repeats}", file=sys.stderr)
        return 2
    try:
        w, h = (int(v) for v in args.camera_resolution.lower().split("x"))
        EnvConfig(obs_mode=args.obs_mode, camera_resolution=(w, h))
    except ValueError as exc:
        msg = exc if "camera_resolution" in str(exc) else f"must be WxH, got {args.camera_resolution!r}"
        print(f"{prog}: --camera-resolution {msg}", file=sys.stderr)
        return 2
    import wt_inspect_env  # noqa: F401 - registers the ids
    env_id = {"full": "WindTurbineInspection-v0", "blade": "WindTurbineInspection-Blade-v0",
              "surface": "WindTurbineInspection-Surface-v0"}[args.task]
    env = gym.make(env_id, obs_mode=args.obs_mode, camera_resolution=(w, h)).unwrapped  # no wrappers
    hover = env.scaling.hover_action()
    env.reset(seed=0)
    for _ in range(200):  # warm-up
        env.step(hover)
    rss0 = rss_mb()
    rates, resets, total = [], 0, 0
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        for _ in range(args.steps):
            _, _, term, trunc, _ = env.step(hover)
            if term or trunc:
                env.reset()
                resets += 1
        rates.append(args.steps / (time.perf_counter() - t0))
        total += args.steps
    rss1 = rss_mb()
    raw = raw_pybullet_rate(env.params, env.config.ctrl_hz, env.config.physics_hz,
                            obstacle=env.mission.turbines[0].mesh)
    env.close()
    med = statistics.median(rates)
    out = {"task": args.task, "obs_mode": args.obs_mode,
           "camera_resolution": None if args.obs_mode == "state" else [w, h], "steps_per_s": med,
           "realtime_factor": med * env.dt,
           "steps_per_s_min": min(rates), "steps_per_s_max": max(rates), "steps": total, "resets": resets,
           "ctrl_hz": env.config.ctrl_hz, "physics_hz": env.config.physics_hz, "camera_hz": env.config.camera_hz,
           "rss_start_mb": rss0, "rss_end_mb": rss1, "rss_growth_mb": rss1 - rss0,
           "raw_pybullet_steps_per_s": raw, "ratio_to_raw_pybullet": med / raw}
    if args.json:
        print(json.dumps(out))
    else:
        shown = args.obs_mode if args.obs_mode == "state" else f"{args.obs_mode} {w}x{h}"
        print(f"env {args.task} ({shown} observations): {med:,.0f} steps/s (median of {args.repeats} x {args.steps}; "
              f"min {min(rates):,.0f}, max {max(rates):,.0f}) = {out['realtime_factor']:.1f}x real time "
              f"at {env.config.ctrl_hz:g} Hz control, {env.config.physics_hz:g} Hz physics, "
              f"coverage frames at {env.config.camera_hz:g} Hz")
        print(f"reference: raw PyBullet stepping of one body under the same forces {raw:,.0f} steps/s in the same "
              f"run; ratio env / raw = {med / raw:.3f}")
        print(f"memory: {rss0:.1f} MB -> {rss1:.1f} MB over {total:,} steps and {resets} resets "
              f"({rss1 - rss0:+.1f} MB)")
    return 0
