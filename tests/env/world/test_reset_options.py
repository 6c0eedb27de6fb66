"""``reset(options=...)``: per-episode wind, start and randomisation, validated like the constructor."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.task.env_config import RESET_OPTIONS

SURFACE = "WindTurbineInspection-Surface-v0"
WIND5 = {"type": "constant", "velocity": [0.0, 5.0, 0.0]}


@pytest.fixture(scope="module")
def surface_env():
    env = gym.make(SURFACE).unwrapped
    yield env
    env.close()


def _rollout(env, n: int = 30, **reset_kw) -> tuple[dict, np.ndarray]:
    obs, _ = env.reset(**reset_kw)
    hover = env.scaling.hover_action()
    states = [env.sim.state[0]]
    for _ in range(n):
        env.step(hover)
        states.append(env.sim.state[0])
    return obs, np.stack(states)


def test_options_hold_for_one_episode_then_the_constructor_config_returns():
    env = gym.make(SURFACE, wind="none").unwrapped
    fresh = gym.make(SURFACE, wind="none").unwrapped
    try:
        base_obs, base = _rollout(fresh, seed=0)
        obs, _ = env.reset(seed=0, options={"wind": WIND5, "start_offset": [0.0, 0.0, 2.0]})
        np.testing.assert_allclose(obs["position"] - base_obs["position"], [0.0, 0.0, 2.0], atol=1e-5)
        assert env.episode_config.start_offset == (0.0, 0.0, 2.0)
        hover = env.scaling.hover_action()
        for _ in range(50):
            _, _, _, _, info = env.step(hover)
        np.testing.assert_array_equal(info["wind"], [0.0, 5.0, 0.0])
        assert env.sim.vel[0, 1] > 0.3          # blown along +y by the episode's wind
        # The next reset without options is the constructor's configuration again, bit for bit.
        obs2, again = _rollout(env, seed=0)
        assert env.episode_config is env.config
        np.testing.assert_array_equal(again, base)
        for k in base_obs:
            np.testing.assert_array_equal(obs2[k], base_obs[k])
    finally:
        env.close()
        fresh.close()


def test_an_episode_wind_is_built_once_per_spec_and_replays_with_its_seed():
    env = gym.make(SURFACE).unwrapped
    try:
        dryden = {"type": "dryden", "mean_speed": 7.0}
        _, first = _rollout(env, 20, seed=2, options={"wind": dryden})
        field = env.wind
        _rollout(env, 5, seed=3, options={"wind": "none"})
        _, again = _rollout(env, 20, seed=2, options={"wind": dict(dryden)})
        assert env.wind is field                  # reused, not rebuilt ...
        np.testing.assert_array_equal(again, first)   # ... and reseeded: the same gusts
    finally:
        env.close()


def test_start_progress_option_starts_further_along_the_path():
    env = gym.make(SURFACE).unwrapped
    try:
        o0, _ = env.reset(seed=3)
        o1, _ = env.reset(seed=3, options={"start_progress": 0.9})
        assert o0["progress"][0] == 0.0
        assert o1["progress"][0] > 0.0
        o2, _ = env.reset(seed=3)
        assert o2["progress"][0] == 0.0
    finally:
        env.close()


@pytest.mark.parametrize("key, value", [
    ("start_offset", (1.0, 2.0)),
    ("start_offset", [0.0, float("nan"), 0.0]),
    ("start_progress", 1.5),
    ("start_noise", -0.1),
    ("wind", {"type": "hurricane"}),
    ("wind", {"type": "gust", "mean_speed": -4.0}),
    ("randomization", {"mass": (1.2, 0.9)}),
    ("randomization", {"weight": (1.0, 1.0)}),
    ("randomization", "on"),
])
def test_bad_option_values_are_refused_with_the_constructors_message(surface_env, key, value):
    with pytest.raises(ValueError) as at_make:
        gym.make(SURFACE, **{key: value})
    env = surface_env
    env.reset(seed=0)
    env.step(env.scaling.hover_action())
    t = env.sim.time[0]
    with pytest.raises(ValueError) as at_reset:
        env.reset(seed=1, options={key: value})
    assert str(at_reset.value) == str(at_make.value)
    assert "\n" not in str(at_reset.value)
    # refused before anything changed: the running episode goes on
    assert env.sim.time[0] == t and env.episode_config is env.config
    env.step(env.scaling.hover_action())


def test_unknown_option_keys_are_one_line_errors_naming_them():
    env = gym.make(SURFACE).unwrapped
    try:
        with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['reward', 'wnd'\]") as e:
            env.reset(options={"wnd": WIND5, "reward": {}, "start_noise": 0.1})
        assert "\n" not in str(e.value) and all(k in str(e.value) for k in RESET_OPTIONS)
        with pytest.raises(ValueError, match="reset options must be a dict"):
            env.reset(options=[("wind", "none")])
    finally:
        env.close()


def test_turbine_variants_are_refused_with_the_reason():
    env = gym.make(SURFACE).unwrapped
    try:
        for key in ("turbine", "turbine_mesh"):
            with pytest.raises(ValueError, match=f"reset option '{key}' is not supported: .*planned mission"):
                env.reset(options={key: {"blade_length": 30.0}})
    finally:
        env.close()


def test_empty_options_are_the_plain_reset():
    env = gym.make(SURFACE, start_noise=0.2).unwrapped
    try:
        a, _ = env.reset(seed=4, options={})
        b, _ = env.reset(seed=4, options=None)
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])
    finally:
        env.close()


def test_vector_env_reset_options_fly_drone_i_as_the_single_env_then_autoresets_use_the_constructor():
    opts = {"wind": {"type": "constant", "velocity": [0.0, 3.0, 0.0]}, "start_offset": (0.0, 0.0, 2.0)}
    venv = gym.make_vec("WindTurbineInspection-Surface-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        time_limit_s=0.5, wind="none")
    singles = [gym.make("WindTurbineInspection-Surface-v0", time_limit_s=0.5, wind="none").unwrapped for _ in range(2)]
    try:
        vobs, _ = venv.reset(seed=5, options=opts)
        for i, env in enumerate(singles):
            obs, _ = env.reset(seed=5 + i, options=opts)
            np.testing.assert_array_equal(vobs["position"][i], obs["position"])
        hover = np.tile(singles[0].scaling.hover_action(), (2, 1)).astype(np.float32)
        for _ in range(60):          # past the 0.5 s limit: every drone resets once on its own
            vobs, _, _, vtrunc, vinfo = venv.step(hover)
            for i, env in enumerate(singles):
                obs, _, _, trunc, info = env.step(hover[i])
                if trunc:
                    obs, _ = env.reset()          # without options: the constructor's configuration
                np.testing.assert_array_equal(vobs["position"][i], obs["position"])
                assert vtrunc[i] == trunc
        assert venv.unwrapped.world.episode[0] is venv.unwrapped.config
        assert np.all(vinfo["wind"] == 0.0)        # the autoreset episode flies the constructor's still air
        with pytest.raises(ValueError, match=r"unknown reset option.*\['x'\]") as e:
            venv.reset(seed=0, options={"x": 1})
        assert "\n" not in str(e.value)
    finally:
        venv.close()
        for env in singles:
            env.close()
