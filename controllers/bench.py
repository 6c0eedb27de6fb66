"""``wt-inspect bench solver``: MPC time per control step, in closed loop over a surface pass.

Compares on the same VT-NMPC problem (N = 30, dt = 0.01 s):

* ``rti_compiled``   - real-time iteration, QP data from generated + compiled C, HPIPM;
* ``rti_uncompiled`` - the same, QP data evaluated by CasADi's SX virtual machine;
* ``ipopt``          - CasADi + IPOPT solved to convergence, warm-started (primal and dual);
* ``vtnmpc_plus`` - VT-NMPC+ (:data:`controllers.vtnmpc.VTNMPC_PLUS`: observer, camera heading,
  chord heading residual), compiled RTI; the observer update is inside the timed step;
* ``nmpc``, ``pampc`` - the paper's baselines (:mod:`controllers.nmpc`, :mod:`controllers.pampc`),
  compiled RTI with their own stage lengths (PAMPC: 0.1 s stages, commanded every 0.01 s), so the
  paper's ordering of cost per step (NMPC < VT-NMPC < PAMPC) is measured, not assumed.

Each runs hundreds of control steps in closed loop on the CasADi model itself (RK4 at fine steps,
with optional rotor-drag wind), following an inspection point that moves along a straight surface;
the first steps are warm-up and excluded. The compile time of the QP-data library is measured
separately (into a fresh temporary cache, so it is a real compile).

This module also holds the closed-loop harness used by the controller tests
(:class:`SurfacePass`, :class:`ModelPlant`, :func:`run_closed_loop`). The plant only needs
``reset(state)``, ``step(command)`` and a ``state`` property, so the PyBullet simulator
(:class:`wt_inspect_env.sim.QuadrotorSim`) can be passed instead of :class:`ModelPlant`.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from wt_inspect_env.dynamics import QuadrotorModel, quat_to_rotmat_np
from wt_inspect_env.quadrotor import QuadrotorParams, get_preset
from wt_inspect_env.spaces import ActionScaling
from wt_inspect_env.validation import check_array, check_positive

# ------------------------------------------------------------------------------------------------
# closed-loop harness
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SurfacePass:
    """An inspection point moving at constant ``speed`` along a straight surface.

    ``normal`` is the surface's outward normal (horizontal for a blade's side face), ``direction``
    the point's direction of travel (orthogonal to the normal), ``start`` its position at t = 0.
    """

    start: tuple[float, float, float] = (0.0, 0.0, 30.0)
    normal: tuple[float, float, float] = (0.0, -1.0, 0.0)
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    speed: float = 0.7

    def __post_init__(self) -> None:
        check_array("start", self.start, (3,))
        n = check_array("normal", self.normal, (3,))
        d = check_array("direction", self.direction, (3,))
        check_positive("speed", self.speed, allow_zero=True)
        if abs(np.linalg.norm(n) - 1) > 1e-9 or abs(np.linalg.norm(d) - 1) > 1e-9:
            raise ValueError("normal and direction must be unit vectors")
        if abs(float(n @ d)) > 1e-9:
            raise ValueError("direction must be orthogonal to the normal")

    def point(self, t: float) -> np.ndarray:
        return np.asarray(self.start) + self.speed * t * np.asarray(self.direction)

    def velocity(self, t: float = 0.0) -> np.ndarray:
        return self.speed * np.asarray(self.direction, dtype=float)

    def ideal_state(self, t: float, d_ref: float) -> np.ndarray:
        """Where the VT-NMPC should be: p + d_ref n, level, facing the point."""
        from .vtnmpc import ideal_state
        return ideal_state(self.point(t), self.normal, d_ref)


class ModelPlant:
    """The shared CasADi model integrated with RK4 at ``substeps`` per control step: a stand-in
    for the PyBullet simulator with the same ``reset``/``step``/``state`` interface.

    The plant has the linear rotor drag of the parameters, F_B = -D (v_B - R^T v_wind), which
    the controllers' model (like the paper's) does not know; ``wind(t, positions) -> velocities``
    (world) sets the air velocity (still air without it).
    """

    def __init__(self, params: QuadrotorParams, dt: float = 0.01, substeps: int = 10,
                 wind: Callable[[float, np.ndarray], np.ndarray] | None = None) -> None:
        self.params = params
        self.dt = check_positive("dt", dt)
        self._model = QuadrotorModel(params)
        import casadi as ca
        x = ca.SX.sym("x", 10)
        u = ca.SX.sym("u", 4)
        a = ca.SX.sym("a", 3)
        self._F = ca.Function("plant", [x, u, a],
                              [self._model.rk4_expr(x, u, dt, a_ext=a, steps=substeps)])
        self.wind = wind
        self._drag = np.diag(params.rotor_drag)
        self.t = 0.0
        self._state = np.zeros(10)

    @property
    def state(self) -> np.ndarray:
        return self._state.copy()

    def reset(self, state: np.ndarray) -> np.ndarray:
        self._state = check_array("state", state, (10,)).copy()
        self.t = 0.0
        return self.state

    def disturbance_accel(self) -> np.ndarray:
        """World-frame acceleration from rotor drag relative to the air at the current state."""
        x = self._state
        R = quat_to_rotmat_np(x[6:10])
        v_wind = np.zeros(3) if self.wind is None else \
            np.asarray(self.wind(self.t, x[None, 0:3]), dtype=float)[0]
        f_body = -self._drag @ (x[3:6] - R.T @ v_wind)
        return R @ f_body / self.params.mass

    def step(self, command: np.ndarray) -> np.ndarray:
        a = self.disturbance_accel()  # held over the step (drag changes slowly)
        xn = np.asarray(self._F(self._state, command, a)).ravel()
        xn[6:10] /= np.linalg.norm(xn[6:10])
        self._state = xn
        self.t += self.dt
        return self.state


def make_observation(state: np.ndarray, point: np.ndarray, normal: np.ndarray,
                     point_velocity: np.ndarray) -> dict[str, np.ndarray]:
    """An environment-style observation (float32, keys of ``OBS_KEYS``) for a model state."""
    f32 = lambda v: np.asarray(v, dtype=np.float32)  # noqa: E731
    return {
        "position": f32(state[0:3]), "velocity_body": f32(state[3:6]),
        "quaternion": f32(state[6:10]), "body_rates": f32(np.zeros(3)),
        "point": f32(point), "normal": f32(normal), "point_velocity": f32(point_velocity),
        "coverage": f32([0.0]), "progress": f32([0.0]),
    }


def inspection_geometry(state: np.ndarray, point: np.ndarray, normal: np.ndarray) -> tuple[float, float]:
    """(horizontal distance d, heading h) of a state to a point, as the paper defines them."""
    a = np.asarray(point) - state[0:3]
    d = float(np.hypot(a[0], a[1]))
    bx = quat_to_rotmat_np(state[6:10])[:, 0]
    h = float((bx[0] * a[0] + bx[1] * a[1]) / max(d, 1e-9))
    return d, h


@dataclass
class ClosedLoopResult:
    """Trajectories and per-step records of one closed-loop run."""

    states: np.ndarray
    commands: np.ndarray
    distance: np.ndarray
    heading: np.ndarray
    step_ms: np.ndarray
    qp_iterations: np.ndarray
    fallbacks: int
    statuses: list[str] = field(default_factory=list)
    feedback_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def safety_metric(self, d_ref: float, margin: float = 1.0, start: int = 0) -> float:
        """Share of steps with |d - d_ref| < margin (the paper's SM)."""
        d = self.distance[start:]
        return float(np.mean(np.abs(d - d_ref) < margin))


def run_closed_loop(policy: Any, plant: Any, scenario: SurfacePass, steps: int,
                    initial_state: np.ndarray, scaling: ActionScaling,
                    dt: float = 0.01) -> ClosedLoopResult:
    """Run ``policy`` (``act(obs) -> normalised action``) on ``plant`` for ``steps`` control
    steps of ``dt``; the step time is the wall time of ``act``."""
    policy.reset()
    plant.reset(np.asarray(initial_state, dtype=float))
    state = plant.state
    states, commands, dist, head, times, iters, fb_ms = [state], [], [], [], [], [], []
    statuses: list[str] = []
    fallbacks = 0
    normal = np.asarray(scenario.normal, dtype=float)
    for k in range(steps):
        t = k * dt
        point = scenario.point(t)
        obs = make_observation(state, point, normal, scenario.velocity(t))
        d, h = inspection_geometry(state, point, normal)
        dist.append(d)
        head.append(h)
        t0 = time.perf_counter()
        action = policy.act(obs)
        times.append((time.perf_counter() - t0) * 1e3)
        st = getattr(policy, "last_stats", None)
        if st is not None:
            iters.append(st.qp_iterations)
            fb_ms.append(st.feedback_ms)
            statuses.append(st.status)
            fallbacks += int(st.fallback)
        command = scaling.to_command(action)
        plant.step(command)
        state = plant.state
        if not np.all(np.isfinite(state)):
            raise RuntimeError(f"plant state became non-finite at step {k}")
        states.append(state)
        commands.append(command)
    return ClosedLoopResult(np.array(states), np.array(commands), np.array(dist), np.array(head),
                            np.array(times), np.array(iters), fallbacks, statuses,
                            np.array(fb_ms))


def offset_start(scenario: SurfacePass, d_ref: float, offset: Sequence[float] = (0.5, -1.0, 0.5),
                 yaw_error_deg: float = 15.0) -> np.ndarray:
    """A start state displaced from the ideal pose by ``offset`` (m, world) and a yaw error."""
    x = scenario.ideal_state(0.0, d_ref)
    x[0:3] += np.asarray(offset, dtype=float)
    yaw = 2 * np.arctan2(x[8], x[9]) + np.deg2rad(yaw_error_deg)
    x[6:10] = [0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)]
    return x


