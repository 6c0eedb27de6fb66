"""N quadrotors in one PyBullet client: the one simulator core (rate loop, motor lag, drag, wind, contacts).

Every drone is its own rigid body in one ``DIRECT`` client that also holds the ground and one
static body per turbine geometry (phase 1, and the rotated phase-2 turbine). Collision groups keep
the drones apart: a drone collides with the ground and with the geometry of *its own* phase only,
never with another drone, and the camera rays of a drone see the ground and its geometry only. So
each drone lives in a world of its own, and drone ``i`` under the same commands follows a
simulator of one drone bit for bit.

The single-drone :class:`~wt_inspect_env.world.sim.QuadrotorSim` is a front over this core with
``n = 1``: world building, the GUI, plants, obstacle bodies and their drawing, and the client's
lifetime live here only. What the front adds is single-drone convenience (validated commands,
contact details as dicts, obstacles swapped by mesh object).

Every drone is stepped by the :class:`~wt_inspect_env.world.integration.DroneIntegrator`: one call
into the compiled flight core advances every drone in free flight through all physics sub-steps;
only drones that may touch the ground or their geometry during the step are handed to PyBullet
(:mod:`~wt_inspect_env.world.sim` describes the physics of a sub-step). The wind stays per drone (each owns an
arbitrary, seeded :class:`~wt_inspect_env.physics.wind.WindField`), evaluated once per control step.
"""
from __future__ import annotations

import os
import sys
from typing import Any, Sequence

import numpy as np
import pybullet as p

from ..physics.quadrotor import GRAVITY, QuadrotorParams
from ..physics.sim_config import SimConfig
from ..physics.wind import WindBatch, WindField
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


def _proximity(arrays: tuple[list, list]) -> MeshProximity:
    """The exact distance structure of a mesh's (vertices, flat indices), which tells the
    integrator when a drone may touch it."""
    verts, idx = arrays
    return MeshProximity(np.asarray(verts)[np.asarray(idx).reshape(-1, 3)])


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


def checked_plant(params: QuadrotorParams, plant: QuadrotorParams | None,
                  thrust_scale: float) -> QuadrotorParams:
    """The airframe a simulator integrates instead of its nominal ``params`` (``None``: the nominal
    one), refused with one line unless it keeps the nominal rotor layout - the mixer and the rate
    loop are built for that layout, so another one would not be a perturbed plant but another drone."""
    plant = params if plant is None else plant
    if not isinstance(plant, QuadrotorParams):
        raise ValueError(f"plant must be a QuadrotorParams or None, got {plant!r}")
    check_positive("thrust_scale", thrust_scale)
    if plant.rotor_positions.tolist() != params.rotor_positions.tolist() or plant.rotor_spin != params.rotor_spin:
        raise ValueError("plant must keep the nominal rotor layout (arm_length, rotor_spin)")
    return plant


DRONE_COLLISION_GROUP = 4
GROUND_GROUP = 1
_GEOMETRY_GROUP0 = 16        # geometry g is in group 16 << g (phase 1, phase 2, ...)
_MAX_GEOMETRIES = 8
_PARKED = (0.0, 0.0, -1.0e5)  # where geometries out of the world wait (far below the ground)


def geometry_group(g: int) -> int:
    """PyBullet collision group bit of geometry ``g`` (each geometry its own, above the ground's)."""
    return _GEOMETRY_GROUP0 << g


def ray_mask(g: int) -> int:
    """Collision mask of the camera rays of a drone flying in geometry ``g`` (ground + geometry)."""
    return GROUND_GROUP | geometry_group(g)


def bullet_rotation(quat: np.ndarray) -> tuple[np.ndarray, ...]:
    """The nine entries (row-major, body-to-world) of Bullet's ``btMatrix3x3::setRotation`` for
    ``(N, 4)`` quaternions - the same operations, so bitwise equal to ``p.getMatrixFromQuaternion``."""
    x, y, z, w = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]
    s = 2.0 / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return (1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy))


