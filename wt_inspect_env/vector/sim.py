"""N quadrotors in one PyBullet client: the physics of :class:`~wt_inspect_env.sim.QuadrotorSim`, batched.

Every drone is its own rigid body in one ``DIRECT`` client that also holds the ground and one
static body per turbine geometry (phase 1, and the rotated phase-2 turbine). Collision groups keep
the drones apart: a drone collides with the ground and with the geometry of *its own* phase only,
never with another drone, and the camera rays of a drone see the ground and its geometry only. So
each drone lives in the world of a single :class:`QuadrotorSim`, and drone ``i`` under the same
commands follows the single simulator bit for bit (a test checks it).

What is batched: the PX4-like rate PID, the mixer's unsaturated path, the motor lag, the drag and the
rotation matrices are NumPy operations over all drones, written with the same floating-point
operations in the same order as the scalar code of :class:`QuadrotorSim` (products and sums in the
same association, the rotation matrix with Bullet's own quaternion formula), which is what makes
the results identical rather than merely close.

Where a per-drone Python loop remains, and why:

* applying the wrench and reading the pose and velocity back: PyBullet has no batched calls for
  ``applyExternalForce``/``applyExternalTorque``/``getBasePositionAndOrientation``/``getBaseVelocity``;
  these four calls per drone and physics sub-step are most of what a drone-step costs;
* the mixer when a rotor saturates: the desaturation logic is branchy (priorities, rescaling) and
  rare in flight, so the drones that need it run the scalar :meth:`Mixer.mix`;
* the wind: each drone owns an arbitrary, seeded :class:`~wt_inspect_env.wind.WindField` (a user
  callable in general), evaluated once per control step.

One ``stepSimulation`` and one ``getContactPoints`` per sub-step serve all drones.
"""
from __future__ import annotations

from itertools import chain

_flat = chain.from_iterable
from typing import Any, Sequence

import numpy as np
import pybullet as p

from ..quadrotor import QuadrotorParams
from ..pybullet_refs import call_releasing
from ..rate_control import Mixer, RateController, RateGains, mix_saturated
from ..sim import (DRONE_COLLISION_GROUP, SimConfig, SubstepConstants, _mesh_arrays, checked_plant, checked_state,
                   create_drone_body, new_client, place_body)
from ..wind import WindField, wind_velocities

GROUND_GROUP = 1
_GEOMETRY_GROUP0 = 16        # geometry g is in group 16 << g (phase 1, phase 2, ...)
_MAX_GEOMETRIES = 8


