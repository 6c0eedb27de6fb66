"""``wt-inspect bench solver``: MPC time per control step, in closed loop on the surface task.

Every solver flies the same episode - the paper's turbine, one surface, the paper's 4 m/s gust,
the drone started 0.5 m (standard deviation) off its pose - through the evaluation harness's own
episode loop (:func:`wt_inspect.evaluation.runner.execute`), so what is timed is exactly the
``policy.act`` the evaluation measures. Per control step it reports, as medians over the steps
after ``--warmup``:

* ``latency`` - observation to command: the policy's own measurement of the part of ``act`` that
  needs the observation (``last_stats.latency_ms``; for the real-time iteration the feedback QP,
  plus the preparation when it is not done ahead);
* ``step`` - the whole ``act`` call (wall time, measured by the harness), what the control period
  must hold;
* both divided by a **reference** timed in the same run (:func:`reference_ms`: a fixed dense
  Riccati recursion of the QP's size in NumPy, timed between the solvers), so figures taken on a
  loaded or a faster machine can be compared by their ratio.

Solvers (all N = 30, as registered): ``rti_compiled`` (VT-NMPC, QP data from generated and
compiled C, HPIPM), ``rti_ahead`` (the same with ``prepare_ahead``: the next step's QP is prepared
at the predicted state after the command is returned, so the latency is the feedback QP alone),
``rti_hpipm`` / ``rti_hpipm_ahead`` (the same two with HPIPM called directly,
:mod:`controllers.hpipm_direct`, instead of through CasADi's plugin, and ``qp_mu0=1``),
``rti_predict`` (the latter with the QP solved in the preparation for the predicted state and
the feedback its tangential predictor: the full QP only when the active set changes),
``rti_uncompiled`` (the same, QP data by CasADi's virtual machine), ``ipopt``
(the VT-NMPC OCP solved to convergence every step, warm-started), ``vtnmpc_plus`` (VT-NMPC+, the
observer inside the timed step), ``nmpc`` and ``pampc`` (the paper's baselines, compiled RTI with
their own stage lengths), so the paper's ordering of cost per step (NMPC < VT-NMPC < PAMPC) is
measured, not assumed. The names resolved through the registry (``rti_compiled``, ``vtnmpc_plus``,
``nmpc``, ``pampc``) are the policies as the evaluation flies them, with the clearance constraint
(nearest mesh points looked up every step, one soft half-space per stage;
:mod:`controllers.rti_policy`); ``rti_no_clearance``, ``vtnmpc_plus_no_clearance`` and
``nmpc_no_clearance`` are the same without it, so its cost per step is the difference in one run.
The ``rti_*`` solver variants built here (``rti_ahead``, ``rti_hpipm``, ...) compare QP paths on
the VT-NMPC OCP without the constraint. ``vtnmpc_plus_filter`` is VT-NMPC+ flown through the
safety filter (:mod:`controllers.safety_filter`); its extra row is the filter's own time per step,
beside the reference and the VT-NMPC+ step of the same run. The compile time of the QP-data library
is measured separately, into a
fresh temporary cache so that it is a real compile.

``--acados-python PATH`` (the Python of a virtual environment with acados) adds the comparison
with the same OCP written in acados, alternating rounds on the same recorded observations, and
the ratio to IPOPT on them (:mod:`.acados_compare`).
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from typing import Any, Callable, Sequence

import numpy as np

from ..evaluation import registry
from ..evaluation.runner import execute, make_spec
from ..evaluation.scenarios import env_options

SCENARIO = "surface"
WIND = 4.0
START_NOISE = 0.5


def _vtnmpc_variant(**options: Any) -> Callable[[Any], Any]:
    """A VT-NMPC factory with solver options the registry's names do not carry (the benchmark
    compares solvers of one OCP, which is this module's own business)."""
    def build(env: Any) -> Any:
        from controllers.vtnmpc import VTNMPCPolicy
        return VTNMPCPolicy(params=env.params, d_ref=env.config.standoff, dt=env.dt, **options)
    return build


