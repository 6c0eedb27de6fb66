"""Domain randomisation: validated ranges, seeded draws that change the physics, noise, latency."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from side_by_side import _run_side_by_side

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.physics.quadrotor import GRAVITY, get_preset
from wt_inspect_env.task.randomization import RandomizationConfig, coerce_randomization

SURFACE = "WindTurbineInspection-Surface-v0"
# Every range pinned to the nominal value: a randomisation that changes nothing.
NOMINAL = dict(mass=(1.0, 1.0), inertia=(1.0, 1.0), drag=(1.0, 1.0), thrust=(1.0, 1.0), torque_coeff=(1.0, 1.0),
               motor_time_constant=(1.0, 1.0), position_noise=(0.0, 0.0), velocity_noise=(0.0, 0.0),
               attitude_noise=(0.0, 0.0), rate_noise=(0.0, 0.0), latency_steps=(0, 0))


def pinned(**changes) -> dict:
    return {**NOMINAL, **changes}


@pytest.fixture(scope="module")
def lab_env():
    """A ~1 kg quadrotor (lab250) in still air; randomisation set per test through reset options."""
    env = gym.make(SURFACE, drone="lab250", wind="none").unwrapped
    yield env
    env.close()


def _fly(env, actions, **reset_kw) -> np.ndarray:
    env.reset(**reset_kw)
    out = [env.sim.state[0]]
    for a in actions:
        env.step(a)
        out.append(env.sim.state[0])
    return np.stack(out)


@pytest.mark.parametrize("changes, match", [
    (dict(mass=(0.0, 1.1)), "randomization mass must be positive"),
    (dict(mass=(1.1, 0.9)), "randomization mass must have low <= high"),
    (dict(drag=(1.0,)), r"randomization drag must be a \(low, high\) pair"),
    (dict(thrust="wide"), "randomization thrust must be a"),
    (dict(position_noise=(-0.1, 0.1)), "randomization position_noise must be non-negative"),
    (dict(rate_noise=(0.0, float("nan"))), "randomization rate_noise must be finite"),
    (dict(latency_steps=(0, 1.5)), "randomization latency_steps must be a .* integers"),
    (dict(latency_steps=(-1, 2)), "randomization latency_steps must be non-negative"),
])
def test_bad_ranges_are_one_line_errors_naming_the_field(changes, match):
    with pytest.raises(ValueError, match=match) as e:
        RandomizationConfig(**changes)
    assert "\n" not in str(e.value)


def test_coercion_and_airframe_check():
    assert coerce_randomization(None) is None and coerce_randomization(False) is None
    assert coerce_randomization(True) == RandomizationConfig()
    assert coerce_randomization({"mass": [1.0, 1.2]}).mass == (1.0, 1.2)
    with pytest.raises(ValueError, match=r"unknown randomization option\(s\) \['weight'\]"):
        coerce_randomization({"weight": (1.0, 1.0)})
    # the M100's 4 x 20 N cannot give 2 m g for a 30 % heavier airframe: refused at construction
    with pytest.raises(ValueError, match="randomization mass up to 1.3 .* max_rotor_thrust"):
        RandomizationConfig(mass=(1.0, 1.3)).check_airframe(get_preset("matrice100"))
    RandomizationConfig().check_airframe(get_preset("matrice100"))   # the defaults fit both presets
    RandomizationConfig().check_airframe(get_preset("lab250"))


def test_off_by_default_and_a_nominal_draw_is_bit_identical_to_off(lab_env):
    env = lab_env
    rng = np.random.default_rng(0)
    hover = env.scaling.hover_action()
    actions = [np.clip(hover + rng.normal(0, 0.05, 4), -1, 1) for _ in range(60)]
    off = _fly(env, actions, seed=5)
    _, info = env.reset(seed=5)
    assert env.config.randomization is None and "randomization" not in info
    assert env.sim.plants[0] is env.params
    # The whole randomisation path (a new plant in PyBullet, constants, queue) with nothing changed
    # flies exactly today's trajectory: the plant path adds no numerical difference.
    same = _fly(env, actions, seed=5, options={"randomization": NOMINAL})
    np.testing.assert_array_equal(same, off)
    # after a randomised episode the next plain reset is the nominal airframe again, bit for bit
    _fly(env, actions[:10], seed=5, options={"randomization": True})
    assert env.sim.plants[0] is not env.params
    np.testing.assert_array_equal(_fly(env, actions, seed=5), off)
    assert env.sim.plants[0] is env.params


def test_heavier_airframe_sinks_under_the_nominal_hover_command_as_newton_says(lab_env):
    env = lab_env
    hover = env.scaling.hover_action()
    steps = 100                                     # 1 s at 100 Hz
    level = _fly(env, [hover] * steps, seed=0)
    assert abs(level[-1, 2] - level[0, 2]) < 1e-3   # the nominal airframe hovers
    k = 1.1
    heavy = _fly(env, [hover] * steps, seed=0, options={"randomization": pinned(mass=(k, k))})
    assert env.sim.plants[0].mass == pytest.approx(k * get_preset("lab250").mass)
    # m a = m0 g - m g  ->  a = -g (1 - 1/k); drop 1/2 a t^2, less a little for the rotor lag and drag
    drop = heavy[0, 2] - heavy[-1, 2]
    ideal = 0.5 * GRAVITY * (1.0 - 1.0 / k) * 1.0 ** 2
    assert 0.85 * ideal < drop < ideal
    # a weaker thrust constant is the same physics from the other side: 1/k of the thrust
    weak = _fly(env, [hover] * steps, seed=0, options={"randomization": pinned(thrust=(1 / k, 1 / k))})
    assert 0.85 * ideal < weak[0, 2] - weak[-1, 2] < ideal
    light = _fly(env, [hover] * steps, seed=0, options={"randomization": pinned(mass=(0.9, 0.9))})
    assert light[-1, 2] > light[0, 2] + 0.3


def test_inertia_and_motor_lag_draws_change_the_rotational_response(lab_env):
    env = lab_env
    a = env.scaling.hover_action().copy()
    a[0] = 0.3                                       # roll-rate step
    def roll_rate_after(n, **rand):
        env.reset(seed=0, options={"randomization": pinned(**rand)})
        for _ in range(n):
            env.step(a)
        return env.sim.body_rates[0, 0]
    nominal = roll_rate_after(3)
    assert roll_rate_after(3, inertia=(1.5, 1.5)) < nominal < roll_rate_after(3, inertia=(0.7, 0.7))
    assert roll_rate_after(3, motor_time_constant=(2.0, 2.0)) < nominal


def test_same_seed_same_draws_and_flight_different_seed_different_draws():
    kw = dict(drone="lab250", randomization=True, start_noise=0.1)
    a, b = gym.make(SURFACE, **kw).unwrapped, gym.make(SURFACE, **kw).unwrapped
    try:
        rng = np.random.default_rng(1)
        actions = [np.clip(a.scaling.hover_action() + rng.normal(0, 0.05, 4), -1, 1) for _ in range(40)]
        ta, tb = _fly(a, actions, seed=11), _fly(b, actions, seed=11)
        np.testing.assert_array_equal(ta, tb)
        _, ia = a.reset(seed=11)
        _, ib = b.reset(seed=12)
        ra, rb = ia["randomization"], ib["randomization"]
        assert ra != rb
        cfg = RandomizationConfig()
        nominal = get_preset("lab250")
        for r in (ra, rb):
            assert cfg.mass[0] <= r["mass"] / nominal.mass <= cfg.mass[1]
            assert all(cfg.inertia[0] <= j / j0 <= cfg.inertia[1] for j, j0 in zip(r["inertia"], nominal.inertia))
            assert cfg.thrust[0] <= r["thrust_scale"] <= cfg.thrust[1]
            assert cfg.latency_steps[0] <= r["latency_steps"] <= cfg.latency_steps[1]
            assert cfg.position_noise[0] <= r["position_noise"] <= cfg.position_noise[1]
        # what info reports is what PyBullet flies
        assert b.sim.plants[0].mass == rb["mass"] and b.sim.thrust_scales[0] == rb["thrust_scale"]
        assert b.sim.plants[0].motor_time_constant == rb["motor_time_constant"]
    finally:
        a.close()
        b.close()


def test_latency_delays_every_command_by_whole_control_steps(lab_env):
    env = lab_env
    rng = np.random.default_rng(2)
    hover = env.scaling.hover_action()
    actions = [np.clip(hover + rng.normal(0, 0.1, 4), -1, 1) for _ in range(40)]
    for L in (1, 2):
        late = _fly(env, actions, seed=0, options={"randomization": pinned(latency_steps=(L, L))})
        shifted = _fly(env, [hover] * L + actions[:-L], seed=0, options={"randomization": NOMINAL})
        np.testing.assert_array_equal(late, shifted)


def test_observation_noise_has_the_drawn_spread_and_leaves_the_rest_exact(lab_env):
    env = lab_env
    sd = 0.05
    obs, info = env.reset(seed=0, options={"randomization": pinned(position_noise=(sd, sd),
                                                                   attitude_noise=(0.02, 0.02))})
    assert info["randomization"]["position_noise"] == sd
    hover = env.scaling.hover_action()
    err, norms = [], []
    for _ in range(300):
        obs, _, _, _, info = env.step(hover)
        err.append(obs["position"] - env.sim.state[0, 0:3])
        norms.append(np.linalg.norm(obs["quaternion"]))
        np.testing.assert_array_equal(obs["velocity_body"], env.sim.state[0, 3:6].astype(np.float32))
    err = np.array(err)
    assert abs(err.mean()) < 0.01 and 0.8 * sd < err.std() < 1.2 * sd
    np.testing.assert_allclose(norms, 1.0, atol=1e-6)
    # the metrics see the true flight: the same as without noise, bit for bit
    env.reset(seed=0, options={"randomization": NOMINAL})
    for _ in range(300):
        _, _, _, _, exact = env.step(hover)
    assert info["metrics"] == exact["metrics"]




@pytest.mark.parametrize("n", [1, pytest.param(3, marks=pytest.mark.slow)])
def test_vector_env_drone_i_is_the_randomised_single_env_seeded_s_plus_i(n):
    """Randomised plants, noise and latency per drone, across autoresets: still bit for bit."""
    wide = dict(latency_steps=(0, 3), position_noise=(0.0, 0.05), attitude_noise=(0.0, 0.02))
    seen = _run_side_by_side(n, 160, env_id=SURFACE, randomization=wide, start_noise=0.2, time_limit_s=0.5)
    assert seen["resets"] >= n


def test_vector_env_reports_each_drones_draw_and_flies_it():
    venv = gym.make_vec(SURFACE, num_envs=3, vectorization_mode="vector_entry_point", randomization=True,
                        time_limit_s=0.05, wind="none")
    try:
        venv.reset(seed=0)
        u = venv.unwrapped
        draws = list(u.randomization)
        assert len({d.plant.mass for d in draws}) == 3
        for i, d in enumerate(draws):
            assert u.sim.plants[i] is d.plant and u.sim.thrust_scales[i] == d.thrust_scale
        hover = np.tile(u.scaling.hover_action(), (3, 1))
        for _ in range(5):
            _, _, term, trunc, info = venv.step(hover)
        assert (term | trunc).all()
        for i in range(3):
            assert info["final_info"]["randomization"]["mass"][i] == draws[i].plant.mass
    finally:
        venv.close()