def geometry_group(g: int) -> int:
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
                 geometries: Sequence[Any] = (), winds: Sequence[WindField | None] | None = None) -> None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"num_envs must be a positive integer, got {n!r}")
        if not config.rate_loop or config.per_rotor_forces:
            raise ValueError("the batched simulator supports rate_loop=True, per_rotor_forces=False only, "
                             f"got rate_loop={config.rate_loop!r}, per_rotor_forces={config.per_rotor_forces!r}")
        if len(geometries) > _MAX_GEOMETRIES:
            raise ValueError(f"at most {_MAX_GEOMETRIES} geometries, got {len(geometries)}")
        self.n = n = int(n)
        self.params, self.config = params, config
        winds = [None] * n if winds is None else list(winds)
        if len(winds) != n:
            raise ValueError(f"winds must hold one field per drone ({n}), got {len(winds)}")
        self.winds = winds
        self._varying = [i for i, w in enumerate(winds) if w is not None and not w.is_constant]
        self.dt = 1.0 / config.ctrl_hz
        self.physics_dt = 1.0 / config.physics_hz
        self._n_sub = config.substeps
        gains = config.rate_gains or RateGains.for_params(params)
        # The scalar controller is the source of the folded gains (and of the reference semantics).
        ref = RateController(gains, params.inertia, self.physics_dt)
        self._kp, self._kd, self._ki_dt, self._J = ref._kp, ref._kd, ref._ki_dt, ref._J
        self._ilim = tuple(float(x) for x in gains.integral_limit)
        self._d_beta = ref._beta
        self.mixer = Mixer(params)
        B = self.mixer
        self._bt, self._bx, self._by, self._bz = B._bt, B._bx, B._by, B._bz
        k = SubstepConstants.of(params, config, self.mixer)
        self._alpha, self._beta, self._A_tau = k.alpha, k.beta, k.A_tau
        self._lin_drag, self._quad_drag, self._has_drag = k.lin_drag, k.quad_drag, k.has_drag

        self._client = -1
        self._build_world(geometries)
        z = np.zeros((n, 3))
        self.pos, self.vel, self.omega = z.copy(), z.copy(), z.copy()
        self.quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
        self.f = np.full((n, 4), params.weight / 4.0)
        # Rate-loop state axis-major (3, n), so each axis is one contiguous row for the NumPy ops.
        self.i_term, self.d_term, self.prev_rates = np.zeros((3, n)), np.zeros((3, n)), np.zeros((3, n))
        self.saturation = np.zeros((3, n), dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        self.in_collision = np.zeros(n, dtype=bool)
        self.last_wind = z.copy()
        self.geometry = np.zeros(n, dtype=np.int64)
        self.plants: list[QuadrotorParams] = [params] * n
        self._thrust_scale: np.ndarray | None = None    # per drone, once a plant differs (set_plant)

    # ------------------------------------------------------------------ plants
    def set_plant(self, i: int, plant: QuadrotorParams | None = None, thrust_scale: float = 1.0) -> None:
        """:meth:`QuadrotorSim.set_plant` for drone ``i``: its physics (mass, inertia, motor lag, drag,
        the wrench's torque rows, a thrust factor) follow ``plant``, the controller side stays
        ``params``. The per-sub-step constants become per-drone arrays on the first call (the same
        elementwise operations, so each drone still matches the single simulator bit for bit)."""
        plant = checked_plant(self.params, plant, thrust_scale)
        n = self.n
        if self._thrust_scale is None:      # scalars -> per-drone arrays
            self._alpha, self._beta = np.full(n, self._alpha), np.full(n, self._beta)
            self._A_tau = tuple(tuple(np.full(n, a) for a in row) for row in self._A_tau)
            self._lin_drag = tuple(np.full(n, d) for d in self._lin_drag)
            self._quad_drag = tuple(np.full(n, d) for d in self._quad_drag)
            self._thrust_scale = np.ones(n)
        k = SubstepConstants.of(plant, self.config, self.mixer if plant is self.params else Mixer(plant))
        self._alpha[i], self._beta[i] = k.alpha, k.beta
        for row, vals in zip(self._A_tau, k.A_tau):
            for arr, v in zip(row, vals):
                arr[i] = v
        for arr, v in zip(self._lin_drag + self._quad_drag, k.lin_drag + k.quad_drag):
            arr[i] = v
        self._has_drag = self._has_drag or k.has_drag
        self._thrust_scale[i] = float(thrust_scale)
        self.plants[i] = plant
        p.changeDynamics(self.body_ids[i], -1, mass=plant.mass, localInertiaDiagonal=list(plant.inertia),
                         physicsClientId=self._client)

    # ------------------------------------------------------------------ world
    def _build_world(self, geometries: Sequence[Any]) -> None:
        params, config, n = self.params, self.config, self.n
        cid = self._client = new_client(p.DIRECT, self.physics_dt)
        try:
            self.ground_id = -1
            if config.ground:
                plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
                self.ground_id = p.createMultiBody(0.0, plane, basePosition=[0, 0, config.ground_height],
                                                   physicsClientId=cid)
                p.setCollisionFilterGroupMask(self.ground_id, -1, GROUND_GROUP, 0xFFFF, physicsClientId=cid)
            self.geometry_ids: list[int] = []
            for g, mesh in enumerate(geometries):
                verts, idx = _mesh_arrays(mesh)
                shape = call_releasing(p.createCollisionShape, p.GEOM_MESH, vertices=verts, indices=idx,
                                       flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid)
                body = p.createMultiBody(0.0, shape, physicsClientId=cid)
                p.setCollisionFilterGroupMask(body, -1, geometry_group(g), 0xFFFF, physicsClientId=cid)
                self.geometry_ids.append(body)
            box = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(params.collision_half_extents),
                                         physicsClientId=cid)
            self.body_ids: list[int] = []
            for _ in range(n):
                self.body_ids.append(create_drone_body(cid, params, box))
            self._drone_index = {b: i for i, b in enumerate(self.body_ids)}
            self._geometry_index = {b: g for g, b in enumerate(self.geometry_ids)}
            for i in range(n):
                self._apply_mask(i, 0)
        except BaseException:
            self.close()
            raise

    def _apply_mask(self, i: int, g: int) -> None:
        mask = GROUND_GROUP | (geometry_group(g) if self.geometry_ids else 0)
        p.setCollisionFilterGroupMask(self.body_ids[i], -1, DRONE_COLLISION_GROUP, mask,
                                      physicsClientId=self._client)

    def set_wind(self, i: int, wind: WindField | None) -> None:
        """Give drone ``i`` another wind field (used from its next reset on)."""
        self.winds[i] = wind
        self._varying = [j for j, w in enumerate(self.winds) if w is not None and not w.is_constant]

    def set_geometry(self, i: int, g: int) -> None:
        """Let drone ``i`` collide with (and see) geometry ``g`` only."""
        if not 0 <= g < len(self.geometry_ids):
            raise ValueError(f"geometry must be in [0, {len(self.geometry_ids)}), got {g!r}")
        if self.geometry[i] != g:
            self._apply_mask(i, g)
            self.geometry[i] = g

    @property
    def client(self) -> int:
        if self._client < 0:
            raise RuntimeError("this BatchedQuadrotorSim is closed")
        return self._client

    def close(self) -> None:
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

    # ------------------------------------------------------------------ reset / state
    def reset_drone(self, i: int, state: np.ndarray) -> None:
        """Place drone ``i`` at ``state`` = [p, v_body, q] at rest in the rate loop (as
        :meth:`QuadrotorSim.reset` with zero body rates) and restart its clock."""
        x = checked_state(state)
        cid, body = self._client, self.body_ids[i]
        place_body(cid, body, x, np.zeros(3))
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        vel, omega = p.getBaseVelocity(body, physicsClientId=cid)
        self.pos[i], self.quat[i], self.vel[i], self.omega[i] = pos, quat, vel, omega
        self.steps[i] = 0
        self.i_term[:, i] = self.d_term[:, i] = self.prev_rates[:, i] = 0.0
        self.saturation[:, i] = 0
        ts = 1.0 if self._thrust_scale is None else float(self._thrust_scale[i])
        self.f[i] = self.plants[i].weight / ts / 4.0      # as QuadrotorSim.reset: the plant's hover
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

    @property
    def state(self) -> np.ndarray:
        """(n, 10) [position, body velocity, quaternion], as :attr:`QuadrotorSim.state` row by row."""
        R = self.rotation()
        vx, vy, vz = self.vel[:, 0], self.vel[:, 1], self.vel[:, 2]
        out = np.empty((self.n, 10))
        out[:, 0:3] = self.pos
        out[:, 3] = R[0] * vx + R[3] * vy + R[6] * vz
        out[:, 4] = R[1] * vx + R[4] * vy + R[7] * vz
        out[:, 5] = R[2] * vx + R[5] * vy + R[8] * vz
        out[:, 6:10] = self.quat
        return out

    @property
    def body_rates(self) -> np.ndarray:
        R = self.rotation()
        ox, oy, oz = self.omega[:, 0], self.omega[:, 1], self.omega[:, 2]
        return np.stack([R[0] * ox + R[3] * oy + R[6] * oz,
                         R[1] * ox + R[4] * oy + R[7] * oz,
                         R[2] * ox + R[5] * oy + R[8] * oz], axis=1)

    @property
    def time(self) -> np.ndarray:
        return self.steps * self.dt

    # ------------------------------------------------------------------ stepping
    def step(self, commands: np.ndarray) -> None:
        """Hold ``commands`` (n, 4) = [p, q, r, T] per drone (finite, T >= 0) for one control period."""
        n = self.n
        if self._varying:
            self.last_wind[self._varying] = wind_velocities([self.winds[i] for i in self._varying],
                                                            self.steps[self._varying] * self.dt,
                                                            self.pos[self._varying])
        pc, qc, rc, T = (np.ascontiguousarray(commands[:, k]) for k in range(4))
        wx, wy, wz = self.last_wind[:, 0], self.last_wind[:, 1], self.last_wind[:, 2]
        cid = self._client
        bodies = self.body_ids
        applyForce, applyTorque = p.applyExternalForce, p.applyExternalTorque
        stepSim, getPose, getVel = p.stepSimulation, p.getBasePositionAndOrientation, p.getBaseVelocity
        getContacts = p.getContactPoints
        LINK = p.LINK_FRAME
        zero = (0.0, 0.0, 0.0)
        alpha, beta = self._alpha, self._beta
        (a10, a11, a12, a13), (a20, a21, a22, a23), (a30, a31, a32, a33) = self._A_tau
        ts = self._thrust_scale
        dlx, dly, dlz = self._lin_drag
        dqx, dqy, dqz = self._quad_drag
        bt, bx, by, bz = self._bt, self._bx, self._by, self._bz
        f_lo, f_hi = self.mixer.f_min, self.mixer.f_max
        f = self.f
        f0, f1, f2, f3 = f[:, 0].copy(), f[:, 1].copy(), f[:, 2].copy(), f[:, 3].copy()
        pos, quat, vel, omega = self.pos, self.quat, self.vel, self.omega
        touched = np.zeros(n, dtype=bool)
        for _ in range(self._n_sub):
            R = bullet_rotation(quat)
            ox, oy, oz = omega[:, 0], omega[:, 1], omega[:, 2]
            pm = R[0] * ox + R[3] * oy + R[6] * oz
            qm = R[1] * ox + R[4] * oy + R[7] * oz
            rm = R[2] * ox + R[5] * oy + R[8] * oz
            tx, ty, tz = self._rate_pid(pc, qc, rc, pm, qm, rm)
            c0 = T * bt[0] + tx * bx[0] + ty * by[0] + tz * bz[0]
            c1 = T * bt[1] + tx * bx[1] + ty * by[1] + tz * bz[1]
            c2 = T * bt[2] + tx * bx[2] + ty * by[2] + tz * bz[2]
            c3 = T * bt[3] + tx * bx[3] + ty * by[3] + tz * bz[3]
            ok = ((f_lo <= c0) & (c0 <= f_hi) & (f_lo <= c1) & (c1 <= f_hi) & (f_lo <= c2) & (c2 <= f_hi)
                  & (f_lo <= c3) & (c3 <= f_hi))
            self.saturation[:, ok] = 0
            if not ok.all():   # the saturated drones take the desaturating mixer, batched
                idx = np.flatnonzero(~ok)
                (c0[idx], c1[idx], c2[idx], c3[idx]), self.saturation[:, idx] = mix_saturated(
                    self.mixer, T[idx], tx[idx], ty[idx], tz[idx])
            g0 = f0 + beta * (c0 - f0)
            g1 = f1 + beta * (c1 - f1)
            g2 = f2 + beta * (c2 - f2)
            g3 = f3 + beta * (c3 - f3)
            f0 = f0 + alpha * (c0 - f0)
            f1 = f1 + alpha * (c1 - f1)
            f2 = f2 + alpha * (c2 - f2)
            f3 = f3 + alpha * (c3 - f3)
            if ts is not None:                # randomised plants' thrust factors (set_plant)
                g0, g1, g2, g3 = g0 * ts, g1 * ts, g2 * ts, g3 * ts
            if self._has_drag:
                ax_, ay_, az_ = vel[:, 0] - wx, vel[:, 1] - wy, vel[:, 2] - wz
                bxv = R[0] * ax_ + R[3] * ay_ + R[6] * az_
                byv = R[1] * ax_ + R[4] * ay_ + R[7] * az_
                bzv = R[2] * ax_ + R[5] * ay_ + R[8] * az_
                sp = np.sqrt(bxv * bxv + byv * byv + bzv * bzv)
                dx = -(dlx + dqx * sp) * bxv
                dy = -(dly + dqy * sp) * byv
                dz = -(dlz + dqz * sp) * bzv
            else:
                dx = dy = dz = np.zeros(n)
            force = np.stack([dx, dy, dz + g0 + g1 + g2 + g3], axis=1).tolist()
            torque = np.stack([a10 * g0 + a11 * g1 + a12 * g2 + a13 * g3,
                               a20 * g0 + a21 * g1 + a22 * g2 + a23 * g3,
                               a30 * g0 + a31 * g1 + a32 * g2 + a33 * g3], axis=1).tolist()
            for b, fo, to in zip(bodies, force, torque):    # no batched PyBullet call (module doc)
                applyForce(b, -1, fo, zero, LINK, physicsClientId=cid)
                applyTorque(b, -1, to, LINK, physicsClientId=cid)
            stepSim(physicsClientId=cid)
            states = [(getPose(b, physicsClientId=cid), getVel(b, physicsClientId=cid)) for b in bodies]
            flat = np.fromiter(_flat(_flat(_flat(states))), float, 13 * n).reshape(n, 13)
            pos, quat, vel, omega = flat[:, 0:3], flat[:, 3:7], flat[:, 7:10], flat[:, 10:13]
            cps = getContacts(physicsClientId=cid)
            if cps:
                self._mark_contacts(cps, touched)
        self.f = np.stack([f0, f1, f2, f3], axis=1)
        self.pos, self.quat, self.vel, self.omega = pos, quat, vel, omega
        self.in_collision = touched
        self.steps += 1

    def _rate_pid(self, pc, qc, rc, pm, qm, rm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`RateController.update` over all drones (same operations; anti-windup per axis)."""
        beta = self._d_beta
        d, prev, it = self.d_term, self.prev_rates, self.i_term
        e = (pc - pm, qc - qm, rc - rm)
        meas = (pm, qm, rm)
        out = []
        for k in range(3):
            dk = d[k] + beta * ((meas[k] - prev[k]) - d[k])
            d[k] = dk
            prev[k] = meas[k]
            sk = self.saturation[k]
            frozen = (sk != 0) & ((e[k] > 0) == (sk > 0))
            ik = it[k] + self._ki_dt[k] * e[k]
            lim = self._ilim[k]
            ik = np.where(ik > lim, lim, np.where(ik < -lim, -lim, ik))
            it[k] = np.where(frozen, it[k], ik)
            out.append(self._kp[k] * e[k] + self._J[k] * it[k] - self._kd[k] * dk)
        return out[0], out[1], out[2]

    _CONTACT_TOL = 1e-3   # as QuadrotorSim: Bullet keeps points a little beyond touching

    def _mark_contacts(self, cps, touched: np.ndarray) -> None:
        """Flag drones touching the ground or their own geometry (pairs from a stale broadphase
        entry with another phase's geometry are not counted)."""
        di, gi, ground = self._drone_index, self._geometry_index, self.ground_id
        for c in cps:
            if c[8] > self._CONTACT_TOL:
                continue
            for me, other in ((c[1], c[2]), (c[2], c[1])):
                i = di.get(me)
                if i is None:
                    continue
                if other == ground or gi.get(other, -1) == self.geometry[i]:
                    touched[i] = True