def _direct_hpipm(**options: Any) -> Any:
    """HPIPM called directly, with acados' initial barrier parameter (2 IPM iterations, not 3)."""
    from controllers.rti import RTIOptions
    return RTIOptions(qp_mode="speed_abs", qp_solver="hpipm", qp_mu0=1.0, **options)


def _without_clearance(kind: str) -> Callable[[Any], Any]:
    """A registered MPC built as its registry factory builds it, with ``clearance=False``."""
    def build(env: Any) -> Any:
        common = dict(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, clearance=False)
        if kind == "nmpc":
            from controllers.nmpc import NMPCPolicy
            return NMPCPolicy(**common)
        from controllers.vtnmpc import VTNMPC_PLUS, VTNMPCPolicy
        return VTNMPCPolicy(**common, **(VTNMPC_PLUS if kind == "vtnmpc_plus" else {}))
    return build


def _uncompiled(env: Any) -> Any:
    from controllers.rti import RTIOptions
    return _vtnmpc_variant(solver=RTIOptions(qp_mode="speed_abs", compiled=False))(env)


SOLVERS: dict[str, tuple[str, Callable[[], Callable[[Any], Any]]]] = {
    "rti_compiled": ("VT-NMPC, compiled RTI, with the clearance constraint (as registered)",
                     lambda: registry.resolve("vtnmpc")),
    "rti_no_clearance": ("VT-NMPC, compiled RTI, without the clearance constraint",
                         lambda: _without_clearance("vtnmpc")),
    "rti_ahead": ("VT-NMPC, compiled RTI, next step prepared after the command",
                  lambda: _vtnmpc_variant(prepare_ahead=True)),
    "rti_hpipm": ("VT-NMPC, compiled RTI, HPIPM called directly",
                  lambda: _vtnmpc_variant(solver=_direct_hpipm())),
    "rti_hpipm_ahead": ("VT-NMPC, HPIPM called directly, next step prepared after the command",
                        lambda: _vtnmpc_variant(solver=_direct_hpipm(), prepare_ahead=True)),
    "rti_predict": ("VT-NMPC, direct HPIPM, QP solved ahead, tangential predictor as feedback",
                    lambda: _vtnmpc_variant(solver=_direct_hpipm(tangential_predictor=True), prepare_ahead=True)),
    "rti_uncompiled": ("VT-NMPC, uncompiled QP data", lambda: _uncompiled),
    "ipopt": ("VT-NMPC OCP, IPOPT to convergence", lambda: _vtnmpc_variant(backend="ipopt")),
    "vtnmpc_plus": ("VT-NMPC+, compiled RTI, clearance", lambda: registry.resolve("vtnmpc-plus")),
    "vtnmpc_plus_no_clearance": ("VT-NMPC+, compiled RTI, without the clearance constraint",
                                 lambda: _without_clearance("vtnmpc_plus")),
    "nmpc": ("NMPC baseline, compiled RTI, clearance", lambda: registry.resolve("nmpc")),
    "nmpc_no_clearance": ("NMPC baseline, compiled RTI, without the clearance constraint",
                          lambda: _without_clearance("nmpc")),
    "pampc": ("PAMPC baseline, compiled RTI, clearance", lambda: registry.resolve("pampc")),
    "vtnmpc_plus_filter": ("VT-NMPC+ through the safety filter (filter row: the filter's own time)",
                           lambda: registry.resolve("vtnmpc-plus+filter")),
}


def reference_ms(repeats: int = 200, horizon: int = 30, nx: int = 10, nu: int = 4) -> float:
    """Median time [ms] of a fixed backward Riccati recursion (the core of a structured QP
    solve, ``horizon`` stages of ``nx`` states and ``nu`` inputs) in NumPy: a machine-speed
    yardstick timed in the same run as the solvers, not a solver."""
    rng = np.random.default_rng(0)
    A = np.eye(nx) + 0.01 * rng.standard_normal((nx, nx))
    B = 0.01 * rng.standard_normal((nx, nu))
    Q, R = np.eye(nx), np.eye(nu)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        P = Q.copy()
        for _k in range(horizon):
            BtP = B.T @ P
            K = np.linalg.solve(R + BtP @ B, BtP @ A)
            P = Q + A.T @ P @ A - (BtP @ A).T @ K
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def _latencies(result: Any) -> np.ndarray:
    return np.asarray(result.arrays["latency_ms"], dtype=float)[:-1]


