"""PyBullet quadrotor simulator commanded by body rates and collective thrust (PX4 offboard style).

One :class:`QuadrotorSim` owns one PyBullet ``DIRECT`` client: the drone (a box with the mass and
inertia of :class:`~wt_inspect_env.physics.quadrotor.QuadrotorParams`), the ground plane and, optionally,
the turbine's collision mesh (the same trimesh the planner uses, as a static concave triangle mesh).

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

import os
import sys
from typing import Any

import numpy as np
import pybullet as p

from ..physics.quadrotor import GRAVITY, QuadrotorParams, get_preset
from ..physics.rate_control import Mixer, RateGains
from ..physics.sim_config import SimConfig
from ..physics.wind import WindField, make_wind
from ..planner.proximity import MeshProximity
from ..scene.pybullet_refs import call_releasing
from ..scene.scene_visuals import create_chunks, load_texture, show_chunks
from ..util.validation import check_array, check_positive
from .integration import DroneIntegrator


def _mesh_arrays(mesh: Any) -> tuple[list, list]:
    """Validated (vertices, flat indices) lists from a trimesh-like mesh."""
    verts = getattr(mesh, "vertices", None)
    faces = getattr(mesh, "faces", None)
    if verts is None or faces is None:
        raise ValueError(f"obstacles must be a trimesh.Trimesh (vertices and faces), got {mesh!r}")
    v = check_array("obstacles.vertices", verts, (None, 3))
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ValueError(f"obstacles.faces must have shape (M, 3) with M > 0, got shape {f.shape}")
    if not np.issubdtype(f.dtype, np.integer) or f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"obstacles.faces must index the {len(v)} vertices, got range "
                         f"[{f.min()}, {f.max()}]")
    return v.tolist(), f.astype(np.int64).ravel().tolist()


def new_client(mode: int, physics_dt: float) -> int:
    """A PyBullet client set up as every simulator of this package uses it: gravity along -z, a
    fixed step of ``physics_dt`` without sub-stepping, deterministic overlapping pairs."""
    cid = p.connect(mode)
    if cid < 0:  # pragma: no cover - PyBullet refuses only when out of clients / no display
        raise RuntimeError("PyBullet could not create a client")
    try:
        p.resetSimulation(physicsClientId=cid)
        p.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=cid)
        p.setPhysicsEngineParameter(fixedTimeStep=physics_dt, numSubSteps=0, deterministicOverlappingPairs=1,
                                    physicsClientId=cid)
    except BaseException:  # pragma: no cover
        p.disconnect(physicsClientId=cid)
        raise
    return cid


def checked_state(state: Any) -> np.ndarray:
    """A validated copy of a model state [p, v_body, q] with its quaternion normalised (the norm
    must already be within 1e-3 of one)."""
    x = check_array("state", state, (10,))
    q = x[6:10]
    nq = float(np.linalg.norm(q))
    if abs(nq - 1.0) > 1e-3:
        raise ValueError(f"state quaternion must have unit norm, got norm {nq:.6g} ({q.tolist()})")
    x = x.copy()
    x[6:10] = q / nq
    return x


def place_body(cid: int, body: int, x: np.ndarray, w_b: np.ndarray) -> None:
    """Set a drone body's pose and world velocities in PyBullet from a model state and body rates."""
    q = x[6:10].tolist()
    R = np.array(p.getMatrixFromQuaternion(q)).reshape(3, 3)
    p.resetBasePositionAndOrientation(body, x[0:3].tolist(), q, physicsClientId=cid)
    p.resetBaseVelocity(body, (R @ x[3:6]).tolist(), (R @ w_b).tolist(), physicsClientId=cid)


def create_drone_body(cid: int, params: QuadrotorParams, shape: int | None = None) -> int:
    """The drone's rigid body: a box of the airframe's collision size with its mass and inertia, no
    damping (so it matches the model), never asleep. ``shape``: a box shape to reuse."""
    if shape is None:
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(params.collision_half_extents),
                                       physicsClientId=cid)
    body = p.createMultiBody(baseMass=params.mass, baseCollisionShapeIndex=shape, basePosition=[0, 0, 1],
                             physicsClientId=cid)
    p.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, localInertiaDiagonal=list(params.inertia),
                     activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
    return body


