"""``wt-inspect bench vecenv``: aggregate steps per second of the vector env against the single env.

For each N in ``--num-envs`` the same mission (default: the full two-phase mission, 100 Hz control,
400 Hz physics, coverage and occlusion on, the paper's 4 m/s gust) is stepped with the hover action
plus small seeded noise for every drone; episodes that end are reset inside the measured time (the
vector env's own autoreset, ``env.reset()`` for the single env). N = 1 is the *single*
:class:`~wt_inspect_env.env.WindTurbineInspectionEnv`, measured in the same run, and every other
figure is also printed as a ratio to it. Raw PyBullet stepping of one body under the same forces
(:func:`~wt_inspect.commands.timing_reference.raw_pybullet_rate`) is timed too, as the
machine reference. Memory: resident set size before building each env, after warm-up and at the
end, and the growth per drone. Figures are medians over ``--repeats`` blocks.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import gymnasium as gym
import numpy as np

from .args import json_object
from .timing_reference import raw_pybullet_rate, rss_mb

ENV_IDS = {"full": "WindTurbineInspection-v0", "blade": "WindTurbineInspection-Blade-v0",
           "surface": "WindTurbineInspection-Surface-v0"}


def _parse_counts(text: str) -> list[int]:
    try:
        counts = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--num-envs must be comma-separated positive integers, got {text!r}") from None
    if not counts or any(c < 1 for c in counts):
        raise ValueError(f"--num-envs must be comma-separated positive integers, got {text!r}")
    return sorted(set(counts))


def _actions(rng: np.random.Generator, hover: np.ndarray, n: int) -> np.ndarray:
    return np.clip(hover + rng.normal(0.0, 0.02, (n, 4)), -1.0, 1.0).astype(np.float32)


def measure_single(task: str, steps: int, repeats: int, options: dict) -> dict:
    """Steps per second of the single env (hover + noise, resets on episode end)."""
    rss0 = rss_mb()
    env = gym.make(ENV_IDS[task], **options).unwrapped
    hover = env.scaling.hover_action()
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    for _ in range(200):
        env.step(_actions(rng, hover, 1)[0])
    rss1 = rss_mb()
    rates, resets = [], 0
    for _ in range(repeats):
        acts = _actions(rng, hover, steps)
        t0 = time.perf_counter()
        for a in acts:
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
                resets += 1
        rates.append(steps / (time.perf_counter() - t0))
    rss2 = rss_mb()
    dt = env.dt
    env.close()
    return _summary(rates, dt, 1, steps * repeats, resets, rss0, rss1, rss2)


def measure_vector(task: str, n: int, steps: int, repeats: int, options: dict) -> dict:
    """Aggregate steps per second of the vector env with ``n`` drones."""
    rss0 = rss_mb()
    env = gym.make_vec(ENV_IDS[task], num_envs=n, vectorization_mode="vector_entry_point", **options)
    hover = env.unwrapped.scaling.hover_action()
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    for _ in range(max(20, 200 // n)):
        env.step(_actions(rng, hover, n))
    rss1 = rss_mb()
    per_block = max(1, steps // n)
    rates, resets = [], 0
    for _ in range(repeats):
        acts = _actions(rng, hover, per_block * n).reshape(per_block, n, 4)
        t0 = time.perf_counter()
        for a in acts:
            _, _, term, trunc, _ = env.step(a)
            resets += int(np.count_nonzero(term | trunc))
        rates.append(per_block * n / (time.perf_counter() - t0))
    rss2 = rss_mb()
    dt = env.unwrapped.dt
    env.close()
    return _summary(rates, dt, n, per_block * n * repeats, resets, rss0, rss1, rss2)


def measure_memory(task: str, n: int, total_steps: int, options: dict, samples: int = 10) -> dict:
    """Resident set size over ``total_steps`` aggregate steps of the vector env with ``n`` drones
    (autoresets included): ``samples`` readings, and the growth per million steps from a
    least-squares line through the second half of them (after the allocator has settled)."""
    from tqdm import tqdm

    env = gym.make_vec(ENV_IDS[task], num_envs=n, vectorization_mode="vector_entry_point", **options)
    hover = env.unwrapped.scaling.hover_action()
    rng = np.random.default_rng(1)
    env.reset(seed=1)
    per_sample = max(1, total_steps // (n * samples))
    acts = _actions(rng, hover, 64 * n).reshape(64, n, 4)
    readings = [(0, rss_mb())]
    done = 0
    with tqdm(total=per_sample * samples * n, unit="step", unit_scale=True, desc=f"memory, N = {n}",
              disable=not sys.stderr.isatty()) as bar:
        for _ in range(samples):
            for k in range(per_sample):
                env.step(acts[k % 64])
            done += per_sample * n
            bar.update(per_sample * n)
            readings.append((done, rss_mb()))
    env.close()
    half = readings[len(readings) // 2:]
    x = np.array([r[0] for r in half], dtype=float) / 1e6
    y = np.array([r[1] for r in half])
    slope = float(np.polyfit(x, y, 1)[0]) if len(half) >= 2 and np.ptp(x) > 0 else float("nan")
    return {"num_envs": n, "steps": done, "rss_mb": [r[1] for r in readings], "at_steps": [r[0] for r in readings],
            "growth_mb_per_million_steps_second_half": slope,
            "growth_mb_total": readings[-1][1] - readings[0][1]}


def _summary(rates: list[float], dt: float, n: int, total: int, resets: int,
             rss0: float, rss1: float, rss2: float) -> dict:
    med = statistics.median(rates)
    return {"steps_per_s": med, "steps_per_s_min": min(rates), "steps_per_s_max": max(rates),
            "realtime_factor": med * dt, "num_envs": n, "steps": total, "resets": resets,
            "rss_before_mb": rss0, "rss_after_warmup_mb": rss1, "rss_end_mb": rss2,
            "memory_per_drone_mb": (rss1 - rss0) / n, "rss_growth_mb": rss2 - rss1}


def crazyflow_rates(python: str, counts: list[int], steps: int, repeats: int) -> dict[str, float]:
    """Aggregate drone-steps/s of crazyflow stepped like an env, measured by ``python`` (the
    interpreter of crazyflow's own virtual environment) running :mod:`.peer_crazyflow`."""
    import subprocess
    from pathlib import Path
    script = Path(__file__).with_name("peer_crazyflow.py")
    try:
        proc = subprocess.run([python, str(script), ",".join(map(str, counts)), str(steps), str(repeats)],
                              capture_output=True, text=True, timeout=3600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise ValueError(f"--crazyflow-python {python!r} could not run: {exc}") from None
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise ValueError(f"--crazyflow-python {python!r} failed: {tail[:200]}")
    try:
        return {k: float(v) for k, v in json.loads(proc.stdout.strip().splitlines()[-1]).items()}
    except (ValueError, IndexError):
        raise ValueError(f"--crazyflow-python {python!r} printed no result") from None


def run_bench(counts: list[int], task: str = "full", steps: int = 20000, repeats: int = 3,
              options: dict | None = None, crazyflow_python: str | None = None, memory_steps: int = 0) -> dict:
    """Run the benchmark; returns ``{"1": {...}, "8": {...}, ...}`` plus a ``"reference"`` entry."""
    import wt_inspect_env  # noqa: F401 - registers the ids

    options = dict(options or {})
    out: dict = {}
    single = measure_single(task, steps, repeats, options)
    out["1"] = single
    for n in counts:
        if n == 1:
            continue
        out[str(n)] = measure_vector(task, n, steps, repeats, options)
    probe = gym.make(ENV_IDS[task], **options).unwrapped
    raw = raw_pybullet_rate(probe.params, probe.config.ctrl_hz, probe.config.physics_hz,
                            obstacle=probe.mission.turbines[0].mesh)
    probe.close()
    for entry in out.values():
        entry["ratio_to_single"] = entry["steps_per_s"] / single["steps_per_s"]
        entry["ratio_to_raw_pybullet"] = entry["steps_per_s"] / raw
    out["reference"] = {"raw_pybullet_steps_per_s": raw, "task": task, "options": options}
    if crazyflow_python:
        peer = crazyflow_rates(crazyflow_python, sorted({1, *counts}), steps, repeats)
        for key, rate in peer.items():
            if key in out:
                out[key]["crazyflow_steps_per_s"] = rate
                out[key]["ratio_to_crazyflow"] = out[key]["steps_per_s"] / rate
    if memory_steps:
        out["memory"] = measure_memory(task, max(counts), memory_steps, options)
    return out


def main(argv: list[str], prog: str = "wt-inspect bench vecenv") -> int:
    """``wt-inspect bench vecenv``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--num-envs", default="1,8,32,128", help="comma-separated drone counts (default 1,8,32,128)")
    ap.add_argument("--task", default="full", choices=sorted(ENV_IDS))
    ap.add_argument("--steps", type=int, default=20000, help="aggregate steps per repeat and N (default 20000)")
    ap.add_argument("--repeats", type=int, default=3, help="timed blocks per N (default 3)")
    ap.add_argument("--env", type=json_object("--env"), default=None,
                    help="environment options as a JSON object (as gym.make keywords)")
    ap.add_argument("--crazyflow-python", default=None, metavar="PATH",
                    help="the Python of a virtual environment with crazyflow: time it stepped like an env, "
                         "same N, side by side")
    ap.add_argument("--memory-steps", type=int, default=0, metavar="M",
                    help="also step the largest N for M aggregate steps and report the resident set's growth")
    ap.add_argument("--json", action="store_true", help="print one JSON object keyed by N")
    args = ap.parse_args(argv)
    try:
        counts = _parse_counts(args.num_envs)
        if args.steps < 1 or args.repeats < 1:
            raise ValueError(f"--steps and --repeats must be positive, got {args.steps}, {args.repeats}")
        if args.memory_steps < 0:
            raise ValueError(f"--memory-steps must be >= 0, got {args.memory_steps}")
        out = run_bench(counts, args.task, args.steps, args.repeats, args.env or {}, args.crazyflow_python,
                        args.memory_steps)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(out))
        return 0
    raw = out["reference"]["raw_pybullet_steps_per_s"]
    print(f"vector env, task {args.task}: aggregate env steps/s (median of {args.repeats} x {args.steps}); "
          f"raw PyBullet reference {raw:,.0f} steps/s")
    peer = args.crazyflow_python is not None
    print(f"{'N':>5} {'steps/s':>10} {'x real time':>11} {'x single':>9} {'x raw':>7} {'MB/drone':>9} "
          f"{'RSS growth':>11}"
          + (f" {'crazyflow':>10} {'x cf':>6}" if peer else ""))
    for key, e in out.items():
        if key in ("reference", "memory"):
            continue
        label = "1*" if key == "1" else key
        print(f"{label:>5} {e['steps_per_s']:>10,.0f} {e['realtime_factor']:>11.1f} {e['ratio_to_single']:>9.2f} "
              f"{e['ratio_to_raw_pybullet']:>7.3f} {e['memory_per_drone_mb']:>9.2f} {e['rss_growth_mb']:>+10.1f}M"
              + (f" {e.get('crazyflow_steps_per_s', float('nan')):>10,.0f} "
                 f"{e.get('ratio_to_crazyflow', float('nan')):>6.2f}"
                 if peer else ""))
    print("(* N = 1 is the single WindTurbineInspectionEnv"
          + ("; crazyflow: Sim(n_worlds=N), first-principles dynamics, body-rate control at 400 Hz, stepped every 10 ms"
             if peer else "") + ")")
    if "memory" in out:
        m = out["memory"]
        print(f"memory, N = {m['num_envs']}, {m['steps']:,} aggregate steps: RSS {m['rss_mb'][0]:.0f} -> "
              f"{m['rss_mb'][-1]:.0f} MB ({m['growth_mb_total']:+.1f} MB); second half "
              f"{m['growth_mb_per_million_steps_second_half']:+.2f} MB per million steps")
    return 0
