"""PyBullet quadrotor simulator commanded by body rates and collective thrust (PX4 offboard style).

One :class:`QuadrotorSim` owns one PyBullet ``DIRECT`` client: the drone (a box with the mass and
inertia of :class:`~wt_inspect_env.physics.quadrotor.QuadrotorParams`), the ground plane and, optionally,
the turbine's collision mesh (the same trimesh the planner uses, as a static concave triangle mesh).
It is a front over the batched core :class:`~wt_inspect_env.world.batched_sim.BatchedQuadrotorSim`
with one drone, so that one simulator builds the world, steps the drones and owns the client for
both; the front adds what only a single drone needs (validated commands, contact details as dicts,
obstacles swapped by mesh object).

Each :meth:`QuadrotorSim.step` holds a command ``[p, q, r, T]`` (body rates [rad/s], collective
thrust [N]) for ``1 / ctrl_hz`` and runs ``physics_hz / ctrl_hz`` physics sub-steps. In each:

1. the PX4-like rate PID (:mod:`~wt_inspect_env.physics.rate_control`) turns the rate error into body
   torques, the mixer turns thrust + torques into four rotor thrusts within their limits;
2. the rotors follow their commands through a first-order lag (exact discretisation; the force
   applied over a sub-step is the lagged thrust's mean over it, so impulses are right to O(dt^2));
3. the rotor thrusts act along body +z at the rotor positions, the yaw torque is
   ``-spin * torque_coeff * f`` per rotor (the wrench is ``params.mixer @ f``);
4. wind acts through relative-airspeed drag in body axes: ``-D v_rel - 1/2 rho CdA |v_rel| v_rel``
   with ``v_rel = R^T (v - v_wind)``; the wind is evaluated once per control step at the drone;
5. PyBullet integrates the rigid body (default damping off so it matches the model); contacts with
   the ground or the obstacles are collected after every sub-step.

By default the rotor forces are applied as their resultant: one force at the centre of mass plus
one torque (identical rigid-body dynamics, fewer PyBullet calls); ``SimConfig(per_rotor_forces=True)``
applies the four forces at the rotor positions instead, and a test checks both agree.

``SimConfig(rate_loop=False)`` bypasses the rate loop: the commanded body rates are imposed
directly on the body at every sub-step (with the gyroscopic torque cancelled so they stay constant
through it) and the collective thrust acts at the centre of mass. That is exactly the paper's model
(:mod:`~wt_inspect_env.physics.dynamics`), which the agreement test relies on.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pybullet as p

from ..physics.quadrotor import QuadrotorParams, get_preset
from ..physics.rate_control import Mixer, RateGains
from ..physics.sim_config import SimConfig
from ..physics.wind import WindField, make_wind
from .batched_sim import DRONE_COLLISION_GROUP, BatchedQuadrotorSim
from .integration import DroneIntegrator

RAY_MASK_WITHOUT_DRONE = 0xFFFF & ~DRONE_COLLISION_GROUP   # rays that do not see the drone itself
_MAX_CACHED_OBSTACLES = 4


def _to_body(q: list[float], v: list[float]) -> tuple[float, float, float]:
    """World vector ``v`` in the body frame of quaternion ``q`` (R^T v, R from Bullet), in scalar
    arithmetic so a state read back is the same to the bit as it always was."""
    R = p.getMatrixFromQuaternion(q)
    x, y, z = v
    return (R[0] * x + R[3] * y + R[6] * z, R[1] * x + R[4] * y + R[7] * z, R[2] * x + R[5] * y + R[8] * z)


class QuadrotorSim:
    """A PyBullet quadrotor with a PX4-like rate loop, motor lag, drag and wind (see module doc)."""

    def __init__(self, params: QuadrotorParams | str | None = None,
                 config: SimConfig | None = None, wind: WindField | None = None,
                 obstacles: Any = None, obstacle_texture: Any = None) -> None:
        if params is None:
            params = get_preset("matrice100")
        elif isinstance(params, str):
            params = get_preset(params)
        if not isinstance(params, QuadrotorParams):
            raise ValueError(f"params must be a QuadrotorParams or preset name, got {params!r}")
        config = SimConfig() if config is None else config
        if not isinstance(config, SimConfig):
            raise ValueError(f"config must be a SimConfig, got {config!r}")
        self.params = params
        self.config = config
        self.dt = 1.0 / config.ctrl_hz
        self.physics_dt = 1.0 / config.physics_hz
        self.rate_gains = config.rate_gains or RateGains.for_params(params)
        self.mixer = Mixer(params)
        # The field is used as given (not copied): its owner, e.g. the environment, may reseed it.
        # Simulators stepped independently should not share a random field object.
        wind = None if wind is None else make_wind(wind)
        # Obstacle (turbine) geometries of the core by mesh object: id -> (mesh, geometry index).
        self._obstacles: dict[int, tuple[Any, int]] = {}
        self._sim = BatchedQuadrotorSim(params, config, 1, geometries=() if obstacles is None else (obstacles,),
                                        winds=[wind], obstacle_texture=obstacle_texture, park_unused=True)
        if obstacles is not None:
            self._obstacles[id(obstacles)] = (obstacles, 0)
        self._contacts: list[dict] = []
        try:  # never leak the client when the rest of the set-up rejects its input
            self.reset(np.array([0, 0, 1.0 + params.frame_height, 0, 0, 0, 0, 0, 0, 1.0]))
        except BaseException:
            self.close()
            raise

    @property
    def wind(self) -> WindField | None:
        """The wind field (``None``: still air); assigning one takes effect at the next reset."""
        return self._sim.winds[0]

    @wind.setter
    def wind(self, wind: WindField | None) -> None:
        self._sim.set_wind(0, None if wind is None else make_wind(wind))

    @property
    def obstacle_texture(self) -> Any:
        """The obstacles' look in rendered images (e.g. texture.SpanTexture), or ``None``: drawing
        only, physics and rays use the collision shapes."""
        return self._sim.obstacle_texture

    def enable_gui(self) -> None:
        """Move the simulation into a PyBullet GUI window (one per process; needs a display).

        The world is rebuilt in a new GUI client and the drone keeps its state; :attr:`client`
        changes, so call this before handing the client id to other modules.
        """
        self._check_open()
        self._sim.enable_gui()

    # ------------------------------------------------------------------ lifecycle
    @property
    def client(self) -> int:
        """The PyBullet client id (e.g. for ``p.rayTestBatch(..., physicsClientId=sim.client)``)."""
        self._check_open()
        return self._sim.client

    @property
    def body_id(self) -> int:
        """PyBullet body id of the drone."""
        return self._sim.body_ids[0]

    def _check_open(self) -> None:
        if self._sim.closed:
            raise RuntimeError("this QuadrotorSim is closed")

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        self._sim.close()

    def __enter__(self) -> "QuadrotorSim":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_obstacles(self, mesh: Any) -> None:
        """Replace the static obstacle (turbine) collision mesh; ``None`` removes it.

        Obstacle bodies are kept per mesh object (the last four) and *parked* far below the ground
        when not in use, instead of being removed: the rotor-turn swap of a two-phase mission
        happens every episode, and PyBullet cannot free a removed concave mesh shape (it warns and
        leaks), so re-creating it would grow memory with every reset. Kept bodies are not part of
        the world while parked (no contacts, no ray hits near the turbine).
        """
        self._check_open()
        sim = self._sim
        if mesh is None:
            g = -1
        elif id(mesh) in self._obstacles:          # the entry holds the mesh, so its id is not reused
            g = self._obstacles[id(mesh)][1]
        else:
            full = len(self._obstacles) >= _MAX_CACHED_OBSTACLES
            oldest = next(iter(self._obstacles)) if full else None
            g = sim.add_geometry(mesh, replace=self._obstacles[oldest][1] if full else None)
            if full:
                del self._obstacles[oldest]
            self._obstacles[id(mesh)] = (mesh, g)
        sim.set_geometry(0, g)
        sim.integrator.forget_clearance(0)   # every call, changed or not: the clearance is measured afresh

    @property
    def obstacle_chunks(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(centres (K, 3), radii (K,)) of the bounding spheres of the active obstacle's drawn
        chunks (only with an ``obstacle_texture``; else ``None``)."""
        return self._sim.obstacle_chunks

    def show_obstacle_chunks(self, mask: Any = True) -> None:
        """Draw only the active obstacle's chunks where ``mask`` is true (e.g. those a camera's
        frustum can see: TinyRenderer's cost grows with every triangle it is given, drawn or
        not); ``True`` draws them all. Drawing only: collisions and rays are unaffected."""
        self._sim.show_obstacle_chunks(mask)

    @property
    def obstacle_id(self) -> int:
        """PyBullet body id of the obstacle mesh (-1 if none)."""
        return self._sim.obstacle_id

    @property
    def ground_id(self) -> int:
        """PyBullet body id of the ground plane."""
        return self._sim.ground_id

    # ------------------------------------------------------------------ plant
    @property
    def plant(self) -> QuadrotorParams:
        """The airframe PyBullet integrates (``params`` unless :meth:`set_plant` changed it)."""
        return self._sim.plants[0]

    @property
    def thrust_scale(self) -> float:
        """The thrust factor of the plant in use (:meth:`set_plant`)."""
        return float(self._sim.thrust_scales[0])

    def set_plant(self, plant: QuadrotorParams | None = None, thrust_scale: float = 1.0) -> None:
        """Fly a different airframe than the nominal ``params`` (domain randomisation).

        The *physics* - body mass and inertia, motor lag, drag, the torque rows of the rotor
        wrench - follow ``plant``, and each rotor produces ``thrust_scale`` times the thrust it was
        commanded; the *controller side* - rate gains, the rate loop's inertia, the mixer's
        allocation and limits - keeps ``params``, as an autopilot tuned for the nominal airframe
        would. ``set_plant()`` restores the nominal airframe exactly. Takes effect at once; call it
        before :meth:`reset` (which starts the rotors at the plant's hover thrust).
        """
        self._check_open()
        self._sim.set_plant(0, plant, thrust_scale)

    # ------------------------------------------------------------------ reset / state
    def reset(self, state: Any, body_rates: Any = None, seed: int | None = None) -> None:
        """Place the drone at ``state`` = [p, v_body, q] (model convention) and restart time.

        ``body_rates`` (3,) default to zero. The rotors start at hover thrust (m g / 4 each) and the
        rate-loop integrators at zero. ``seed`` (if given) reseeds the wind field with
        ``wind.reset(seed)``; without it the field keeps its seed, and since random fields are
        functions of time from their seed, the same gusts replay. (An environment that owns the
        wind reseeds it itself; it need not pass a seed here.)
        """
        self._check_open()
        self._sim.reset_drone(0, state, body_rates, seed)
        self._contacts = []

    @property
    def integrator(self) -> DroneIntegrator:
        """The stepping loop (its ``core`` holds the flight state; counters say how many steps
        PyBullet integrated)."""
        return self._sim.integrator

    @property
    def time(self) -> float:
        """Simulated time since the last reset [s]."""
        return int(self._sim.steps[0]) * self.dt

    @property
    def state(self) -> np.ndarray:
        """(10,) [position, body velocity, quaternion (x, y, z, w)], the model's convention."""
        sim = self._sim
        q = sim.quat[0].tolist()
        return np.array([*sim.pos[0].tolist(), *_to_body(q, sim.vel[0].tolist()), *q])

    @property
    def body_rates(self) -> np.ndarray:
        """(3,) body angular velocity (p, q, r) [rad/s]."""
        sim = self._sim
        return np.array(_to_body(sim.quat[0].tolist(), sim.omega[0].tolist()))

    @property
    def world_velocity(self) -> np.ndarray:
        """The drone's velocity in the world frame [m/s] (a copy)."""
        return self._sim.vel[0].copy()

    @property
    def rotor_thrusts(self) -> np.ndarray:
        """(4,) current rotor thrusts [N] (after motor lag and saturation; times the plant's
        ``thrust_scale``)."""
        return self._sim.f[0] * self.thrust_scale

    @property
    def wind_velocity(self) -> np.ndarray:
        """(3,) wind velocity at the drone used during the last step [m/s]."""
        return self._sim.last_wind[0].copy()

    @property
    def in_collision(self) -> bool:
        """Whether the drone touched the obstacles or the ground during the last step."""
        return bool(self._sim.in_collision[0])

    @property
    def contacts(self) -> list[dict]:
        """Contact points of the last step's last touching sub-step: dicts with ``other``
        ('ground' or 'obstacle'), ``position`` (on the other body), ``normal`` (from the other body
        towards the drone), ``distance`` (negative = penetration [m]), ``normal_force`` [N]."""
        return [dict(c) for c in self._contacts]

    def sync_scene(self) -> None:
        """Put the drone's PyBullet body at its current pose (the flight core integrates free
        flight without PyBullet; renders of the scene call this first)."""
        self._check_open()
        self._sim.sync_scene()

    # ------------------------------------------------------------------ stepping
    def step(self, command: Any) -> None:
        """Hold ``command`` = [p, q, r, T] for one control period (1 / ctrl_hz)."""
        self._check_open()
        try:
            cmd = np.asarray(command, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"command must be a numeric array [p, q, r, T], got {command!r}") from None
        if cmd.shape != (4,):
            raise ValueError(f"command must have shape (4,) [p, q, r, T], got shape {cmd.shape}")
        if not np.isfinite(cmd).all():
            raise ValueError(f"command must be finite, got {cmd.tolist()}")
        if cmd[3] < 0:
            raise ValueError(f"command thrust T must be >= 0 N (rotors cannot push down), got {float(cmd[3])!r}")
        sim = self._sim
        sim.step(cmd[None])
        cps = sim.contact_points.get(0)
        ground, obstacle, t = sim.ground_id, sim.obstacle_id, self.time
        self._contacts = [] if cps is None else [{
            "other": "ground" if c[2] == ground else ("obstacle" if c[2] == obstacle else f"body{c[2]}"),
            "position": np.array(c[6]),
            "normal": np.array(c[7]),    # Bullet: normal on B (the other body) towards A
            "distance": float(c[8]),
            "normal_force": float(c[9]),
            "time": t,
        } for c in cps]