def _summary(values: np.ndarray) -> dict[str, float]:
    v = values[np.isfinite(values)]
    return {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99)),
            "max_ms": float(np.max(v))}


def acados_spec(steps: int) -> Any:
    """The episode whose observations the acados comparison replays (the bench's task)."""
    opts = env_options(SCENARIO, WIND, overrides={"start_noise": START_NOISE})
    return make_spec(SCENARIO, "bench-acados-record", WIND, 0, opts, max_time=(steps + 1) * 0.01, custom=True)


def run_benchmark(steps: int = 500, warmup: int = 20,
                  solvers: Sequence[str] = ("rti_compiled", "rti_uncompiled", "ipopt")) -> dict[str, Any]:
    """Closed-loop timing of each solver on the same episode; see the module docstring."""
    unknown = [s for s in solvers if s not in SOLVERS]
    if unknown:
        raise ValueError(f"unknown solver {unknown[0]!r}; valid: {', '.join(SOLVERS)}")
    if steps < 1 or warmup < 0:
        raise ValueError(f"steps must be >= 1 and warmup >= 0, got {steps}, {warmup}")
    from controllers.rti import RTIOptions
    opts = env_options(SCENARIO, WIND, overrides={"start_noise": START_NOISE})
    results: dict[str, Any] = {"setup": {"scenario": SCENARIO, "wind": WIND, "start_noise": START_NOISE,
                                         "steps": steps, "warmup": warmup, "machine": platform.processor()
                                         or platform.machine()}}
    refs = [reference_ms()]
    with tempfile.TemporaryDirectory() as tmp:   # a real compile, not a cache hit
        spec = make_spec(SCENARIO, "compile", WIND, 0, opts, max_time=0.01, custom=True)
        t0 = time.perf_counter()
        res = execute(spec, _vtnmpc_variant(solver=RTIOptions(qp_mode="speed_abs", cache_dir=tmp)), record=False)
        results["compile"] = {"setup_and_one_step_s": time.perf_counter() - t0, "steps": res.steps}
    for name in solvers:
        factory = SOLVERS[name][1]()
        built: dict[str, float] = {}

        def timed_factory(env: Any, factory: Callable[[Any], Any] = factory,
                          built: dict[str, float] = built) -> Any:
            t0 = time.perf_counter()
            policy = factory(env)
            built["setup_s"] = time.perf_counter() - t0
            return policy

        dt = 0.01
        spec = make_spec(SCENARIO, f"bench-{name}", WIND, 0, opts, max_time=(steps + warmup) * dt, custom=True)
        res = execute(spec, timed_factory, record=True)
        step_ms = np.asarray(res.arrays["act_ms"], dtype=float)[:-1][warmup:]
        latency = _latencies(res)[warmup:]
        entry: dict[str, Any] = {"description": SOLVERS[name][0], "steps": int(step_ms.size),
                                 "setup_s": built.get("setup_s", float("nan")),
                                 "step": _summary(step_ms), "latency": _summary(latency),
                                 "coverage": res.metrics.get("coverage"), "safety": res.metrics.get("safety_sm")}
        if "filter_median_ms" in res.solve:     # a filtered policy: the filter's own time per step
            entry["filter"] = {"median_ms": res.solve["filter_median_ms"], "p99_ms": res.solve["filter_p99_ms"]}
        results[name] = entry
        refs.append(reference_ms())
    ref = statistics.median(refs)
    results["reference"] = {"median_ms": ref, "what": "NumPy Riccati recursion, N=30, nx=10, nu=4"}
    for name in solvers:
        e = results[name]
        e["step_ratio_vs_reference"] = e["step"]["median_ms"] / ref
        e["latency_ratio_vs_reference"] = e["latency"]["median_ms"] / ref
        if "filter" in e:
            e["filter"]["ratio_vs_reference"] = e["filter"]["median_ms"] / ref
            if "vtnmpc_plus" in results:
                e["filter"]["ratio_vs_vtnmpc_plus_step"] = e["filter"]["median_ms"] / results["vtnmpc_plus"]["step"][
                    "median_ms"]
    return results


