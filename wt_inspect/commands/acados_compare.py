"""The VT-NMPC control step against the same OCP in acados (``wt-inspect bench solver --acados-python``).

acados needs its own virtual environment (its wheel vendors another CasADi), so its side runs in a
child process with that environment's Python: :mod:`.peer_acados`, which imports nothing from this
project and receives the problem as numbers (:func:`ocp_spec`: horizon, step, mass, gravity,
stand-off, norm guard, the solver's scaled weights, input bounds, hover, QP mode, tolerance and
iteration limit).

What is timed, on the same inputs for both: one episode of the bench's task is flown once with the
VT-NMPC without the clearance constraint (the harness's own episode loop) and its observations are
recorded; then, in ``rounds`` alternating rounds, the recorded observations are replayed through

* ours: a fresh VT-NMPC policy (default solver configuration, no clearance constraint), ``act``
  per observation - observation check, state, parameters, preparation, feedback, shift, action;
* acados: the same OCP, one SQP-RTI step per observation (state and parameters from the
  observation in Python, one compiled update call, ``solve``, the action) - the same work;
* ours with the clearance constraint (the registered policy, with the mission's turbine), whose
  difference to the first is the constraint's own cost.

Replaying a policy's own observations reproduces its closed loop exactly (it is deterministic),
and acados' commands agree with ours to the QP tolerance (reported as the largest action
difference), so both solve the same sequence of problems. After the rounds the same observations go
once through the OCP solved to convergence by IPOPT (warm-started), for the ratio to IPOPT.
Medians and p99 are over the steps after the warm-up, per round; the figures reported are the
medians over rounds, and each ratio is formed within a round first.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

PEER = Path(__file__).with_name("peer_acados.py")
OBS_FOR_PEER = ("position", "velocity_body", "quaternion", "point", "normal", "point_velocity")


def ocp_spec(policy: Any) -> dict[str, Any]:
    """The numbers that define a plain VT-NMPC policy's OCP, for the peer (ValueError for a
    variant the peer does not write out: observer, camera heading, chord residual, clearance,
    several RK4 steps per stage, a path constraint)."""
    from controllers.vtnmpc import VTNMPCPolicy
    from wt_inspect_env.physics.quadrotor import GRAVITY
    if not isinstance(policy, VTNMPCPolicy):
        raise ValueError(f"the acados peer writes out the VT-NMPC only, got {type(policy).__name__}")
    c = policy.config
    if (c.disturbance_observer or c.heading_model != "body" or c.heading_residual != "paper"
            or c.rk4_steps != 1 or policy.clearance_active or policy.ocp.nh or c.backend != "rti"):
        raise ValueError("the acados peer writes out the paper's VT-NMPC (body heading, paper residual, "
                         "no observer, one RK4 step, no clearance constraint, RTI)")
    ocp, solver = policy.ocp, policy.solver
    return {"horizon": ocp.horizon, "dt": ocp.dt, "mass": c.params.mass, "gravity": GRAVITY,
            "d_ref": c.d_ref, "eps": c.norm_eps,
            "stage_weights": solver.stage_weights.tolist(), "terminal_weights": solver.terminal_weights.tolist(),
            "u_lower": np.asarray(ocp.u_lower, float).tolist(), "u_upper": np.asarray(ocp.u_upper, float).tolist(),
            "hover": np.asarray(ocp.fallback_input, float).tolist(),
            "qp_mode": c.solver.qp_mode, "qp_tol": c.solver.qp_tol, "qp_iter_max": c.solver.qp_iter_max}


def check_python(python: str) -> None:
    """ValueError unless ``python`` is an executable file (checked before anything is flown)."""
    if not (os.path.isfile(python) and os.access(python, os.X_OK)):
        raise ValueError(f"--acados-python {python!r} is not an executable file")


def run_peer(python: str, request: Mapping[str, Any], timeout: float = 900.0) -> dict[str, Any]:
    """Run :mod:`.peer_acados` with ``python`` on ``request``; its JSON result (ValueError with the
    last line of its error output when it fails)."""
    with tempfile.TemporaryDirectory(prefix="wt-acados-io-") as tmp:
        req, res = Path(tmp, "request.json"), Path(tmp, "result.json")
        req.write_text(json.dumps(request), encoding="utf-8")
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
        try:
            proc = subprocess.run([python, str(PEER), str(req), str(res)], capture_output=True, text=True,
                                  timeout=timeout, env=env)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise ValueError(f"--acados-python {python!r} could not run: {exc}") from None
        if proc.returncode != 0 or not res.exists():
            lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()] or ["no output"]
            raise ValueError(f"--acados-python {python!r} failed: {lines[-1][:300]}")
        return json.loads(res.read_text(encoding="utf-8"))


def _plain_vtnmpc(env: Any, **options: Any) -> Any:
    from controllers.vtnmpc import VTNMPCPolicy
    return VTNMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, clearance=False,
                        **options)


def record(spec: Any, steps: int) -> tuple[list[dict[str, np.ndarray]], dict[str, Callable[[], Any]]]:
    """Fly ``spec`` with the plain VT-NMPC; its observations (copies, as the env gave them) and
    builders of fresh policies for the same env: ``plain``, ``clearance`` (as registered, with the
    mission's turbine), ``ipopt``."""
    from ..evaluation import registry
    from ..evaluation.runner import execute
    observations: list[dict[str, np.ndarray]] = []
    builders: dict[str, Callable[[], Any]] = {}

    def factory(env: Any) -> Any:
        policy = _plain_vtnmpc(env)
        inner = policy.act

        def act(obs: Mapping[str, Any]) -> np.ndarray:
            if len(observations) < steps:
                observations.append({k: np.array(v, copy=True) for k, v in obs.items()})
            return inner(obs)

        policy.act = act
        vtnmpc = registry.resolve("vtnmpc")
        builders.update(plain=lambda: _plain_vtnmpc(env), clearance=lambda: vtnmpc(env),
                        ipopt=lambda: _plain_vtnmpc(env, backend="ipopt"))
        return policy

    execute(spec, factory, record=False)
    if len(observations) < steps:
        raise ValueError(f"the recorded episode ended after {len(observations)} of {steps} steps")
    return observations, builders


def replay(policy: Any, observations: list[dict[str, np.ndarray]],
           stats: list[tuple[float, float, int]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-step wall time [ms] of ``policy.act`` over ``observations`` and the actions; ``stats``
    (a list) receives (preparation [ms], feedback QP [ms], QP iterations) of every step."""
    policy.reset()
    times, actions = np.empty(len(observations)), np.empty((len(observations), 4))
    clock = time.perf_counter
    for i, obs in enumerate(observations):
        t0 = clock()
        actions[i] = policy.act(obs)
        times[i] = (clock() - t0) * 1e3
        if stats is not None:
            st = policy.last_stats
            stats.append((st.prepare_ms, st.feedback_ms, st.qp_iterations))
    return times, actions


def _summary(v: np.ndarray) -> dict[str, float]:
    return {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99)), "max_ms": float(np.max(v))}


def compare(python: str, spec: Any, steps: int = 500, warmup: int = 20, rounds: int = 3,
            ipopt: bool = True) -> dict[str, Any]:
    """The comparison of the module docstring; a JSON-ready dict."""
    if rounds < 1:
        raise ValueError(f"--acados-rounds must be positive, got {rounds}")
    observations, build = record(spec, steps + warmup)
    ours = build["plain"]()
    ocp = ocp_spec(ours)
    peer_obs = {k: [o[k].tolist() for o in observations] for k in OBS_FOR_PEER}
    out: dict[str, Any] = {"steps": steps, "warmup": warmup, "rounds": []}
    with tempfile.TemporaryDirectory(prefix="wt-acados-build-") as build_dir:
        t0 = time.perf_counter()
        run_peer(python, {"mode": "build", "ocp": ocp, "build_dir": build_dir})
        out["acados_build_s"] = time.perf_counter() - t0
        clearance = build["clearance"]()
        for _ in range(rounds):
            qp: list[tuple[float, float, int]] = []
            t_ours, a_ours = replay(ours, observations, qp)
            peer = run_peer(python, {"mode": "replay", "ocp": ocp, "build_dir": build_dir,
                                     "observations": peer_obs})
            t_cl, _ = replay(clearance, observations)
            t_ac = np.asarray(peer["step_ms"], dtype=float)
            a_ac = np.asarray(peer["actions"], dtype=float)
            w = slice(warmup, None)
            r = {"ours": _summary(t_ours[w]), "acados": _summary(t_ac[w]), "ours_clearance": _summary(t_cl[w]),
                 "max_action_diff": float(np.max(np.abs(a_ours - a_ac))),
                 "acados_nonzero_status": int(np.count_nonzero(peer["status"]))}
            r["ratio_median"] = r["ours"]["median_ms"] / r["acados"]["median_ms"]
            r["ratio_p99"] = r["ours"]["p99_ms"] / r["acados"]["p99_ms"]
            r["clearance_cost_ms"] = r["ours_clearance"]["median_ms"] - r["ours"]["median_ms"]
            q = np.asarray(qp, dtype=float)[w]
            r["ours_qp_ms"], r["ours_prepare_ms"] = float(np.median(q[:, 1])), float(np.median(q[:, 0]))
            r["ours_qp_iterations"] = float(np.mean(q[:, 2]))
            r["acados_qp_ms"] = float(np.median(np.asarray(peer["qp_ms"], dtype=float)[w]))
            r["acados_qp_iterations"] = float(np.mean(np.asarray(peer["qp_iterations"], dtype=float)[w]))
            out["rounds"].append(r)
    R = out["rounds"]

    def med(*path: str) -> float:
        vals = []
        for r in R:
            v: Any = r
            for p in path:
                v = v[p]
            vals.append(v)
        return float(statistics.median(vals))

    for who in ("ours", "acados", "ours_clearance"):
        out[who] = {"median_ms": med(who, "median_ms"), "p99_ms": med(who, "p99_ms")}
    out["ratio_ours_over_acados"] = {"median": med("ratio_median"), "p99": med("ratio_p99")}
    out["clearance_cost_ms"] = med("clearance_cost_ms")
    for key in ("ours_qp_ms", "ours_prepare_ms", "ours_qp_iterations", "acados_qp_ms", "acados_qp_iterations"):
        out[key] = med(key)
    out["max_action_diff"] = max(r["max_action_diff"] for r in R)
    if ipopt:
        t_ip, _ = replay(build["ipopt"](), observations)
        out["ipopt"] = _summary(t_ip[warmup:])
        out["ratio_ipopt_over_ours"] = out["ipopt"]["median_ms"] / out["ours"]["median_ms"]
    return out


def print_comparison(c: Mapping[str, Any]) -> None:
    """The comparison as the command prints it."""
    print(f"VT-NMPC against the same OCP in acados: {c['steps']} recorded observations after {c['warmup']} "
          f"warm-up, {len(c['rounds'])} alternating rounds, clearance constraint off on both; "
          "step = observation to normalised action [ms]")
    print(f"{'round':<8}{'ours':>8}{'p99':>8}{'acados':>8}{'p99':>8}{'ratio':>7}{'p99':>7}"
          f"{'+clear.':>9}{'p99':>8}  max |action diff|")
    for i, r in enumerate(c["rounds"], 1):
        print(f"{i:<8}{r['ours']['median_ms']:8.3f}{r['ours']['p99_ms']:8.3f}{r['acados']['median_ms']:8.3f}"
              f"{r['acados']['p99_ms']:8.3f}{r['ratio_median']:7.2f}{r['ratio_p99']:7.2f}"
              f"{r['ours_clearance']['median_ms']:9.3f}{r['ours_clearance']['p99_ms']:8.3f}"
              f"  {r['max_action_diff']:.1e}")
    ratio = c["ratio_ours_over_acados"]
    print(f"median over rounds: ours {c['ours']['median_ms']:.3f} ms (p99 {c['ours']['p99_ms']:.3f}), acados "
          f"{c['acados']['median_ms']:.3f} ms (p99 {c['acados']['p99_ms']:.3f}); ours/acados {ratio['median']:.2f}x "
          f"(p99 {ratio['p99']:.2f}x)")
    print(f"of which the QP (feedback): ours {c['ours_qp_ms']:.3f} ms, acados (time_qp) {c['acados_qp_ms']:.3f} ms, "
          f"mean IPM iterations {c['ours_qp_iterations']:.2f} / {c['acados_qp_iterations']:.2f}; our preparation "
          f"{c['ours_prepare_ms']:.3f} ms")
    print(f"ours with the clearance constraint: {c['ours_clearance']['median_ms']:.3f} ms (p99 "
          f"{c['ours_clearance']['p99_ms']:.3f}), the constraint's own cost {c['clearance_cost_ms']:+.3f} ms")
    if "ipopt" in c:
        print(f"IPOPT to convergence on the same observations: {c['ipopt']['median_ms']:.2f} ms "
              f"(p99 {c['ipopt']['p99_ms']:.2f}); IPOPT/ours {c['ratio_ipopt_over_ours']:.1f}x")
    print(f"acados solver generated and compiled in {c['acados_build_s']:.1f} s")
