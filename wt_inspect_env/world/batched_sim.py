"""N quadrotors in one PyBullet client: the physics of :class:`~wt_inspect_env.world.sim.QuadrotorSim`, batched.

Every drone is its own rigid body in one ``DIRECT`` client that also holds the ground and one
static body per turbine geometry (phase 1, and the rotated phase-2 turbine). Collision groups keep
the drones apart: a drone collides with the ground and with the geometry of *its own* phase only,
never with another drone, and the camera rays of a drone see the ground and its geometry only. So
each drone lives in the world of a single :class:`QuadrotorSim`, and drone ``i`` under the same
commands follows the single simulator bit for bit (a test checks it).

Both simulators step their drones with the same :class:`~wt_inspect_env.world.integration.DroneIntegrator`:
one call into the compiled flight core advances every drone in free flight through all physics
sub-steps; only drones that may touch the ground or their geometry during the step are handed to
PyBullet. The wind stays per drone (each owns an arbitrary, seeded
:class:`~wt_inspect_env.physics.wind.WindField`), evaluated once per control step.
"""
from __future__ import annotations

import os
import sys
from typing import Any, Sequence

import numpy as np
import pybullet as p

from ..physics.quadrotor import QuadrotorParams
from ..physics.sim_config import SimConfig
from ..physics.wind import WindBatch, WindField
from ..planner.proximity import MeshProximity
from ..scene.pybullet_refs import call_releasing
from ..scene.scene_visuals import create_chunks, load_texture, show_chunks
from .integration import DroneIntegrator
from .sim import (
    DRONE_COLLISION_GROUP,
    _mesh_arrays,
    checked_plant,
    checked_state,
    create_drone_body,
    new_client,
    place_body,
)