def main(argv: list[str] | None = None, prog: str = "wt-inspect bench solver") -> int:
    """``wt-inspect bench solver``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--steps", type=int, default=500, help="timed steps per solver (default 500)")
    parser.add_argument("--warmup", type=int, default=20, help="untimed first steps (default 20)")
    parser.add_argument("--solvers", default="rti_compiled,rti_no_clearance,rti_ahead,rti_hpipm,rti_hpipm_ahead,"
                        "rti_predict,"
                        "rti_uncompiled,ipopt,vtnmpc_plus,vtnmpc_plus_no_clearance,nmpc,nmpc_no_clearance,pampc,"
                        "vtnmpc_plus_filter",
                        help="comma-separated subset of " + ", ".join(SOLVERS))
    parser.add_argument("--acados-python", default=None, metavar="PATH",
                        help="the Python of a virtual environment with acados (comma-deps-acados): also time "
                             "the same OCP in acados, alternating rounds on the same observations")
    parser.add_argument("--acados-rounds", type=int, default=3, help="alternating rounds with acados (default 3)")
    args = parser.parse_args(argv)
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    try:
        if args.acados_python:
            from .acados_compare import check_python
            check_python(args.acados_python)
        results = run_benchmark(steps=args.steps, warmup=args.warmup, solvers=solvers)
        if args.acados_python:
            from .acados_compare import compare
            results["acados"] = compare(args.acados_python, acados_spec(args.steps + args.warmup),
                                        args.steps, args.warmup, args.acados_rounds)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    ref = results["reference"]["median_ms"]
    print(f"closed loop on the {SCENARIO} task, {WIND:g} m/s gust, {args.steps} steps after {args.warmup} "
          f"warm-up; medians per control step [ms]; reference {ref:.4f} ms ({results['reference']['what']})")
    print(f"{'solver':<26}{'latency':>9}{'p99':>8}{'step':>9}{'p99':>8}{'lat/ref':>9}{'step/ref':>9}  what")
    for name in solvers:
        r = results[name]
        print(f"{name:<26}{r['latency']['median_ms']:9.3f}{r['latency']['p99_ms']:8.3f}"
              f"{r['step']['median_ms']:9.3f}{r['step']['p99_ms']:8.3f}"
              f"{r['latency_ratio_vs_reference']:9.1f}{r['step_ratio_vs_reference']:9.1f}  {r['description']}")
        if "filter" in r:
            f = r["filter"]
            vs = (f"; {f['ratio_vs_vtnmpc_plus_step']:.2f}x the VT-NMPC+ step" if "ratio_vs_vtnmpc_plus_step" in f
                  else "")
            print(f"{'  filter alone':<26}{'':>9}{'':>8}{f['median_ms']:9.3f}{f['p99_ms']:8.3f}{'':>9}"
                  f"{f['ratio_vs_reference']:9.1f}  the safety filter's own time per step{vs}")
    print("latency = observation to command (the policy's own measurement); step = the whole act() call")
    ranked = [n for n in ("nmpc", "rti_compiled", "pampc") if n in results]
    if len(ranked) > 1:
        order = sorted(ranked, key=lambda n: results[n]["step"]["median_ms"])
        print("measured order of median cost per step: " + " < ".join(
            f"{'vtnmpc' if n == 'rti_compiled' else n} ({results[n]['step']['median_ms']:.3f})" for n in order))
    print(f"QP-data library: set-up with a fresh compile {results['compile']['setup_and_one_step_s']:.2f} s "
          "(then cached)")
    if "acados" in results:
        from .acados_compare import print_comparison
        print()
        print_comparison(results["acados"])
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
