"""The ``structure`` observation entry (``structure_observation=True``): the nearest point of the
turbine, exact against a brute-force distance over every triangle, in the single and the vector env,
and the agents' ``structure_body`` feature built from it."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from oracles import brute_distance

import wt_inspect_env  # noqa: F401 - registers the env ids
from wt_inspect_env.physics.dynamics import quat_to_rotmat_np

ENV = "WindTurbineInspection-v0"


def test_off_by_default_the_observation_is_unchanged():
    env = gym.make(ENV)
    try:
        obs, _ = env.reset(seed=0)
        assert "structure" not in obs and "structure" not in env.observation_space.spaces
    finally:
        env.close()


def test_the_entry_is_the_nearest_mesh_point_of_the_flown_rotor_position():
    """Random hovering flight from starts scattered around the stand-off: at every step the entry's
    distance equals the brute-force distance to the active rotor position's mesh (float32 entry:
    to 1e-4 relative), its vector points from the drone to a point on that mesh, and its length
    is the distance."""
    plain = gym.make(ENV, structure_observation=True)
    try:
        check_env(plain.unwrapped, skip_render_check=True)
    finally:
        plain.close()
    env = gym.make(ENV, structure_observation=True, start_noise=3.0)
    try:
        u = env.unwrapped
        rng = np.random.default_rng(0)
        for seed in range(3):
            obs, _ = env.reset(seed=seed)
            hover = u.scaling.hover_action()
            for t in range(30):
                if t % 10 == 0:
                    tris = u.mission.turbines[u.phase_index].mesh.triangles
                    pos = obs["position"].astype(np.float64)
                    vec, d = obs["structure"][0:3].astype(np.float64), float(obs["structure"][3])
                    ref = float(brute_distance(pos[None], tris)[0])
                    assert d == pytest.approx(ref, rel=1e-4)
                    assert np.linalg.norm(vec) == pytest.approx(d, rel=1e-4)
                    assert float(brute_distance((pos + vec)[None], tris)[0]) < 1e-3 * max(d, 1.0)
                act = np.clip(hover + rng.normal(0.0, 0.05, 4), -1, 1).astype(np.float32)
                obs, _, term, trunc, _ = env.step(act)
                if term or trunc:
                    break
    finally:
        env.close()


def test_a_bad_option_names_the_field():
    with pytest.raises(ValueError, match="structure_observation"):
        gym.make(ENV, structure_observation=1)


def test_the_structure_feature_is_the_entry_in_the_body_frame():
    """``structure_body`` = R^T (c - x) / d_ref and |c - x| / d_ref; asking for it without the entry
    is refused with the option to set."""
    from agents.interface import BatchedFeatures
    from agents.wrappers import FeatureConfig
    cfg = FeatureConfig(groups=("structure_body",))
    feats = BatchedFeatures(cfg, 2, standoff=7.0, dt=0.01, max_rate=1.7)
    yaw = np.pi / 2                                       # body x along world y
    q = np.array([[0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)], [0.0, 0.0, 0.0, 1.0]])
    obs = {"position": np.zeros((2, 3)), "velocity_body": np.zeros((2, 3)), "quaternion": q,
           "body_rates": np.zeros((2, 3)), "point": np.ones((2, 3)), "normal": np.tile([1.0, 0.0, 0.0], (2, 1)),
           "point_velocity": np.zeros((2, 3)), "coverage": np.zeros((2, 1)), "progress": np.zeros((2, 1)),
           "structure": np.array([[0.0, 3.5, 0.0, 3.5], [1.4, 0.0, 0.0, 1.4]])}
    feats.update(slice(None), obs)
    f = feats.features()
    R0 = quat_to_rotmat_np(q[0])
    np.testing.assert_allclose(f[0], np.append(R0.T @ [0.0, 3.5, 0.0], 3.5) / 7.0, atol=1e-6)
    np.testing.assert_allclose(f[0, :3], [0.5, 0.0, 0.0], atol=1e-6)     # ahead of the camera
    np.testing.assert_allclose(f[1], [0.2, 0.0, 0.0, 0.2], atol=1e-6)
    del obs["structure"]
    feats = BatchedFeatures(cfg, 2, standoff=7.0, dt=0.01, max_rate=1.7)
    feats.update(slice(None), obs)
    with pytest.raises(ValueError, match="structure_observation=True"):
        feats.features()


def _start_near_the_surface(env, gap: float, seed: int = 0):
    """Reset ``env`` with its start moved ``gap`` metres towards the surface from the stand-off
    pose (along the first point's horizontal normal)."""
    obs, _ = env.reset(seed=seed)
    n = np.asarray(obs["normal"], dtype=np.float64)
    n_xy = np.array([n[0], n[1], 0.0]) / np.hypot(n[0], n[1])
    return env.reset(seed=seed, options={"start_offset": (-gap * n_xy).tolist()})


def test_clearance_limit_ends_the_episode_too_close_with_the_crash_penalty():
    """Started 2 m from the blade surface (d_min 3 m), hovering: with ``clearance_limit=2.9`` the
    first step ends the episode as ``too_close`` with the crash penalty; without it the episode
    goes on."""
    for limit in (2.9, None):
        env = gym.make(ENV, clearance_limit=limit, structure_observation=True, wind="none")
        try:
            obs, _ = _start_near_the_surface(env, 5.0)
            assert float(obs["structure"][3]) < 2.5
            _, reward, term, trunc, info = env.step(env.unwrapped.scaling.hover_action().astype(np.float32))
            if limit is None:
                assert not term and info["termination"] in (None, "")
            else:
                assert term and info["termination"] == "too_close"
                assert info["reward_terms"]["crash"] == pytest.approx(-env.unwrapped.config.reward.crash)
        finally:
            env.close()


@pytest.mark.slow
def test_noisy_starts_inside_the_clearance_limit_are_drawn_again():
    """Full mission, 0.5 m start noise, starts anywhere along the path (256 drones, 4 resets):
    without a limit some starts round the hub and blade roots lie inside 2.9 m of the mesh (the
    ideal poses there are little more than d_min away); with ``clearance_limit=2.9`` every start
    keeps the limit plus the 0.1 m margin, so no training episode begins with its own end."""
    from wt_inspect_env.vector import WindTurbineInspectionVectorEnv
    from wt_inspect_env.world.world import START_CLEARANCE_MARGIN

    def starts(**extra):
        venv = WindTurbineInspectionVectorEnv(num_envs=256, task="full", structure_observation=True, wind="none",
                                              start_noise=0.5, start_progress=0.999, **extra)
        try:
            return np.concatenate([venv.reset(seed=k)[0]["structure"][:, 3] for k in range(4)])
        finally:
            venv.close()

    assert (starts() < 2.9).sum() >= 5
    assert starts(clearance_limit=2.9).min() >= 2.9 + START_CLEARANCE_MARGIN - 1e-4


@pytest.mark.parametrize("margin", [0.0, 0.5])
def test_the_clearance_reward_term_is_the_shortfall_below_d_min(margin):
    """``reward.clearance`` = w: the term is -w dt max(0, d_min + margin - d) / d_min with d the
    exact distance (brute force over every triangle); 0 at the stand-off."""
    env = gym.make(ENV, reward={"clearance": 2.0, "clearance_margin": margin}, wind="none")
    try:
        u = env.unwrapped
        hover = u.scaling.hover_action().astype(np.float32)
        env.reset(seed=0)
        _, _, _, _, info = env.step(hover)
        assert info["reward_terms"]["clearance"] == 0.0
        _start_near_the_surface(env, 5.0)
        _, _, _, _, info = env.step(hover)
        tris = u.mission.turbines[u.phase_index].mesh.triangles
        d = float(brute_distance(u.sim.state[0:1, 0:3], tris)[0])
        d_min = u.config.d_min
        assert d < d_min - 0.5
        assert info["reward_terms"]["clearance"] == pytest.approx(-2.0 * u.dt * (d_min + margin - d) / d_min,
                                                                  rel=1e-9)
    finally:
        env.close()


def test_bad_clearance_options_name_the_field():
    with pytest.raises(ValueError, match="clearance_limit"):
        gym.make(ENV, clearance_limit=-1.0)
    with pytest.raises(ValueError, match="clearance"):
        gym.make(ENV, reward={"clearance": -1.0})
    with pytest.raises(ValueError, match="clearance_margin"):
        gym.make(ENV, reward={"clearance": 1.0, "clearance_margin": -0.5})


def test_a_policy_check_keeps_the_structure_entry():
    """check_observation (every policy's first step) keeps the optional ``structure`` entry, checked
    like the others (it once dropped it: an agent trained on ``structure_body`` failed at its first
    periodic evaluation with "needs the observation entry 'structure'")."""
    from wt_inspect_env.policy import check_observation
    env = gym.make(ENV, structure_observation=True)
    try:
        obs, _ = env.reset(seed=0)
        out = check_observation(obs)
        np.testing.assert_array_equal(out["structure"], np.asarray(obs["structure"], dtype=np.float64))
        assert "structure" not in check_observation({k: v for k, v in obs.items() if k != "structure"})
        bad = dict(obs, structure=np.zeros(3))
        with pytest.raises(ValueError, match="structure"):
            check_observation(bad)
        bad = dict(obs, structure=np.array([0.0, 1.0, np.nan, 1.0]))
        with pytest.raises(ValueError, match="structure"):
            check_observation(bad)
    finally:
        env.close()


@pytest.mark.slow
def test_an_agent_on_the_structure_feature_trains_and_is_evaluated(tmp_path):
    """A tiny PPO run whose features include ``structure_body`` (env structure_observation=True)
    trains and runs its periodic evaluations on the single env."""
    import json

    from agents.recipe import Recipe, default_recipe_path
    from agents.training import train
    data = json.loads(default_recipe_path("ppo").read_text())
    data["env"] = {**data["env"], "time_limit_s": 2.0, "structure_observation": True, "clearance_limit": 2.9}
    data["eval_env"] = {"start_noise": 0.0, "time_limit_s": 1.0, "clearance_limit": None}
    data["agent"]["features"]["groups"] = list(data["agent"]["features"]["groups"]) + ["structure_body"]
    data["algo_kwargs"] = {**data["algo_kwargs"], "n_steps": 64, "batch_size": 64, "n_epochs": 1}
    data["policy_kwargs"] = {**data["policy_kwargs"], "net_arch": {"pi": [8], "vf": [8]}}
    data.update(eval_every_env_steps=500, checkpoint_every_env_steps=10_000)
    train("ppo", "surface", 1000, 2, tmp_path, recipe=Recipe.from_dict(data), progress_bar=False)
    evals = json.loads((tmp_path / "evaluations.json").read_text())
    assert len(evals) >= 2 and all(0.0 <= e["mean"]["coverage"] <= 1.0 for e in evals)
    # the evaluation records the least clearance (the eval env observes the structure): the
    # stand-off is 7 m, so a 1 s flight from the ideal pose stays between d_min and ~7 m
    for e in evals:
        least = e["mean"]["clearance_min_m"]
        assert least == min(ep["clearance_min_m"] for ep in e["episodes"]) and 3.0 < least < 7.5
