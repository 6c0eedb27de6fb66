"""The compiled flight core against its references: the Python rate loop and mixer, PyBullet's own
integrator (free flight, randomised plants, imposed rates) and PyBullet's contacts (crafted
approaches into a blade face, a blade tip, the tower and the ground, for N = 1 and N = 64)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from wt_inspect.commands.bench_sim import excitation, integrator_difference
from wt_inspect_env.physics.dynamics import hover_state
from wt_inspect_env.physics.flight_core import FlightCore
from wt_inspect_env.physics.quadrotor import get_preset
from wt_inspect_env.physics.rate_control import Mixer, RateController, RateGains
from wt_inspect_env.physics.sim_config import SimConfig, SubstepConstants
from wt_inspect_env.physics.wind import GustWind
from wt_inspect_env.turbine.mesh import build_turbine
from wt_inspect_env.world.batched_sim import BatchedQuadrotorSim
from wt_inspect_env.world.sim import QuadrotorSim

M100 = get_preset("matrice100")


def test_ten_seconds_in_the_gust_match_pybullet_to_well_below_a_millimetre():
    d = integrator_difference("matrice100", {"type": "gust", "mean_speed": 4.0}, 10.0)
    assert d["path_length_m"] > 20.0                      # the excitation really flies
    assert d["steps"]["compiled"]["near_steps"] == 0 and d["steps"]["bullet"]["free_steps"] == 0
    assert d["max_position_difference_m"] < 1e-9          # the bound is 1 mm


@pytest.mark.parametrize("rate_loop", [True, False])
def test_randomised_plant_and_imposed_rates_match_pybullet(rate_loop):
    plant = dataclasses.replace(M100, mass=M100.mass * 1.1, inertia=tuple(1.1 * x for x in M100.inertia))
    finals = []
    for name in ("compiled", "bullet"):
        with QuadrotorSim(M100, SimConfig(integrator=name, rate_loop=rate_loop), wind=GustWind(6.0)) as sim:
            sim.set_plant(plant, 0.93)
            sim.reset(hover_state([0.0, 0.0, 40.0]))
            for k in range(300):
                sim.step(excitation(k, 1.1 * M100.weight))
            finals.append(np.concatenate([sim.state, sim.body_rates, sim.rotor_thrusts]))
    np.testing.assert_allclose(finals[0], finals[1], rtol=0, atol=1e-9)


def test_controller_side_is_the_python_rate_loop_and_mixer_including_saturation():
    """Per sub-step, the core's rotor thrusts are those of RateController + Mixer + the motor lag
    (the readable reference) for commands that saturate the mixer on every axis."""
    cfg = SimConfig()
    core = FlightCore(M100, cfg, 1)
    gains = RateGains.for_params(M100)
    ref = RateController(gains, M100.inertia, 1.0 / cfg.physics_hz)
    mixer = Mixer(M100)
    k = SubstepConstants.of(M100, cfg, mixer)
    core.reset(0, [0, 0, 10], [0, 0, 0, 1], [0, 0, 0], [0, 0, 0], np.zeros(3))
    f = [M100.weight / 4.0] * 4
    rng = np.random.default_rng(3)
    saturated = 0
    idx = np.array([0])
    for _ in range(200):
        cmd = np.array([*rng.normal(0, 3.0, 3), rng.uniform(0.0, 1.6) * M100.weight])
        omega_b = rng.normal(0, 1.0, 3)
        core.omega[0] = omega_b                # identity attitude: body = world
        core.commands[0] = cmd
        core.wrench(idx)
        tx, ty, tz = ref.update(*cmd[:3], *omega_b, mixer.saturation)
        c = mixer.mix(cmd[3], tx, ty, tz)
        saturated += mixer.saturation != (0, 0, 0)
        f = [fi + k.alpha * (ci - fi) for fi, ci in zip(f, c)]
        # to rounding: a compiler may contract a * b + c into one FMA in the C core (measured:
        # 2e-15 N apart with -ffp-contract=fast -march=native), which Python never does
        np.testing.assert_allclose(core.rotor[0], f, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(core.sat[0], mixer.saturation)
    assert saturated > 50


def _approaches(turbine):
    """(start position, world velocity) pairs flying into a blade face, a blade tip, the tower and
    the ground at 3 m/s from 4.5 m away (drag off: straight lines at constant speed)."""
    tm = turbine
    i = int(np.argmax(tm.blade_areas))
    face_c, face_n = tm.blade_centroids[i], tm.blade_normals[i]
    blade0 = tm.blade_vertices[tm.triangle_blade == 0].reshape(-1, 3)
    tip_dir = blade0.mean(axis=0) - tm.rotor_center
    tip_dir /= np.linalg.norm(tip_dir)
    tip = blade0[np.argmax((blade0 - tm.rotor_center) @ tip_dir)]
    obst = np.asarray(tm.obstacle_mesh.vertices)
    tower_x = obst[:, 0].max() if abs(obst[:, 0].max()) < 20 else 3.0
    tower_pt = np.array([tower_x, 0.0, 30.0])
    out = []
    for target, direction in ((face_c, -face_n), (tip, -tip_dir), (tower_pt, np.array([-1.0, 0, 0])),
                              (np.array([5.0, -20.0, 0.0]), np.array([0, 0, -1.0]))):
        out.append((target - 4.5 * direction, 3.0 * direction))
    return out


def _first_contact_single(mesh, start, vel, integrator):
    with QuadrotorSim(M100, SimConfig(integrator=integrator, drag=False), obstacles=mesh) as sim:
        x = hover_state(start)
        x[3:6] = vel
        sim.reset(x)
        for k in range(400):
            sim.step([0.0, 0.0, 0.0, M100.weight])
            if sim.in_collision:
                return k, sim.state, {c["other"] for c in sim.contacts}
    return None, None, None


def test_approaches_end_on_the_same_step_as_pybullet_single():
    tm = build_turbine()
    mesh = tm.mesh
    for start, vel in _approaches(tm):
        ref = _first_contact_single(mesh, start, vel, "bullet")
        got = _first_contact_single(mesh, start, vel, "compiled")
        assert ref[0] is not None, f"no contact flying from {start} along {vel}"
        assert got[0] == ref[0] and got[2] == ref[2]
        np.testing.assert_allclose(got[1], ref[1], atol=1e-9)


@pytest.mark.slow
@pytest.mark.unit
def test_approaches_end_on_the_same_step_as_pybullet_64_drones():
    tm = build_turbine()
    approaches = _approaches(tm)
    n = 64
    first = {}
    for name in ("compiled", "bullet"):
        sim = BatchedQuadrotorSim(M100, SimConfig(integrator=name, drag=False), n, geometries=[tm.mesh])
        try:
            rng = np.random.default_rng(5)
            for i in range(n):
                start, vel = approaches[i % 4]
                x = hover_state(start + (0.0 if i < 4 else rng.normal(0, 0.3, 3)))
                x[3:6] = vel * (1.0 + 0.1 * (i // 4))
                sim.reset_drone(i, x)
            hit = np.full(n, -1)
            cmd = np.tile([0.0, 0.0, 0.0, M100.weight], (n, 1))
            for k in range(200):            # the last of the 62 hits comes at step 157
                sim.step(cmd)
                new = sim.in_collision & (hit < 0)
                hit[new] = k
            first[name] = (hit, sim.state.copy())
        finally:
            sim.close()
    assert (first["bullet"][0] >= 0).sum() >= 60     # a few tip approaches with offset starts miss
    np.testing.assert_array_equal(first["compiled"][0], first["bullet"][0])
    assert math.isclose(float(np.abs(first["compiled"][1] - first["bullet"][1]).max()), 0.0, abs_tol=1e-6)
