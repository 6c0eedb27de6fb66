"""A shipped agent flown by its bare stable-baselines3 model: ``agents.policy.agent_env`` turns the
env's Dict observation into what ``model.predict`` takes, and the flight is SB3Policy's."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import wt_inspect_env  # noqa: E402,F401 - registers the ids
from agents.policy import agent_env, load_sb3_policy  # noqa: E402
from agents.safe_load import resolve_model_path  # noqa: E402

OPTIONS = {"wind": {"type": "gust", "mean_speed": 4.0}, "standoff": 7.0, "drone": "matrice100"}
DECISIONS = 40   # agent steps: 160 control steps (1.6 s) with the shipped agents' action_repeat 4


@pytest.mark.slow
def test_bare_sb3_model_flies_the_wrapped_env_as_the_controller_flies_the_raw_one():
    path = resolve_model_path("ppo_surface_wind_mix")
    raw = gym.make("WindTurbineInspection-Surface-v0", **OPTIONS)
    controller = load_sb3_policy("ppo", path, raw)
    model = controller.model                      # the bare SB3 PPO (loaded without unpickling)
    repeat = controller.spec.action_repeat

    # the env's own observation is a Dict: the model cannot take it
    obs, _ = raw.reset(seed=0)
    with pytest.raises(Exception):  # noqa: B017 - SB3 fails in its own preprocessing; the error type is not its API
        model.predict(obs, deterministic=True)

    env = agent_env(gym.make("WindTurbineInspection-Surface-v0", **OPTIONS), "ppo_surface_wind_mix")
    assert env.observation_space.shape == model.observation_space.shape == (27,)
    assert env.action_space.shape == model.action_space.shape
    x, _ = env.reset(seed=0)
    assert env.observation_space.contains(x)
    wrapped_positions = []
    for _ in range(DECISIONS):
        action, _ = model.predict(x, deterministic=True)
        x, reward, terminated, truncated, info = env.step(action)
        assert np.isfinite(reward) and info["env_steps"] == repeat
        wrapped_positions.append(env.unwrapped.sim.state[0, :3].copy())
        assert not (terminated or truncated)

    controller.reset()
    obs, _ = raw.reset(seed=0)
    ctrl_positions = []
    for k in range(DECISIONS * repeat):
        obs, *_ = raw.step(controller.act(obs))
        if (k + 1) % repeat == 0:
            ctrl_positions.append(raw.unwrapped.sim.state[0, :3].copy())
    np.testing.assert_array_equal(np.array(wrapped_positions), np.array(ctrl_positions))
    # and it flew: 1.6 s of the surface task near the stand-off pose, not a fall
    assert np.linalg.norm(wrapped_positions[-1] - wrapped_positions[0]) < 5.0
    assert wrapped_positions[-1][2] > 50.0


def test_agent_env_names_an_unknown_model():
    with pytest.raises(ValueError, match="no_such_agent"):
        agent_env(None, "no_such_agent")      # the name is resolved before the env is touched
