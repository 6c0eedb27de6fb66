"""One place to change the task: a TaskHooks subclass is honoured by the single env, the vector env
and both training backends (the agents then learn the changed task, whichever backend runs it)."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.task.hooks import TaskHooks

ENV = "WindTurbineInspection-Surface-v0"
BONUS = 1000.0
SHORT = 5       # control steps per episode under the changed termination


class BonusAndShortEpisodes(TaskHooks):
    """A changed task: a large bonus every step (its own reward term) and episodes of SHORT steps."""

    def rewards(self, world, actions, n_new, terminated):
        reward, terms = super().rewards(world, actions, n_new, terminated)
        return reward + BONUS, {**terms, "bonus": np.full(world.n, BONUS)}

    def terminations(self, world, state, finite, collision):
        code = super().terminations(world, state, finite, collision)
        return np.where((code == 0) & (world.steps >= SHORT), self.code_for("short"), code)


def test_the_single_and_the_vector_env_run_the_changed_task_alike():
    single = gym.make(ENV, hooks=BonusAndShortEpisodes(), wind="none").unwrapped
    venv = gym.make_vec(ENV, num_envs=3, vectorization_mode="vector_entry_point", hooks=BonusAndShortEpisodes(),
                        wind="none")
    try:
        single.reset(seed=4)
        venv.reset(seed=4)
        hover = single.scaling.hover_action().astype(np.float32)
        for k in range(1, SHORT + 1):
            _, r, term, _, info = single.step(hover)
            _, vr, vterm, _, vinfo = venv.step(np.tile(hover, (3, 1)))
            assert r == vr[0] and info["reward_terms"]["bonus"] == BONUS
            # the bonus on top of the task's terms (an ended episode pays the default crash price)
            assert r > BONUS - single.config.reward.crash * (k == SHORT) - 1.0
            assert term == (k == SHORT) and np.all(vterm == (k == SHORT))
        assert info["termination"] == "short"
        assert list(vinfo["final_info"]["termination"]) == ["short"] * 3
    finally:
        single.close()
        venv.close()


@pytest.mark.parametrize("backend", ["vector", "dummy"])
def test_training_one_step_learns_the_changed_task_on_every_backend(backend):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from agents.training import make_vec_env
    from agents.wrappers import AgentSpec

    venv = make_vec_env("surface", {"hooks": BonusAndShortEpisodes(), "wind": "none"}, AgentSpec(), 2,
                        backend=backend)
    try:
        model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, seed=0, device="cpu")
        model.learn(total_timesteps=16)
        rewards = model.rollout_buffer.rewards
        # every decision holds control steps with the bonus (the task's own terms are small beside it)
        assert rewards.min() > 0.5 * BONUS
        # SHORT control steps per episode: a new episode every two decisions
        assert model.rollout_buffer.episode_starts[1:].sum() >= 2
    finally:
        venv.close()


class SameTask(TaskHooks):
    """The default task through the general (hook-calling) path: a subclass that overrides a hook."""

    def rewards(self, world, actions, n_new, terminated):
        return super().rewards(world, actions, n_new, terminated)


CLEARANCE = dict(task="full", start_progress=0.999, start_near_structure=1.0, start_near_distance=3.4,
                 clearance_limit=3.2, reward={"clearance": 20.0, "clearance_margin": 0.3},
                 wind={"type": "gust", "mean_speed": 7.0}, start_noise=0.8,
                 time_limit_s=3.0)


@pytest.mark.parametrize("opts", [
    dict(wind={"type": "dryden", "mean_speed": 5.0}, start_noise=0.8, randomization=True, time_limit_s=3.0),
    CLEARANCE], ids=["default-terms", "clearance-terms"])
def test_the_compiled_step_and_the_hook_path_fly_the_same_episode_bit_for_bit(opts):
    fast = gym.make_vec(ENV, num_envs=3, vectorization_mode="vector_entry_point", **opts)
    hooked = gym.make_vec(ENV, num_envs=3, vectorization_mode="vector_entry_point", hooks=SameTask(), **opts)
    assert fast.unwrapped.world._fused_ok() and not hooked.unwrapped.world._fused_ok()
    rng = np.random.default_rng(0)
    try:
        a_obs, _ = fast.reset(seed=2)
        b_obs, _ = hooked.reset(seed=2)
        ends = close = 0
        for _ in range(450):              # past the 3 s limit: autoresets on both
            act = np.clip(rng.normal(0.0, 0.3, (3, 4)), -1, 1)
            a = fast.step(act)
            b = hooked.step(act)
            for k in a[0]:
                np.testing.assert_array_equal(a[0][k], b[0][k])
            np.testing.assert_array_equal(a[1], b[1])
            assert np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3])
            assert set(a[4]["reward_terms"]) == set(b[4]["reward_terms"])
            for k in a[4]["reward_terms"]:
                np.testing.assert_array_equal(a[4]["reward_terms"][k], b[4]["reward_terms"][k])
            ends += int(np.sum(a[2] | a[3]))
            close += int(np.sum(np.asarray(a[4]["termination"]) == "too_close"))
        assert ends >= 3
        assert (close > 0) == ("clearance_limit" in opts)     # the clearance end is flown on both paths
        for i in range(3):
            ma, mb = fast.unwrapped.metrics(i), hooked.unwrapped.metrics(i)
            assert all(ma[k] == mb[k] or (ma[k] != ma[k] and mb[k] != mb[k]) for k in ma)
    finally:
        fast.close()
        hooked.close()