# ------------------------------------------------------------------------------------------------
# the benchmark
# ------------------------------------------------------------------------------------------------


def _summary(times_ms: np.ndarray) -> dict[str, float]:
    return {
        "median_ms": float(np.median(times_ms)),
        "p95_ms": float(np.percentile(times_ms, 95)),
        "p99_ms": float(np.percentile(times_ms, 99)),
        "max_ms": float(np.max(times_ms)),
        "mean_ms": float(np.mean(times_ms)),
    }


def run_benchmark(steps: int = 500, warmup: int = 20, horizon: int = 30,
                  solvers: Sequence[str] = ("rti_compiled", "rti_uncompiled", "ipopt"),
                  preset: str = "matrice100") -> dict[str, dict[str, Any]]:
    """Closed-loop timing of each solver on the same scenario; see the module docstring."""
    from .nmpc import NMPCConfig, NMPCPolicy
    from .pampc import PAMPCConfig, PAMPCPolicy
    from .rti import RTIOptions
    from .vtnmpc import VTNMPC_PLUS, VTNMPCConfig, VTNMPCPolicy

    # the paper's baselines (compiled RTI, their own weights and stage lengths, same N)
    BASELINES = {"nmpc": (NMPCConfig, NMPCPolicy), "pampc": (PAMPCConfig, PAMPCPolicy)}

    params = get_preset(preset)
    scenario = SurfacePass()
    results: dict[str, dict[str, Any]] = {}

    # compile time: a real compile into a fresh cache directory
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        pol = VTNMPCPolicy(VTNMPCConfig(params=params, horizon=horizon,
                                        solver=RTIOptions(qp_mode="speed_abs", cache_dir=tmp)))
        total = time.perf_counter() - t0
        results["compile"] = {"compile_s": pol.solver.qp_data.compile_seconds,
                              "setup_total_s": total, "compiled": pol.solver.qp_data.compiled}
        del pol

    for name in solvers:
        if name == "rti_compiled":
            cfg = VTNMPCConfig(params=params, horizon=horizon)
        elif name == "rti_uncompiled":
            cfg = VTNMPCConfig(params=params, horizon=horizon,
                               solver=RTIOptions(qp_mode="speed_abs", compiled=False))
        elif name == "ipopt":
            cfg = VTNMPCConfig(params=params, horizon=horizon, backend="ipopt")
        elif name == "vtnmpc_plus":
            cfg = VTNMPCConfig(params=params, horizon=horizon, **VTNMPC_PLUS)
        elif name in BASELINES:
            cfg = BASELINES[name][0](params=params, horizon=horizon)
        else:
            raise ValueError(f"unknown solver {name!r}")
        policy_cls = BASELINES[name][1] if name in BASELINES else VTNMPCPolicy
        control_dt = getattr(cfg, "control_dt", cfg.dt)  # PAMPC: 0.1 s stages, 0.01 s control
        t0 = time.perf_counter()
        policy = policy_cls(cfg)
        setup = time.perf_counter() - t0
        plant = ModelPlant(params, dt=control_dt)
        x0 = offset_start(scenario, cfg.d_ref)
        res = run_closed_loop(policy, plant, scenario, steps + warmup, x0, cfg.scaling, control_dt)
        times = res.step_ms[warmup:]
        entry: dict[str, Any] = _summary(times)
        entry.update({
            "steps": int(times.size), "setup_s": setup,
            "feedback_median_ms": float(np.median(res.feedback_ms[warmup:])),
            "qp_iterations_median": float(np.median(res.qp_iterations[warmup:])),
            "fallbacks": res.fallbacks,
            "final_distance_error_m": float(abs(res.distance[-1] - cfg.d_ref)),
            "final_heading": float(res.heading[-1]),
        })
        results[name] = entry

    base = results.get("rti_compiled")
    if base is not None:
        for name in solvers:
            if name != "rti_compiled" and name in results:
                results[name]["median_ratio_vs_rti_compiled"] = \
                    results[name]["median_ms"] / base["median_ms"]
    return results


