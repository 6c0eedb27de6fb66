"""A closed loop without the simulator: an inspection point sliding along a straight surface
(:class:`SurfacePass`), the shared CasADi model as a fast plant (:class:`ModelPlant`) and the loop
that flies a policy on it (:func:`run_closed_loop`).

The controller tests and the studies (:mod:`wt_inspect.studies.wind_offset`) use it to fly an MPC
in isolation, in milliseconds per step. The plant only needs ``reset(state)``, ``step(command)``
and a ``state`` property, so the PyBullet simulator (:class:`wt_inspect_env.world.sim.QuadrotorSim`) can
be passed instead of :class:`ModelPlant`. The benchmark (``wt-inspect bench solver``) flies the real
environment instead.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from wt_inspect_env.physics.dynamics import QuadrotorModel, quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import QuadrotorParams, drag_force
from wt_inspect_env.task.geometry import heading_and_distance, standoff_state
from wt_inspect_env.task.spaces import ActionScaling
from wt_inspect_env.util.validation import check_array, check_positive


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
        """The inspection point at time ``t`` [s] (moving along the pass)."""
        return np.asarray(self.start) + self.speed * t * np.asarray(self.direction)

    def velocity(self, t: float = 0.0) -> np.ndarray:
        """The inspection point's velocity [m/s] (constant along the pass)."""
        return self.speed * np.asarray(self.direction, dtype=float)

    def ideal_state(self, t: float, d_ref: float) -> np.ndarray:
        """Where the VT-NMPC should be: p + d_ref n, level, facing the point."""
        return standoff_state(self.point(t), self.normal, d_ref)


class ModelPlant:
    """The shared CasADi model integrated with RK4 at ``substeps`` per control step: a stand-in
    for the PyBullet simulator with the same ``reset``/``step``/``state`` interface.

    The plant has the simulator's drag (:func:`wt_inspect_env.physics.quadrotor.drag_force` of the airspeed
    v_B - R^T v_wind), which the controllers' model (like the paper's) does not know;
    ``wind(t, positions) -> velocities`` (world) sets the air velocity (still air without it).
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
        self.t = 0.0
        self._state = np.zeros(10)

    @property
    def state(self) -> np.ndarray:
        """The plant's state (a copy)."""
        return self._state.copy()

    def reset(self, state: np.ndarray) -> np.ndarray:
        """Start again from ``state`` at t = 0; returns the state."""
        self._state = check_array("state", state, (10,)).copy()
        self.t = 0.0
        return self.state

    def disturbance_accel(self) -> np.ndarray:
        """World-frame acceleration from drag relative to the air at the current state."""
        x = self._state
        R = quat_to_rotmat_np(x[6:10])
        v_wind = np.zeros(3) if self.wind is None else \
            np.asarray(self.wind(self.t, x[None, 0:3]), dtype=float)[0]
        f_body = drag_force(self.params, x[3:6] - R.T @ v_wind)
        return R @ f_body / self.params.mass

    def step(self, command: np.ndarray) -> np.ndarray:
        """Hold ``command`` for one step of the model (drag held over it); returns the new state."""
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
    h, d = heading_and_distance(state[0:3], state[6:10], point)
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
