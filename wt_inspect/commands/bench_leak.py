"""``wt-inspect bench leak``: memory over many ``gym.make`` / ``reset`` / ``close`` cycles.

Each cycle builds the environment (turbine, plan, PyBullet world), resets it, steps it once and
closes it - what an evaluation worker, a campaign or a hyper-parameter search does over and over
in one process. After a few warm-up cycles the resident set size (RSS) is sampled after every
cycle (following a garbage collection) and the least-squares slope of RSS over the cycle count is
reported: a leak shows as a positive slope (PyBullet's kept references to the mesh lists made it
one copy of the mesh per cycle before :mod:`wt_inspect_env.scene.pybullet_refs`), allocator noise as a
slope near zero with a small spread.
"""
from __future__ import annotations

import argparse
import gc
import json
import sys
import time
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.util.process_memory import release_free_heap

from .timing_reference import rss_mb

TASK_IDS = {"full": "WindTurbineInspection-v0", "blade": "WindTurbineInspection-Blade-v0",
            "surface": "WindTurbineInspection-Surface-v0"}


def measure_make_close(cycles: int, task: str = "surface", warmup: int = 3,
                       options: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """RSS [MB] after each of ``cycles`` make/reset/step/close cycles (after ``warmup`` unmeasured
    ones) and its slope [kB per cycle]."""
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the ids
    if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 2:
        raise ValueError(f"cycles must be an integer >= 2, got {cycles!r}")
    env_id = TASK_IDS[task]
    opts = dict(options or {})

    def cycle(seed: int) -> None:
        env = gym.make(env_id, **opts)
        try:
            env.reset(seed=seed)
            env.step(env.unwrapped.scaling.hover_action())
        finally:
            env.close()

    def settled_rss() -> float:
        # what is still allocated: without the trim, glibc keeps a large freed block (of a
        # surface mission's set-up) mapped or not depending on the heap's layout, and the resident
        # set of identical cycles jumped between two levels
        gc.collect()
        release_free_heap()
        return rss_mb()

    for i in range(warmup):
        cycle(i)
    rss0 = settled_rss()
    samples = []
    t0 = time.perf_counter()
    for i in range(cycles):
        cycle(i)
        samples.append(settled_rss())
    wall = time.perf_counter() - t0
    x = np.arange(1, cycles + 1, dtype=float)
    slope_mb = float(np.polyfit(x, np.asarray(samples), 1)[0])
    return {"task": task, "cycles": cycles, "warmup": warmup, "rss_start_mb": rss0, "rss_end_mb": samples[-1],
            "rss_growth_mb": samples[-1] - rss0, "rss_max_mb": max(samples), "slope_kb_per_cycle": slope_mb * 1024,
            "seconds_per_cycle": wall / cycles, "rss_mb": samples}


def main(argv: list[str], prog: str = "wt-inspect bench leak") -> int:
    """``wt-inspect bench leak``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--make-close", type=int, default=300, metavar="N", help="measured cycles (default 300)")
    ap.add_argument("--warmup", type=int, default=3, help="unmeasured cycles first (default 3)")
    ap.add_argument("--task", default="surface", choices=list(TASK_IDS))
    ap.add_argument("--json", action="store_true", help="print one JSON object (with every RSS sample)")
    args = ap.parse_args(argv)
    if args.warmup < 0:
        print(f"{prog}: error: --warmup must be >= 0, got {args.warmup}", file=sys.stderr)
        return 2
    try:
        out = measure_make_close(args.make_close, args.task, args.warmup)
    except ValueError as exc:
        print(f"{prog}: error: --make-close {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(out))
    else:
        print(f"make/reset/step/close x {out['cycles']} ({args.task} task, "
              f"{out['seconds_per_cycle']:.2f} s per cycle): "
              f"RSS {out['rss_start_mb']:.1f} MB -> {out['rss_end_mb']:.1f} MB ({out['rss_growth_mb']:+.1f} MB, "
              f"max {out['rss_max_mb']:.1f}); slope {out['slope_kb_per_cycle']:+.1f} kB per cycle")
    return 0