def main(argv: list[str] | None = None, prog: str = "wt-inspect bench solver") -> int:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--steps", type=int, default=500, help="timed steps per solver")
    parser.add_argument("--warmup", type=int, default=20, help="untimed first steps")
    parser.add_argument("--horizon", type=int, default=30)
    parser.add_argument("--solvers", default="rti_compiled,rti_uncompiled,ipopt,vtnmpc_plus,nmpc,pampc",
                        help="comma-separated subset of rti_compiled, rti_uncompiled, ipopt "
                             "(VT-NMPC), vtnmpc_plus (VT-NMPC+) and nmpc, pampc (the baselines, compiled RTI)")
    args = parser.parse_args(argv)
    try:
        if args.steps < 1 or args.warmup < 0:
            raise ValueError(f"steps must be >= 1 and warmup >= 0, got {args.steps}, {args.warmup}")
        solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
        results = run_benchmark(steps=args.steps, warmup=args.warmup, horizon=args.horizon,
                                solvers=solvers)
    except ValueError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    comp = results.pop("compile")
    print(f"VT-NMPC (and the nmpc/pampc baselines), N = {args.horizon}, closed loop over a surface pass, "
          f"{args.steps} steps after {args.warmup} warm-up (times per control step, ms)")
    print(f"{'solver':<16}{'median':>9}{'p95':>9}{'p99':>9}{'max':>9}{'feedbk':>9}{'iter':>6}"
          f"{'fallbk':>8}{'x median':>10}")
    for name, r in results.items():
        ratio = r.get("median_ratio_vs_rti_compiled", 1.0)
        print(f"{name:<16}{r['median_ms']:9.3f}{r['p95_ms']:9.3f}{r['p99_ms']:9.3f}"
              f"{r['max_ms']:9.3f}{r['feedback_median_ms']:9.3f}{r['qp_iterations_median']:6.0f}"
              f"{r['fallbacks']:8d}{ratio:10.1f}")
    print("feedbk = median measurement-to-command latency (RTI: the QP alone); iter = QP (RTI) "
          "or IPOPT iterations")
    ranked = [n for n in ("nmpc", "rti_compiled", "pampc") if n in results]
    if len(ranked) > 1:  # the paper's NMPC < VT-NMPC < PAMPC, measured (rti_compiled = VT-NMPC)
        order = sorted(ranked, key=lambda n: results[n]["median_ms"])
        print("measured order of median cost per step: " + " < ".join(
            f"{'vtnmpc' if n == 'rti_compiled' else n} ({results[n]['median_ms']:.3f})"
            for n in order))
    print(f"QP-data library: compile {comp['compile_s']:.2f} s (fresh cache; "
          f"compiled={comp['compiled']}), cached load is part of setup")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