class BatchedQuadrotorSim:
    """``n`` independent quadrotors (rate loop, motor lag, drag, wind) in one PyBullet client.

    ``geometries``: the static turbine meshes (trimesh-like), one per phase; each drone collides
    with the one selected by :meth:`set_geometry` (0 after construction, -1 - the ground only -
    without geometries); :meth:`add_geometry` adds or replaces one later. ``winds``: one
    :class:`WindField` per drone (or None for still air); the owner reseeds them.
    ``park_unused`` (one drone only): the geometries the drone does not fly in leave the world
    (parked far below the ground) instead of being only masked and hidden, so that rays of any
    mask and contacts with any body see the active one only - the world of :class:`QuadrotorSim`,
    whose users cast rays with masks of their own.
    """

    def __init__(self, params: QuadrotorParams, config: SimConfig, n: int,
                 geometries: Sequence[Any] = (), winds: Sequence[WindField | None] | None = None,
                 obstacle_texture: Any = None, park_unused: bool = False) -> None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"num_envs must be a positive integer, got {n!r}")
        if len(geometries) > _MAX_GEOMETRIES:
            raise ValueError(f"at most {_MAX_GEOMETRIES} geometries, got {len(geometries)}")
        if park_unused and n != 1:
            raise ValueError(f"park_unused needs a world of one drone, got {n} drones")
        self.n = n = int(n)
        self.params, self.config = params, config
        winds = [None] * n if winds is None else list(winds)
        if len(winds) != n:
            raise ValueError(f"winds must hold one field per drone ({n}), got {len(winds)}")
        self.winds = winds
        self._set_varying()
        self.dt = 1.0 / config.ctrl_hz
        self.physics_dt = 1.0 / config.physics_hz
        self._client = -1
        self._gui = False
        self._version = 0                 # bumped by every step and reset: the body-frame cache's key
        self._kin_key: int | None = None
        self._integrator: DroneIntegrator | None = None
        # Drawing (a world of one drone renders): the turbine of drone 0's geometry is visible,
        # textured in chunks with obstacle_texture, plain grey without; the others are hidden.
        self.obstacle_texture = obstacle_texture
        self._render = n == 1
        self._park = bool(park_unused)
        self.geometry = np.full(n, 0 if len(geometries) else -1, dtype=np.int64)
        self._meshes = [_mesh_arrays(mesh) for mesh in geometries]
        self._proximity = [_proximity(arrays) for arrays in self._meshes]
        #: drone -> the touching contact points (PyBullet tuples) of its last touching sub-step,
        #: for the drones that touched the ground or their geometry in the last step
        self.contact_points: dict[int, list] = {}
        self._build_world(p.DIRECT)
        core = self._integrator.core
        # Views of the flight core's arrays (world frame), valid for the simulator's lifetime.
        self.pos, self.vel, self.omega, self.quat = core.pos, core.vel, core.omega, core.quat
        self.steps = np.zeros(n, dtype=np.int64)
        self.in_collision = np.zeros(n, dtype=bool)
        self.last_wind = core.winds
        self._kin_out, self._kin_rates = np.zeros((n, 10)), np.zeros((n, 3))

    @property
    def f(self) -> np.ndarray:
        """(n, 4) rotor thrusts [N] before each plant's thrust factor."""
        return self._integrator.core.rotor

    @property
    def plants(self) -> list[QuadrotorParams]:
        """Each drone's airframe (nominal or drawn by :meth:`set_plant`)."""
        return self._integrator.core.plants

    @property
    def thrust_scales(self) -> np.ndarray:
        """(n,) each plant's thrust factor (:meth:`set_plant`)."""
        return self._integrator.core.thrust_scale

    @property
    def integrator(self) -> DroneIntegrator:
        """The integrator the drones' physics runs in (its ``core`` holds the flight state;
        counters say how many steps PyBullet integrated)."""
        return self._integrator

    # ------------------------------------------------------------------ plants
    def set_plant(self, i: int, plant: QuadrotorParams | None = None, thrust_scale: float = 1.0) -> None:
        """:meth:`QuadrotorSim.set_plant` for drone ``i``: its physics (mass, inertia, motor lag, drag,
        the wrench's torque rows, a thrust factor) follow ``plant``, the controller side stays
        ``params``."""
        plant = checked_plant(self.params, plant, thrust_scale)
        self._integrator.core.set_plant(i, plant, float(thrust_scale))
        p.changeDynamics(self.body_ids[i], -1, mass=plant.mass, localInertiaDiagonal=list(plant.inertia),
                         physicsClientId=self._client)

    # ------------------------------------------------------------------ world
    def _build_world(self, mode: int) -> None:
        params, config, n = self.params, self.config, self.n
        cid = self._client = new_client(mode, self.physics_dt)
        try:
            self.ground_id = -1
            if config.ground:
                plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
                self.ground_id = p.createMultiBody(0.0, plane, basePosition=[0, 0, config.ground_height],
                                                   physicsClientId=cid)
                p.setCollisionFilterGroupMask(self.ground_id, -1, GROUND_GROUP, 0xFFFF, physicsClientId=cid)
            self.geometry_ids: list[int] = []
            self._chunks: list[dict[str, Any] | None] = []
            self._texture_id = -1
            for g, (verts, idx) in enumerate(self._meshes):
                body, chunks = self._create_geometry(g, verts, idx)
                self.geometry_ids.append(body)
                self._chunks.append(chunks)
            box = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(params.collision_half_extents),
                                         physicsClientId=cid)
            self.body_ids: list[int] = []
            for _ in range(n):
                self.body_ids.append(create_drone_body(cid, params, box))
            self._drone_index = {b: i for i, b in enumerate(self.body_ids)}
            self._geometry_index = {b: g for g, b in enumerate(self.geometry_ids)}
            ground = config.ground_height if config.ground else None
            if self._integrator is None:
                self._integrator = DroneIntegrator(params, config, cid, self.body_ids,
                                                   [self._mask(int(g)) for g in self.geometry], ground,
                                                   DRONE_COLLISION_GROUP)
            else:                             # enable_gui: the same drones in a new client
                self._integrator.rebind(cid, self.body_ids)
            for i in range(n):
                p.setCollisionFilterGroupMask(self.body_ids[i], -1, DRONE_COLLISION_GROUP, 0, physicsClientId=cid)
                self._integrator.set_obstacle(i, self._proximity_of(int(self.geometry[i])))
            self._show_geometry(int(self.geometry[0]))
        except BaseException:
            self.close()
            raise

    def _create_geometry(self, g: int, verts: list, idx: list) -> tuple[int, dict[str, Any] | None]:
        """The static body of geometry ``g`` in its collision group, and (a world of one drone)
        its look: a grey visual shape, or textured visual-only chunks with the collision body
        invisible (so a camera view can skip the chunks outside its frustum)."""
        cid = self._client
        shape = call_releasing(p.createCollisionShape, p.GEOM_MESH, vertices=verts, indices=idx,
                               flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid)
        if shape < 0:  # pragma: no cover
            raise ValueError("PyBullet rejected the obstacle mesh")
        chunks = None
        if self._render and self.obstacle_texture is None:
            visual = call_releasing(p.createVisualShape, p.GEOM_MESH, vertices=verts, indices=idx,
                                    rgbaColor=(0.85, 0.85, 0.9, 1.0), physicsClientId=cid)
            body = p.createMultiBody(0.0, shape, baseVisualShapeIndex=visual, physicsClientId=cid)
        else:
            body = p.createMultiBody(0.0, shape, physicsClientId=cid)
            if self._render:
                p.changeVisualShape(body, -1, rgbaColor=(1, 1, 1, 0), physicsClientId=cid)
                if self._texture_id < 0:
                    self._texture_id = load_texture(cid, self.obstacle_texture.image())
                chunks = create_chunks(cid, self._texture_id, self.obstacle_texture, np.asarray(verts),
                                       np.asarray(idx).reshape(-1, 3))
        p.setCollisionFilterGroupMask(body, -1, geometry_group(g), 0xFFFF, physicsClientId=cid)
        return body, chunks

    def add_geometry(self, mesh: Any, replace: int | None = None) -> int:
        """Add the static turbine mesh ``mesh`` (trimesh-like) as a new geometry, or in place of
        geometry ``replace`` (its body removed, the drones flying in it now fly in ``mesh``);
        returns its index. A drone collides with it once :meth:`set_geometry` selects it.

        PyBullet cannot free a removed concave mesh shape (it warns and keeps the memory), so a
        caller that swaps geometries often keeps them and selects, rather than replacing."""
        self._check_open()
        arrays = _mesh_arrays(mesh)
        if replace is None and len(self._meshes) >= _MAX_GEOMETRIES:
            raise ValueError(f"at most {_MAX_GEOMETRIES} geometries")
        if replace is not None and not 0 <= replace < len(self._meshes):
            raise ValueError(f"replace must be in [0, {len(self._meshes)}), got {replace!r}")
        g = len(self._meshes) if replace is None else replace
        body, chunks = self._create_geometry(g, *arrays)
        prox = _proximity(arrays)
        if replace is None:
            self._meshes.append(arrays)
            self._proximity.append(prox)
            self.geometry_ids.append(body)
            self._chunks.append(chunks)
        else:
            cid, old = self._client, self.geometry_ids[g]
            p.removeBody(old, physicsClientId=cid)
            for b in (self._chunks[g] or {"bodies": []})["bodies"]:
                p.removeBody(b, physicsClientId=cid)
            del self._geometry_index[old]
            self._meshes[g], self._proximity[g], self.geometry_ids[g], self._chunks[g] = arrays, prox, body, chunks
            for i in np.flatnonzero(self.geometry == g).tolist():
                self._integrator.set_obstacle(i, prox)
        self._geometry_index[body] = g
        self._show_geometry(int(self.geometry[0]))
        return g

    def _proximity_of(self, g: int) -> MeshProximity | None:
        return self._proximity[g] if g >= 0 else None

    def enable_gui(self) -> None:
        """Move the world into a PyBullet GUI window (one per process; needs a display): the world
        is rebuilt in a new GUI client, every drone keeps its state; :attr:`client` changes, so call
        this before handing the client id to other modules."""
        self._check_open()
        if self._gui:
            return
        if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            raise RuntimeError("enable_gui needs a display (DISPLAY is not set)")
        plants, scales = list(self.plants), self.thrust_scales.copy()
        p.disconnect(physicsClientId=self._client)
        self._client = -1
        self._build_world(p.GUI)              # the flight core keeps every drone's state
        self._gui = True
        for i, (plant, scale) in enumerate(zip(plants, scales)):
            if plant is not self.params:
                self.set_plant(i, plant, float(scale))
        self._integrator.sync_bodies()

    # ------------------------------------------------------------------ drawing (drone 0's view)
    def _show_geometry(self, g: int) -> None:
        """Draw geometry ``g`` only (what drone 0 flies in; -1: none); with ``park_unused`` the
        others also leave the world."""
        if not self._render:
            return
        cid = self._client
        for k, body in enumerate(self.geometry_ids):
            if self._park:
                p.resetBasePositionAndOrientation(body, (0, 0, 0) if k == g else _PARKED, (0, 0, 0, 1),
                                                  physicsClientId=cid)
            if self._chunks[k] is None:
                p.changeVisualShape(body, -1, rgbaColor=(0.85, 0.85, 0.9, 1.0 if k == g else 0.0),
                                    physicsClientId=cid)
            else:
                show_chunks(cid, self._chunks[k], k == g)

    @property
    def obstacle_chunks(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(centres (K, 3), radii (K,)) of the bounding spheres of the drawn chunks of drone 0's
        turbine (only with an ``obstacle_texture``; else ``None``)."""
        g = int(self.geometry[0])
        chunks = self._chunks[g] if g >= 0 else None
        return None if chunks is None else (chunks["centers"], chunks["radii"])

    def show_obstacle_chunks(self, mask: Any = True) -> None:
        """Draw only the chunks of drone 0's turbine where ``mask`` is true (e.g. those a camera's
        frustum can see: TinyRenderer's cost grows with every triangle it is given, drawn or not);
        ``True`` draws them all. Drawing only: collisions and rays are unaffected."""
        g = int(self.geometry[0])
        if g >= 0:
            show_chunks(self._client, self._chunks[g], mask)

    @property
    def obstacle_id(self) -> int:
        """PyBullet body of drone 0's turbine geometry (-1 without one)."""
        g = int(self.geometry[0])
        return self.geometry_ids[g] if g >= 0 else -1

    def _mask(self, g: int) -> int:
        return GROUND_GROUP | (geometry_group(g) if g >= 0 else 0)

    def set_wind(self, i: int, wind: WindField | None) -> None:
        """Give drone ``i`` another wind field (used from its next reset on)."""
        self.winds[i] = wind
        self._set_varying()

    def _set_varying(self) -> None:
        """The drones whose wind changes in time, and their fields batched for the step."""
        self._varying = [j for j, w in enumerate(self.winds) if w is not None and not w.is_constant]
        self._varying_idx = np.array(self._varying, dtype=np.int64)
        self._wind_batch = WindBatch([self.winds[j] for j in self._varying])

    def set_geometry(self, i: int, g: int) -> None:
        """Let drone ``i`` collide with (and see) geometry ``g`` only (-1: the ground only)."""
        if not -1 <= g < len(self.geometry_ids):
            raise ValueError(f"geometry must be in [-1, {len(self.geometry_ids)}), got {g!r}")
        if self.geometry[i] != g:
            self._integrator.set_mask(i, self._mask(g))
            self._integrator.set_obstacle(i, self._proximity_of(g))
            self.geometry[i] = g
            if i == 0:
                self._show_geometry(g)

    # ------------------------------------------------------------------ lifetime
    @property
    def client(self) -> int:
        """The PyBullet client id (e.g. for ``p.rayTestBatch(..., physicsClientId=sim.client)``;
        an error once closed)."""
        self._check_open()
        return self._client

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` disconnected the client."""
        return self._client < 0

    def _check_open(self) -> None:
        if self._client < 0:
            raise RuntimeError("this BatchedQuadrotorSim is closed")

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self._client >= 0:
            try:
                p.disconnect(physicsClientId=self._client)
            finally:
                self._client = -1

    def __enter__(self) -> "BatchedQuadrotorSim":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass

    def sync_scene(self) -> None:
        """Put every drone's PyBullet body at its current pose (the flight core integrates free
        flight without PyBullet; renders of the scene call this first)."""
        self._integrator.sync_bodies()

    # ------------------------------------------------------------------ reset / state
    def reset_drone(self, i: int, state: np.ndarray, body_rates: Any = None, seed: int | None = None) -> None:
        """Place drone ``i`` at ``state`` = [p, v_body, q] with ``body_rates`` (3,) (default zero),
        rotors at its plant's hover thrust and rate-loop integrators at zero, and restart its clock.
        ``seed`` (if given) reseeds the drone's wind field first (``wind.reset(seed)``)."""
        x = checked_state(state)
        w_b = np.zeros(3) if body_rates is None else check_array("body_rates", body_rates, (3,))
        if seed is not None:
            if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
                raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
            if self.winds[i] is not None:
                self.winds[i].reset(int(seed))
        # Through PyBullet once, so the stored pose is exactly what Bullet would hold.
        cid, body = self._client, self.body_ids[i]
        place_body(cid, body, x, w_b)
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, omega = p.getBaseVelocity(body, physicsClientId=cid)
        self._integrator.core.reset(i, pos, quat, vel, omega, w_b)
        self._integrator.placed(i)
        self._version += 1
        self.steps[i] = 0
        self.in_collision[i] = False
        self.contact_points.pop(i, None)
        self.last_wind[i] = self._wind_at(i, 0.0)
    def _wind_at(self, i: int, t: float) -> np.ndarray:
        w = self.winds[i]
        if w is None:
            return np.zeros(3)
        return w(t, self.pos[i:i + 1])[0]

    def rotation(self) -> tuple[np.ndarray, ...]:
        """Body-to-world rotation entries (row-major) of every drone."""
        return bullet_rotation(self.quat)

    def body_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(state (n, 10), body rates (n, 3)), computed once per step or reset (the env layer reads
        them several times a step; compiled, :func:`bullet_rotation`'s arithmetic). The arrays are
        the simulator's own, rewritten in place: read them, do not keep or change them (:attr:`state`
        and :attr:`body_rates` hand out copies)."""
        if self._kin_key != self._version:
            from ..native import world_core as wc
            out, rates = self._kin_out, self._kin_rates
            wc.library().wt_body_frame(self.n, wc.addr(self.pos), wc.addr(self.vel), wc.addr(self.omega),
                                       wc.addr(self.quat), wc.addr(out), wc.addr(rates))
            self._kin, self._kin_key = (out, rates), self._version
        return self._kin

    @property
    def state(self) -> np.ndarray:
        """(n, 10) [position, body velocity, quaternion], as :attr:`QuadrotorSim.state` row by row."""
        return self.body_frame()[0].copy()

    @property
    def body_rates(self) -> np.ndarray:
        """(n, 3) body angular velocities (p, q, r) [rad/s]."""
        return self.body_frame()[1].copy()

    @property
    def time(self) -> np.ndarray:
        """Each drone's simulated time [s]."""
        return self.steps * self.dt

    # ------------------------------------------------------------------ stepping
    def step(self, commands: np.ndarray) -> None:
        """Hold ``commands`` (n, 4) = [p, q, r, T] per drone (finite, T >= 0) for one control period."""
        if self._varying:
            v = self._varying_idx
            self.last_wind[v] = self._wind_batch(self.steps[v] * self.dt, self.pos[v])
        integ = self._integrator
        integ.commands[:] = commands
        self.in_collision[:] = False
        self.contact_points.clear()
        integ.step(self._mark_contacts)
        self._version += 1
        self.steps += 1
        if self._gui:
            integ.sync_bodies()

    def _mark_contacts(self, i: int, substep: int, cps) -> None:
        """The integrator's contact sink: drone ``i`` touched the ground or its own geometry (a
        pair from a stale broadphase entry with another phase's geometry is not counted). The points of
        its last touching sub-step are kept in :attr:`contact_points`."""
        ground, gi, g = self.ground_id, self._geometry_index, self.geometry[i]
        for c in cps:
            other = c[2]
            if other == ground or gi.get(other, -2) == g:
                self.in_collision[i] = True
                self.contact_points[i] = cps
                return