GROUND_GROUP = 1
_GEOMETRY_GROUP0 = 16        # geometry g is in group 16 << g (phase 1, phase 2, ...)
_MAX_GEOMETRIES = 8


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
    with the one selected by :meth:`set_geometry` (0 after construction). ``winds``: one
    :class:`WindField` per drone (or None for still air); the owner reseeds them.
    """

    def __init__(self, params: QuadrotorParams, config: SimConfig, n: int,
                 geometries: Sequence[Any] = (), winds: Sequence[WindField | None] | None = None,
                 obstacle_texture: Any = None) -> None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"num_envs must be a positive integer, got {n!r}")
        if len(geometries) > _MAX_GEOMETRIES:
            raise ValueError(f"at most {_MAX_GEOMETRIES} geometries, got {len(geometries)}")
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
        self.geometry = np.zeros(n, dtype=np.int64)
        self._meshes = [_mesh_arrays(mesh) for mesh in geometries]
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
        """The integrator the drones' physics runs in."""
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
            texture_id = -1
            new_proximity = not hasattr(self, "_proximity")
            if new_proximity:
                self._proximity: list[MeshProximity] = []
            for g, (verts, idx) in enumerate(self._meshes):
                shape = call_releasing(p.createCollisionShape, p.GEOM_MESH, vertices=verts, indices=idx,
                                       flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid)
                chunks = None
                if self._render and self.obstacle_texture is None:
                    visual = call_releasing(p.createVisualShape, p.GEOM_MESH, vertices=verts, indices=idx,
                                            rgbaColor=(0.85, 0.85, 0.9, 1.0), physicsClientId=cid)
                    body = p.createMultiBody(0.0, shape, baseVisualShapeIndex=visual, physicsClientId=cid)
                else:
                    body = p.createMultiBody(0.0, shape, physicsClientId=cid)
                    if self._render:        # drawn as textured chunks, the collision body invisible
                        p.changeVisualShape(body, -1, rgbaColor=(1, 1, 1, 0), physicsClientId=cid)
                        if texture_id < 0:
                            texture_id = load_texture(cid, self.obstacle_texture.image())
                        chunks = create_chunks(cid, texture_id, self.obstacle_texture, np.asarray(verts),
                                               np.asarray(idx).reshape(-1, 3))
                p.setCollisionFilterGroupMask(body, -1, geometry_group(g), 0xFFFF, physicsClientId=cid)
                self.geometry_ids.append(body)
                self._chunks.append(chunks)
                if new_proximity:
                    self._proximity.append(MeshProximity(np.asarray(verts)[np.asarray(idx).reshape(-1, 3)]))
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
                self._integrator.set_obstacle(i, self._proximity[self.geometry[i]] if self._proximity else None)
            self._show_geometry(int(self.geometry[0]))
        except BaseException:
            self.close()
            raise

    def enable_gui(self) -> None:
        """Move the world into a PyBullet GUI window (one per process; needs a display): the world
        is rebuilt in a new GUI client, every drone keeps its state; :attr:`client` changes."""
        if self._gui:
            return
        if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            raise RuntimeError("enable_gui needs a display (DISPLAY is not set)")
        plants, scales = list(self.plants), self.thrust_scales.copy()
        p.disconnect(physicsClientId=self._client)
        self._client = -1
        self._build_world(p.GUI)
        self._gui = True
        for i, (plant, scale) in enumerate(zip(plants, scales)):
            if plant is not self.params:
                self.set_plant(i, plant, float(scale))
        self._integrator.sync_bodies()

    # ------------------------------------------------------------------ drawing (drone 0's view)
    def _show_geometry(self, g: int) -> None:
        """Draw geometry ``g`` only (what drone 0 flies in)."""
        if not self._render:
            return
        for k, body in enumerate(self.geometry_ids):
            if self._chunks[k] is None:
                p.changeVisualShape(body, -1, rgbaColor=(0.85, 0.85, 0.9, 1.0 if k == g else 0.0),
                                    physicsClientId=self._client)
            else:
                show_chunks(self._client, self._chunks[k], k == g)

    @property
    def obstacle_chunks(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(centres (K, 3), radii (K,)) of the bounding spheres of the drawn chunks of drone 0's
        turbine (only with an ``obstacle_texture``; else ``None``)."""
        chunks = self._chunks[int(self.geometry[0])] if self._chunks else None
        return None if chunks is None else (chunks["centers"], chunks["radii"])

    def show_obstacle_chunks(self, mask: Any = True) -> None:
        """Draw only the chunks of drone 0's turbine where ``mask`` is true (e.g. those a camera's
        frustum can see); ``True`` draws them all. Drawing only: collisions and rays are unaffected."""
        if self._chunks:
            show_chunks(self._client, self._chunks[int(self.geometry[0])], mask)

    @property
    def obstacle_id(self) -> int:
        """PyBullet body of drone 0's turbine geometry (-1 without one)."""
        return self.geometry_ids[int(self.geometry[0])] if self.geometry_ids else -1

    def _mask(self, g: int) -> int:
        return GROUND_GROUP | (geometry_group(g) if self.geometry_ids else 0)

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
        """Let drone ``i`` collide with (and see) geometry ``g`` only."""
        if not 0 <= g < len(self.geometry_ids):
            raise ValueError(f"geometry must be in [0, {len(self.geometry_ids)}), got {g!r}")
        if self.geometry[i] != g:
            self._integrator.set_mask(i, self._mask(g))
            self._integrator.set_obstacle(i, self._proximity[g])
            self.geometry[i] = g
            if i == 0:
                self._show_geometry(g)

    @property
    def client(self) -> int:
        """The PyBullet client id (an error once closed)."""
        if self._client < 0:
            raise RuntimeError("this BatchedQuadrotorSim is closed")
        return self._client

    def close(self) -> None:
        """Disconnect the PyBullet client (idempotent)."""
        if self._client >= 0:
            try:
                p.disconnect(physicsClientId=self._client)
            finally:
                self._client = -1

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass

    def sync_scene(self) -> None:
        """Put every drone's PyBullet body at its current pose (for renders of the scene)."""
        self._integrator.sync_bodies()

    # ------------------------------------------------------------------ reset / state
    def reset_drone(self, i: int, state: np.ndarray) -> None:
        """Place drone ``i`` at ``state`` = [p, v_body, q] at rest in the rate loop (as
        :meth:`QuadrotorSim.reset` with zero body rates) and restart its clock."""
        x = checked_state(state)
        cid, body = self._client, self.body_ids[i]
        place_body(cid, body, x, np.zeros(3))
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, omega = p.getBaseVelocity(body, physicsClientId=cid)
        self._integrator.core.reset(i, pos, quat, vel, omega, np.zeros(3))
        self._integrator.placed(i)
        self._version += 1
        self.steps[i] = 0
        self.in_collision[i] = False
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
        integ.step(self._mark_contacts)
        self._version += 1
        self.steps += 1
        if self._gui:
            integ.sync_bodies()

    def _mark_contacts(self, i: int, substep: int, cps) -> None:
        """The integrator's contact sink: drone ``i`` touched the ground or its own geometry (a
        pair from a stale broadphase entry with another phase's geometry is not counted)."""
        ground, gi = self.ground_id, self._geometry_index
        for c in cps:
            other = c[2]
            if other == ground or gi.get(other, -1) == self.geometry[i]:
                self.in_collision[i] = True
                return