DRONE_COLLISION_GROUP = 4
RAY_MASK_WITHOUT_DRONE = 0xFFFF & ~DRONE_COLLISION_GROUP   # rays that do not see the drone itself
_PARKED = (0.0, 0.0, -1.0e5)      # where unused obstacle bodies wait (far below the ground)
_MAX_CACHED_OBSTACLES = 4


def checked_plant(params: QuadrotorParams, plant: QuadrotorParams | None,
                  thrust_scale: float) -> QuadrotorParams:
    """The airframe a simulator integrates instead of its nominal ``params`` (``None``: the nominal
    one), refused with one line unless it keeps the nominal rotor layout - the mixer and the rate
    loop are built for that layout, so another one would not be a perturbed plant but another drone.
    One home for the single and the batched simulator's ``set_plant``."""
    plant = params if plant is None else plant
    if not isinstance(plant, QuadrotorParams):
        raise ValueError(f"plant must be a QuadrotorParams or None, got {plant!r}")
    check_positive("thrust_scale", thrust_scale)
    if plant.rotor_positions.tolist() != params.rotor_positions.tolist() or plant.rotor_spin != params.rotor_spin:
        raise ValueError("plant must keep the nominal rotor layout (arm_length, rotor_spin)")
    return plant


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
        # The field is used as given (not copied): its owner, e.g. the environment, may reseed it.
        # Simulators stepped independently should not share a random field object.
        self.wind: WindField | None = None if wind is None else make_wind(wind)
        self._client = -1
        self._gui = False

        self.dt = 1.0 / config.ctrl_hz
        self.physics_dt = 1.0 / config.physics_hz
        self._n_sub = config.substeps
        self.rate_gains = config.rate_gains or RateGains.for_params(params)
        self.mixer = Mixer(params)
        self._plant = params
        self._thrust_scale = 1.0
        self._integrator: DroneIntegrator | None = None
        self._proximity: dict[int, tuple[Any, MeshProximity]] = {}   # per obstacle mesh (id -> (mesh, structure))

        # Optional look of the obstacles in rendered images (e.g. texture.SpanTexture: .uvs and
        # .image); drawing only, physics and rays use the collision shapes.
        self.obstacle_texture = obstacle_texture
        self._texture_id = -1
        self._obstacle_key: Any = obstacles
        self._chunks: dict[int, dict[str, Any]] = {}
        self._obstacle_arrays: tuple[list, list] | None = (
            None if obstacles is None else _mesh_arrays(obstacles))
        self._last_wind = np.zeros(3)
        self._contacts: list[dict] = []
        self._touched = False
        self._steps = 0
        self._build_world(p.DIRECT)
        try:  # never leak the client when the rest of the set-up rejects its input
            self.reset(np.array([0, 0, 1.0 + params.frame_height, 0, 0, 0, 0, 0, 0, 1.0]))
        except BaseException:
            self.close()
            raise

    def _build_world(self, mode: int) -> None:
        """Connect a client of the given mode and create drone, ground and obstacles in it."""
        params, config = self.params, self.config
        cid = self._client = new_client(mode, self.physics_dt)
        self._texture_id = -1
        self._chunks = {}
        try:
            self._body = create_drone_body(cid, params)
            # Own collision group: still collides with everything, but ray tests (camera
            # occlusion) can exclude it with RAY_MASK_WITHOUT_DRONE.
            p.setCollisionFilterGroupMask(self._body, -1, DRONE_COLLISION_GROUP, 0xFFFF,
                                          physicsClientId=cid)
            self._ground = -1
            if config.ground:
                plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
                self._ground = p.createMultiBody(0.0, plane,
                                                 basePosition=[0, 0, config.ground_height],
                                                 physicsClientId=cid)
            self._obstacle = -1
            self._obstacle_shape = -1
            self._obstacle_cache: dict[int, tuple[int, int, Any, tuple[list, list]]] = {}
            ground = config.ground_height if config.ground else None
            if self._integrator is None:
                self._integrator = DroneIntegrator(params, config, cid, [self._body], [0xFFFF], ground,
                                                   DRONE_COLLISION_GROUP)
            else:                             # enable_gui: the same drones in a new client
                self._integrator.rebind(cid, [self._body])
            if self._obstacle_arrays is not None:
                self._create_obstacle(*self._obstacle_arrays, key=self._obstacle_key)
            self._integrator.set_obstacle(0, self._obstacle_proximity())
        except BaseException:
            self.close()
            raise

    def enable_gui(self) -> None:
        """Move the simulation into a PyBullet GUI window (one per process; needs a display).

        The world is rebuilt in a new GUI client and the drone keeps its state; :attr:`client`
        changes, so call this before handing the client id to other modules.
        """
        self._check_open()
        if self._gui:
            return
        if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            raise RuntimeError("enable_gui needs a display (DISPLAY is not set)")
        p.disconnect(physicsClientId=self._client)
        self._client = -1
        self._build_world(p.GUI)              # the flight core keeps every drone's state
        self._gui = True
        if self._plant is not self.params:
            self.set_plant(self._plant, self._thrust_scale)
        self._integrator.sync_bodies()

    # ------------------------------------------------------------------ lifecycle
    @property
    def client(self) -> int:
        """The PyBullet client id (e.g. for ``p.rayTestBatch(..., physicsClientId=sim.client)``)."""
        self._check_open()
        return self._client

    @property
    def body_id(self) -> int:
        """PyBullet body id of the drone."""
        return self._body

    def _check_open(self) -> None:
        if self._client < 0:
            raise RuntimeError("this QuadrotorSim is closed")

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self._client >= 0:
            try:
                p.disconnect(physicsClientId=self._client)
            finally:
                self._client = -1

    def __enter__(self) -> "QuadrotorSim":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass

    def set_obstacles(self, mesh: Any) -> None:
        """Replace the static obstacle (turbine) collision mesh; ``None`` removes it.

        Obstacle bodies are cached per mesh object and *parked* far below the ground when not in
        use, instead of being removed: the rotor-turn swap of a two-phase mission happens every
        episode, and PyBullet cannot free a removed concave mesh shape (it warns and leaks), so
        re-creating it would grow memory with every reset. Cached bodies are not part of the
        world while parked (no contacts, no ray hits near the turbine).
        """
        self._check_open()
        cid = self._client
        if self._obstacle >= 0:
            p.resetBasePositionAndOrientation(self._obstacle, _PARKED, (0, 0, 0, 1), physicsClientId=cid)
            self._show_chunks(self._chunks.get(self._obstacle), False)
            self._obstacle = self._obstacle_shape = -1
        self._obstacle_key = mesh
        if mesh is None:
            self._obstacle_arrays = None
            self._integrator.set_obstacle(0, None)
            return
        cached = self._obstacle_cache.get(id(mesh))
        if cached is not None and cached[2] is mesh:
            self._obstacle, self._obstacle_shape = cached[0], cached[1]
            self._obstacle_arrays = cached[3]
            p.resetBasePositionAndOrientation(self._obstacle, (0, 0, 0), (0, 0, 0, 1), physicsClientId=cid)
            self._show_chunks(self._chunks.get(self._obstacle), True)
        else:
            self._obstacle_arrays = _mesh_arrays(mesh)
            self._create_obstacle(*self._obstacle_arrays, key=mesh)
        self._integrator.set_obstacle(0, self._obstacle_proximity())

    def _obstacle_proximity(self) -> MeshProximity | None:
        """The exact distance structure of the active obstacle (built once per mesh object), which
        tells the integrator when the drone may touch it."""
        if self._obstacle_arrays is None:
            return None
        key = self._obstacle_key
        hit = self._proximity.get(id(key))
        if hit is None or hit[0] is not key:
            verts, idx = self._obstacle_arrays
            hit = (key, MeshProximity(np.asarray(verts)[np.asarray(idx).reshape(-1, 3)]))
            if len(self._proximity) >= _MAX_CACHED_OBSTACLES:
                self._proximity.pop(next(iter(self._proximity)))
            self._proximity[id(key)] = hit
        return hit[1]

    def _create_obstacle(self, verts: list, idx: list, key: Any = None) -> None:
        cid = self._client
        shape = call_releasing(p.createCollisionShape, p.GEOM_MESH, vertices=verts, indices=idx,
                               flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid)
        if shape < 0:  # pragma: no cover
            raise ValueError("PyBullet rejected the obstacle mesh")
        self._obstacle_shape = shape
        if self.obstacle_texture is None:
            # A visual shape of the same triangles, so rgb_array renders show the turbine.
            visual = call_releasing(p.createVisualShape, p.GEOM_MESH, vertices=verts, indices=idx,
                                    rgbaColor=(0.85, 0.85, 0.9, 1.0), physicsClientId=cid)
            self._obstacle = p.createMultiBody(0.0, shape, baseVisualShapeIndex=visual, physicsClientId=cid)
        else:
            # Drawn as textured visual-only chunks instead (the collision body itself invisible), so
            # a camera view can skip the chunks outside its frustum (see show_obstacle_chunks).
            self._obstacle = p.createMultiBody(0.0, shape, physicsClientId=cid)
            p.changeVisualShape(self._obstacle, -1, rgbaColor=(1, 1, 1, 0), physicsClientId=cid)
            self._chunks[self._obstacle] = self._create_chunks(np.asarray(verts), np.asarray(idx).reshape(-1, 3))
        if key is not None:
            if len(self._obstacle_cache) >= _MAX_CACHED_OBSTACLES:
                old_key = next(iter(self._obstacle_cache))
                old = self._obstacle_cache.pop(old_key)
                p.removeBody(old[0], physicsClientId=cid)
                for body in self._chunks.pop(old[0], {"bodies": []})["bodies"]:
                    p.removeBody(body, physicsClientId=cid)
            self._obstacle_cache[id(key)] = (self._obstacle, shape, key, (verts, idx))

    def _create_chunks(self, v: np.ndarray, f: np.ndarray) -> dict[str, Any]:
        if self._texture_id < 0:
            self._texture_id = load_texture(self._client, self.obstacle_texture.image())
        return create_chunks(self._client, self._texture_id, self.obstacle_texture, v, f)

    def _show_chunks(self, chunks: dict[str, Any] | None, mask: Any) -> None:
        show_chunks(self._client, chunks, mask)

    @property
    def obstacle_chunks(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(centres (K, 3), radii (K,)) of the bounding spheres of the active obstacle's drawn
        chunks (only with an ``obstacle_texture``; else ``None``)."""
        chunks = self._chunks.get(self._obstacle)
        return None if chunks is None else (chunks["centers"], chunks["radii"])

    def show_obstacle_chunks(self, mask: Any = True) -> None:
        """Draw only the active obstacle's chunks where ``mask`` is true (e.g. those a camera's
        frustum can see: TinyRenderer's cost grows with every triangle it is given, drawn or
        not); ``True`` draws them all. Drawing only: collisions and rays are unaffected."""
        self._show_chunks(self._chunks.get(self._obstacle), mask)

    @property
    def obstacle_id(self) -> int:
        """PyBullet body id of the obstacle mesh (-1 if none)."""
        return self._obstacle

    @property
    def ground_id(self) -> int:
        """PyBullet body id of the ground plane."""
        return self._ground

    # ------------------------------------------------------------------ plant
    @property
    def plant(self) -> QuadrotorParams:
        """The airframe PyBullet integrates (``params`` unless :meth:`set_plant` changed it)."""
        return self._plant

    @property
    def thrust_scale(self) -> float:
        """The thrust factor of the plant in use (:meth:`set_plant`)."""
        return self._thrust_scale

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
        plant = checked_plant(self.params, plant, thrust_scale)
        self._integrator.core.set_plant(0, plant, float(thrust_scale))
        self._plant, self._thrust_scale = plant, float(thrust_scale)
        p.changeDynamics(self._body, -1, mass=plant.mass, localInertiaDiagonal=list(plant.inertia),
                         physicsClientId=self._client)

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
        x = checked_state(state)
        w_b = np.zeros(3) if body_rates is None else check_array("body_rates", body_rates, (3,))
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
                raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
            if self.wind is not None:
                self.wind.reset(int(seed))
        # Through PyBullet once, so the stored pose is exactly what Bullet would hold.
        cid, body = self._client, self._body
        place_body(cid, body, x, w_b)
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, omega = p.getBaseVelocity(body, physicsClientId=cid)
        self._integrator.core.reset(0, pos, quat, vel, omega, w_b)   # rotors at the plant's hover thrust
        self._integrator.placed(0)
        self._steps = 0
        self._contacts = []
        self._in_collision = False
        self._last_wind = self._wind_at(0.0)
        self._const_wind = self.wind is None or self.wind.is_constant

    def _wind_at(self, t: float) -> np.ndarray:
        if self.wind is None:
            return np.zeros(3)
        v = self.wind(t, self._integrator.core.pos[0:1])
        return np.array(v[0], dtype=float)

    @property
    def integrator(self) -> DroneIntegrator:
        """The stepping loop (its ``core`` holds the flight state; counters say how many steps
        PyBullet integrated)."""
        return self._integrator

    @property
    def time(self) -> float:
        """Simulated time since the last reset [s]."""
        return self._steps * self.dt

    @property
    def state(self) -> np.ndarray:
        """(10,) [position, body velocity, quaternion (x, y, z, w)], the model's convention."""
        core = self._integrator.core
        q = core.quat[0].tolist()
        R = p.getMatrixFromQuaternion(q)
        vx, vy, vz = core.vel[0].tolist()
        return np.array([*core.pos[0].tolist(), R[0] * vx + R[3] * vy + R[6] * vz,
                         R[1] * vx + R[4] * vy + R[7] * vz, R[2] * vx + R[5] * vy + R[8] * vz, *q])

    @property
    def body_rates(self) -> np.ndarray:
        """(3,) body angular velocity (p, q, r) [rad/s]."""
        core = self._integrator.core
        R = p.getMatrixFromQuaternion(core.quat[0].tolist())
        ox, oy, oz = core.omega[0].tolist()
        return np.array([R[0] * ox + R[3] * oy + R[6] * oz, R[1] * ox + R[4] * oy + R[7] * oz,
                         R[2] * ox + R[5] * oy + R[8] * oz])

    @property
    def world_velocity(self) -> np.ndarray:
        """The drone's velocity in the world frame [m/s] (a copy)."""
        return self._integrator.core.vel[0].copy()

    @property
    def rotor_thrusts(self) -> np.ndarray:
        """(4,) current rotor thrusts [N] (after motor lag and saturation; times the plant's
        ``thrust_scale``)."""
        return self._integrator.core.rotor[0] * self._thrust_scale

    @property
    def wind_velocity(self) -> np.ndarray:
        """(3,) wind velocity at the drone used during the last step [m/s]."""
        return self._last_wind.copy()

    @property
    def in_collision(self) -> bool:
        """Whether the drone touched the obstacles or the ground during the last step."""
        return self._in_collision

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
        self._integrator.sync_bodies()

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
        if not self._const_wind:
            self._last_wind = self._wind_at(self._steps * self.dt)
        integ = self._integrator
        integ.commands[0] = cmd
        integ.winds[0] = self._last_wind
        self._touched = False
        integ.step(self._record_contacts)
        self._in_collision = self._touched
        if not self._touched:
            self._contacts = []
        self._steps += 1
        if self._gui:
            integ.sync_bodies()

    def _record_contacts(self, i: int, substep: int, cps) -> None:
        """The integrator's contact sink: keep the touching sub-step's points."""
        found = []
        for c in cps:
            other = c[2]
            found.append({
                "other": "ground" if other == self._ground else
                         ("obstacle" if other == self._obstacle else f"body{other}"),
                "position": np.array(c[6]),
                "normal": np.array(c[7]),    # Bullet: normal on B (the other body) towards A
                "distance": float(c[8]),
                "normal_force": float(c[9]),
                "time": (self._steps + 1) * self.dt,
            })
        self._contacts = found
        self._touched = True
