"""``wt-inspect bench planner``: planning time for the default turbine (medians over repeats).

Times, per repeat: building the turbine mesh; ``plan_inspection`` end to end (clustering, phase
split and clearance set-up, exact ordering of both phases, path with clearance checks and
resampling); and the exact Held-Karp ordering alone, on the phase-1 instance (10 surfaces) and on
all 12 surfaces at once (the size of the paper's brute-force problem). One warm-up repeat is
discarded. Targets: planning < 0.5 s end to end, exact ordering < 0.1 s.

A second case is a turbine as the whole-mission campaign draws them: the NREL 5-MW preset at rotor
azimuth 70 deg with the planner choosing the rotor turns (dozens of candidate rotor positions, each
checked for clearance, and a transit that needs the grid search); target < 5 s. Both are also
printed as a ratio to a reference timed in the same run (:func:`reference_seconds`: NumPy's
closest point on 200,000 fixed point-triangle pairs), since machines differ by up to ~3x.
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import numpy as np

from wt_inspect_env.planner import HeldKarp, PlannerConfig, cluster_surfaces, plan_inspection
from wt_inspect_env.planner.path import offset_direction
from wt_inspect_env.turbine.mesh import build_turbine
from wt_inspect_env.turbine.spec import TurbineSpec

TARGET_PLAN_S = 0.5
TARGET_ORDER_S = 0.1
TARGET_CHOSEN_TURN_S = 5.0
#: the campaign-style case: NREL 5-MW as published, rotor azimuth 70 deg, rotor turns chosen
CHOSEN_TURN_SPEC = {"preset": "nrel-5mw", "rotor_azimuth_deg": 70.0}


def reference_seconds(repeats: int = 5) -> float:
    """Median time [s] of a fixed NumPy workload like the planner's inner loop (the closest point on
    200,000 seeded point-triangle pairs): the in-run reference the planner's times are divided by."""
    from wt_inspect_env.planner.clearance import closest_points_on_triangles
    rng = np.random.default_rng(0)
    p, a, b, c = (rng.normal(size=(200_000, 3)) for _ in range(4))
    times = []
    for _ in range(repeats + 1):
        t, _ = _timed(closest_points_on_triangles, p, a, b, c)
        times.append(t)
    return statistics.median(times[1:])


def _timed(fn, *args, **kwargs) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return time.perf_counter() - t0, out


def run_bench(repeats: int = 7, spec: TurbineSpec | None = None, config: PlannerConfig | None = None) -> dict:
    """Run the benchmark and return its summary (see module docstring)."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    spec = spec or TurbineSpec()
    config = config or PlannerConfig()
    rows: dict[str, list[float]] = {k: [] for k in ("build", "plan", "cluster", "setup", "order", "path",
                                                    "end_to_end", "dp_phase1", "dp_all")}
    plan = None
    for rep in range(repeats + 1):
        t_build, turbine = _timed(build_turbine, spec)
        t_plan, plan = _timed(plan_inspection, turbine, config)
        surfaces, _ = cluster_surfaces(turbine, angle_deg=config.cluster_angle_deg)
        ends = np.stack([s.ends + config.standoff * offset_direction(s.normal, config.standoff_mode)
                         for s in surfaces])
        phase1 = plan.surface_phase == 1
        t_dp1, _ = _timed(HeldKarp, ends[phase1], plan.start)
        t_dp_all, _ = _timed(HeldKarp, ends, plan.start)
        if rep == 0:
            continue
        rows["build"].append(t_build)
        rows["plan"].append(t_plan)
        rows["end_to_end"].append(t_build + t_plan)
        for k in ("cluster", "setup", "order", "path"):
            rows[k].append(plan.timings[k])
        rows["dp_phase1"].append(t_dp1)
        rows["dp_all"].append(t_dp_all)
    med = {k: statistics.median(v) for k, v in rows.items()}
    chosen = []
    for rep in range(max(1, repeats // 2) + 1):
        t, _ = _timed(lambda: plan_inspection(build_turbine(TurbineSpec(**CHOSEN_TURN_SPEC)),
                                              PlannerConfig(rotor_turn_deg=None)))
        if rep:
            chosen.append(t)
    chosen_s = statistics.median(chosen)
    ref = reference_seconds()
    return {
        "benchmark": "planner",
        "repeats": repeats,
        "median_s": med,
        "max_s": {k: max(v) for k, v in rows.items()},
        "plan_time_s": med["plan"],
        "ordering_time_s": med["order"],
        "surfaces": plan.n_surfaces,
        "surfaces_phase1": int(np.sum(plan.surface_phase == 1)),
        "blade_triangles": plan.turbine_phase1.n_blade_triangles,
        "samples": int(len(plan.points)),
        "tour_length_m": plan.tour_length,
        "target_plan_s": TARGET_PLAN_S,
        "target_order_s": TARGET_ORDER_S,
        "chosen_turn_s": chosen_s,
        "reference_s": ref,
        "meets_targets": bool(med["end_to_end"] < TARGET_PLAN_S and med["order"] < TARGET_ORDER_S
                              and med["dp_all"] < TARGET_ORDER_S
                              and chosen_s < TARGET_CHOSEN_TURN_S),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def main(argv: list[str], prog: str = "wt-inspect bench planner") -> int:
    """``wt-inspect bench planner``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--repeats", type=int, default=7, help="timed repeats after one warm-up (7)")
    args = ap.parse_args(argv)
    try:
        out = run_bench(args.repeats)
    except ValueError as exc:
        print(f"{prog}: error: {exc}")
        return 2
    if args.json:
        print(json.dumps(out))
        return 0
    m = out["median_s"]
    ok = "meets" if out["meets_targets"] else "MISSES"
    print(f"planner, default turbine ({out['surfaces']} surfaces, {out['blade_triangles']} blade triangles, "
          f"{out['samples']} path samples); medians of {out['repeats']} repeats:")
    print(f"  end to end (mesh + plan) {m['end_to_end'] * 1e3:8.1f} ms   target < {TARGET_PLAN_S * 1e3:.0f} ms")
    print(f"    turbine mesh           {m['build'] * 1e3:8.1f} ms")
    print(f"    plan_inspection        {m['plan'] * 1e3:8.1f} ms")
    print(f"      clustering           {m['cluster'] * 1e3:8.1f} ms")
    print(f"      phases + clearance   {m['setup'] * 1e3:8.1f} ms")
    print(f"      exact ordering       {m['order'] * 1e3:8.1f} ms   target < {TARGET_ORDER_S * 1e3:.0f} ms")
    print(f"      path                 {m['path'] * 1e3:8.1f} ms")
    print(f"  Held-Karp alone, {out['surfaces_phase1']} surfaces {m['dp_phase1'] * 1e3:6.1f} ms, "
          f"all {out['surfaces']} surfaces {m['dp_all'] * 1e3:6.1f} ms")
    print(f"  NREL 5-MW, azimuth 70 deg, turns chosen  {out['chosen_turn_s'] * 1e3:8.1f} ms   "
          f"target < {TARGET_CHOSEN_TURN_S:.0f} s")
    ref = out["reference_s"]
    print(f"  in-run reference (NumPy closest points, 200k pairs) {ref * 1e3:.1f} ms: default turbine "
          f"{m['end_to_end'] / ref:.1f}x, chosen turns {out['chosen_turn_s'] / ref:.1f}x the reference")
    print(f"  -> {ok} the targets")
    return 0
