"""Advancing drones one control step: the compiled core in free flight, PyBullet where they may touch.

:class:`DroneIntegrator` is the stepping loop of the simulator
(:class:`~wt_inspect_env.world.batched_sim.BatchedQuadrotorSim`, any ``n``; the single
:class:`~wt_inspect_env.world.sim.QuadrotorSim` is its front with ``n = 1``). Each control step it
splits the drones in two:

* **free** drones - those that provably cannot touch the ground or their turbine before the step
  ends - are advanced through all physics sub-steps by one call into the compiled
  :class:`~wt_inspect_env.physics.flight_core.FlightCore` (no PyBullet call at all);
* **near** drones are advanced by PyBullet as before: per sub-step the core computes the controller
  side (rate PID, mixer, motor lag, drag) and PyBullet applies the wrench, integrates the body with
  its contact constraints and reports the contact points. Bullet's free-body step is what the core
  reproduces, so a drone moves the same either way and the hand-over is seamless.

"Provably" is a bound, not a guess: a drone travels at most ``|v| dt + a_max dt^2 / 2`` in a
control step (``a_max`` from full rotor thrust, gravity and drag at the drone's airspeed); it is
free when its box (its circumscribed sphere) plus that reach plus a margin stays above the ground
and clear of the turbine, whose distance comes from the exact
:meth:`~wt_inspect_env.planner.proximity.MeshProximity.distance_within`. The clearance is re-measured only
when the reach since the last measurement could have used it up, so a drone flying metres from the
blade costs one mesh query every few dozen steps.

``integrator="bullet"`` (``SimConfig``) sends every drone through PyBullet on every step - the
reference that the physics-difference measurement and the tests compare the compiled path with.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
import pybullet as p

from ..physics.flight_core import FlightCore
from ..physics.quadrotor import QuadrotorParams
from ..physics.sim_config import SimConfig
from ..planner.proximity import MeshProximity

CONTACT_TOL = 1e-3       # Bullet keeps points a little beyond touching; count only real contact
_MARGIN = 0.1            # [m] beyond the box's sphere and the reach: Bullet's collision margins
_CHECK_AHEAD = 4.0       # [m] a clearance measurement looks this far beyond what the step needs
_FAR = 1.0e30
_PARK_Z = -1.0e4         # [m] where the bodies of free-flying drones wait

ContactSink = Callable[[int, int, Sequence[Any]], None]   # (drone, sub-step, contact points)


class DroneIntegrator:
    """Steps ``len(bodies)`` drones of one PyBullet client (see the module docstring).

    ``bodies``: the drones' PyBullet body ids; ``masks``: each body's collision mask while it is
    near (the simulator's collision-group rule); ``ground_height``: z of the ground plane, or None
    without a ground. :meth:`set_obstacle` gives drone ``i`` its turbine's proximity structure.
    """

    def __init__(self, params: QuadrotorParams, config: SimConfig, cid: int, bodies: Sequence[int],
                 masks: Sequence[int], ground_height: float | None, drone_group: int) -> None:
        self.params, self.config = params, config
        self.n = n = len(bodies)
        self.core = FlightCore(params, config, n)
        self._cid = cid
        self.bodies = list(bodies)
        self.masks = list(masks)
        self._group = drone_group
        self._ground = ground_height
        self.dt = 1.0 / config.ctrl_hz
        self._n_sub = config.substeps
        self._all_bullet = config.integrator == "bullet"
        self._per_rotor = bool(config.per_rotor_forces)
        self._rotor_pos = [tuple(float(c) for c in r) for r in params.rotor_positions]
        self._radius = float(np.linalg.norm(params.collision_half_extents))
        self._obstacles: list[MeshProximity | None] = [None] * n
        self._free = np.full(n, -_FAR)          # clearance left before a contact is possible [m]
        self._in_bullet = np.zeros(n, dtype=bool)   # the body holds the drone's current state
        self._f_max = 4.0 * float(params.max_rotor_thrust)
        self.commands = self.core.commands      # (n, 4) written by the simulator before each step
        self.winds = self.core.winds            # (n, 3)
        self._reach = np.zeros(n)
        self._code = np.zeros(n, dtype=np.int8)
        self.near_steps = 0                      # drone-steps PyBullet integrated (diagnostics)
        self.free_steps = 0

    # ------------------------------------------------------------------ scene
    def set_obstacle(self, i: int, proximity: MeshProximity | None) -> None:
        """Drone ``i`` collides with the mesh of ``proximity`` from now on (None: no obstacle)."""
        self._obstacles[i] = proximity
        self._free[i] = -_FAR

    def forget_clearance(self, i: int) -> None:
        """Drone ``i``'s clearance to its turbine is measured again before its next free step
        (its obstacle was put back in place)."""
        self._free[i] = -_FAR

    def set_mask(self, i: int, mask: int) -> None:
        """Drone ``i``'s collision mask while near (applied now if its body is in use)."""
        self.masks[i] = mask
        if self._in_bullet[i]:
            p.setCollisionFilterGroupMask(self.bodies[i], -1, self._group, mask, physicsClientId=self._cid)

    def rebind(self, cid: int, bodies: Sequence[int]) -> None:
        """The same drones in another client (a GUI window): their bodies are placed on demand."""
        if len(bodies) != self.n:
            raise ValueError(f"rebind needs {self.n} bodies, got {len(bodies)}")
        self._cid, self.bodies = cid, list(bodies)
        self._in_bullet[:] = False
        self._free[:] = -_FAR

    def placed(self, i: int) -> None:
        """Drone ``i`` was reset: its clearance is unknown and its body must be re-placed."""
        self._free[i] = -_FAR
        self._release(np.array([i]))

    def sync_bodies(self, idx: Sequence[int] | None = None) -> None:
        """Put the PyBullet bodies at the drones' current poses (for rendering and GUI views)."""
        for i in range(self.n) if idx is None else idx:
            if not self._in_bullet[i]:
                self._place(i)

    def _place(self, i: int) -> None:
        """Drone ``i``'s PyBullet body at the core's pose and velocities."""
        core, cid = self.core, self._cid
        p.resetBasePositionAndOrientation(self.bodies[i], core.pos[i].tolist(), core.quat[i].tolist(),
                                          physicsClientId=cid)
        p.resetBaseVelocity(self.bodies[i], core.vel[i].tolist(), core.omega[i].tolist(), physicsClientId=cid)

    # ------------------------------------------------------------------ stepping
    def step(self, sink: ContactSink | None = None) -> None:
        """Advance every drone one control step with :attr:`commands` (n, 4) and :attr:`winds`
        (n, 3) (written by the simulator beforehand). ``sink(i, substep, points)`` receives the
        contact points (PyBullet tuples, within :data:`CONTACT_TOL`) of every sub-step in which a
        near drone touches something."""
        core, n = self.core, self.n
        if self._all_bullet:
            self._step_in_bullet(np.arange(n), sink)
            self.near_steps += n
            return
        need0 = self._radius + _MARGIN
        if core.screen(self.dt, self._f_max, self._ground, need0, self._free, self._reach, self._code) == 0:
            if self._in_bullet.any():
                self._release(np.flatnonzero(self._in_bullet))
            core.step()
            self.free_steps += n
            return
        code, reach = self._code, self._reach
        for i in np.flatnonzero(code == 2).tolist():     # clearance to the turbine used up: measure again
            prox = self._obstacles[i]
            if prox is None:
                free = _FAR
            else:
                free = float(prox.distance_within(core.pos[i:i + 1], reach[i] + need0 + _CHECK_AHEAD)[0]) - need0
            if free >= reach[i]:
                code[i] = 0
                free -= reach[i]
            self._free[i] = free
        near = code != 0
        free_idx = np.flatnonzero(~near)
        if len(free_idx):
            back = free_idx[self._in_bullet[free_idx]]
            if len(back):
                self._release(back)
            core.step(free_idx)
            self.free_steps += len(free_idx)
        near_idx = np.flatnonzero(near)
        if len(near_idx):
            self._free[near_idx] = -_FAR          # measured again once they leave the ground's reach
            self._step_in_bullet(near_idx, sink)
            self.near_steps += len(near_idx)

    def _release(self, idx: np.ndarray) -> None:
        """Bodies of drones the core integrates again leave the collision world (mask 0), so they
        neither collide nor cost the solver while PyBullet steps the near ones."""
        for i in idx.tolist():
            p.setCollisionFilterGroupMask(self.bodies[i], -1, self._group, 0, physicsClientId=self._cid)
            # ... and wait far from the scene, so they are not in the way of the camera rays' search
            p.resetBasePositionAndOrientation(self.bodies[i], (10.0 * i, 0.0, _PARK_Z), (0.0, 0.0, 0.0, 1.0),
                                              physicsClientId=self._cid)
        self._in_bullet[idx] = False

    def _step_in_bullet(self, idx: np.ndarray, sink: ContactSink | None) -> None:
        core, cid = self.core, self._cid
        bodies = [self.bodies[i] for i in idx.tolist()]
        for i, b in zip(idx.tolist(), bodies):
            if not self._in_bullet[i]:
                self._place(i)
                p.setCollisionFilterGroupMask(b, -1, self._group, self.masks[i], physicsClientId=cid)
                self._in_bullet[i] = True
        applyForce, applyTorque, LINK = p.applyExternalForce, p.applyExternalTorque, p.LINK_FRAME
        getPose, getVel, getContacts = p.getBasePositionAndOrientation, p.getBaseVelocity, p.getContactPoints
        zero = (0.0, 0.0, 0.0)
        imposed = not self.config.rate_loop
        per_rotor = self._per_rotor and not imposed
        for s in range(self._n_sub):
            if per_rotor:
                f_before = core.rotor[idx].copy()
            force, torque = core.wrench(idx)
            if per_rotor:   # the four mean rotor thrusts at the rotor positions instead of their resultant
                k = (core.beta[idx] / core.alpha[idx])[:, None]
                g = (f_before + k * (core.rotor[idx] - f_before)) * core.thrust_scale[idx][:, None]
            for j, (i, b) in enumerate(zip(idx.tolist(), bodies)):
                if imposed:
                    p.resetBaseVelocity(b, angularVelocity=core.omega[i].tolist(), physicsClientId=cid)
                if per_rotor:
                    for pos_r, f_r in zip(self._rotor_pos, g[j].tolist()):
                        applyForce(b, -1, (0.0, 0.0, f_r), pos_r, LINK, physicsClientId=cid)
                    fx, fy, fz = force[j].tolist()
                    applyForce(b, -1, (fx, fy, fz - float(g[j].sum())), zero, LINK, physicsClientId=cid)
                    applyTorque(b, -1, (0.0, 0.0, float(torque[j, 2])), LINK, physicsClientId=cid)
                else:
                    applyForce(b, -1, force[j].tolist(), zero, LINK, physicsClientId=cid)
                    applyTorque(b, -1, torque[j].tolist(), LINK, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
            for i, b in zip(idx.tolist(), bodies):
                pos, quat = getPose(b, physicsClientId=cid)
                vel, omega = getVel(b, physicsClientId=cid)
                core.set_state(i, pos, quat, vel, omega)
                if sink is not None:
                    cps = getContacts(bodyA=b, physicsClientId=cid)
                    if cps:
                        touching = [c for c in cps if c[8] <= CONTACT_TOL]
                        if touching:
                            sink(i, s, touching)
