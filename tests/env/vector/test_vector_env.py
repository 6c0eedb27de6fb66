"""The native vector environment: drone i is the single environment seeded s + i, bit for bit."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from gymnasium.vector import AutoresetMode
from side_by_side import ENV, _make_vec, _run_side_by_side

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.vector import WindTurbineInspectionVectorEnv


def test_the_structure_entry_of_drone_i_is_the_single_envs_across_autoresets():
    seen = _run_side_by_side(3, 60, start_noise=0.5, time_limit_s=0.25, structure_observation=True)
    assert seen["resets"] >= 3


def test_the_clearance_terms_of_drone_i_are_the_single_envs():
    # clearance_limit and reward.clearance (on the compiled step) in both envs
    _run_side_by_side(2, 40, start_noise=0.5, clearance_limit=2.5, reward={"clearance": 1.0})


def test_far_start_across_the_rotor_plane_matches_the_single_env():
    # the per-drone working volume holds each drone's start, as the single env's does
    seen = _run_side_by_side(2, 40, start_offset=(0.0, 40.0, 0.0), start_noise=0.5)
    assert seen["resets"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("n", [1, 4, 16])
def test_drone_i_is_the_single_env_seeded_s_plus_i_across_autoresets(n):
    # start noise makes the drones differ; the 1.5 s limit forces autoresets mid-run
    seen = _run_side_by_side(n, 260, start_noise=0.5, time_limit_s=1.5)
    assert seen["resets"] >= n
    assert seen["frames_with_new"] > 0


@pytest.mark.slow
def test_equivalence_through_the_rotor_turn():
    # open-loop reference at 60 m/s: phase 1 ends after ~10 s, the rotor turns, phase 2 follows
    # with the structure entry: it follows each drone's rotor position through the turn
    seen = _run_side_by_side(2, 1700, wind="none", reference_mode="open_loop", reference_speed=60.0,
                             start_noise=0.3, time_limit_s=16.0, action_sd=0.01, structure_observation=True)
    assert seen["max_phase"] == 2


@pytest.mark.slow
def test_pose_error_limit_matches_the_single_env():
    # 1.5 m start noise against a 1.2 m limit: some drones end with "lost_pose", in both envs at the same step
    seen = _run_side_by_side(4, 150, start_noise=1.5, pose_error_limit=1.2, time_limit_s=1.0)
    assert seen.get("lost_pose", 0) >= 1


def test_per_drone_winds_match_single_envs_with_those_winds():
    winds = ["none", {"type": "gust", "mean_speed": 6.0}, {"type": "dryden", "mean_speed": 4.0}]
    _run_side_by_side(3, 120, winds=winds, start_noise=0.2, time_limit_s=0.8)


def test_surface_task_equivalence():
    _run_side_by_side(3, 150, env_id="WindTurbineInspection-Surface-v0", start_progress=0.5, time_limit_s=1.0)


def test_make_vec_metadata_spaces_and_seeded_determinism():
    venv = _make_vec(3, start_noise=0.5)
    try:
        u = venv.unwrapped
        assert isinstance(u, WindTurbineInspectionVectorEnv)
        assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        assert venv.num_envs == 3
        assert venv.single_observation_space == gym.make(ENV).observation_space
        assert venv.action_space.shape == (3, 4)
        obs, info = venv.reset(seed=11)
        assert venv.observation_space.contains(obs)
        act = np.tile(u.scaling.hover_action(), (3, 1))
        first = [venv.step(act)[0]["position"].copy() for _ in range(5)]
        assert venv.observation_space.contains(venv.step(act)[0])
        # the three drones start apart (own seeds) ...
        assert not np.array_equal(first[0][0], first[0][1])
        # ... and the same seed replays exactly, another seed does not
        venv.reset(seed=11)
        again = [venv.step(act)[0]["position"].copy() for _ in range(5)]
        assert all(np.array_equal(a, b) for a, b in zip(first, again))
        venv.reset(seed=12)
        assert not np.array_equal(venv.step(act)[0]["position"], first[0])
        # a list of seeds seeds each drone
        venv.reset(seed=[11, 12, 13])
        assert np.array_equal(venv.step(act)[0]["position"], first[0])
    finally:
        venv.close()


def test_close_disconnects_and_is_idempotent():
    venv = _make_vec(2)
    cid = venv.unwrapped.sim.client
    venv.close()
    venv.close()
    assert not p.isConnected(physicsClientId=cid)


@pytest.mark.parametrize("num_envs", [0, -2, 1.5, "2", True, None])
def test_bad_num_envs(num_envs):
    with pytest.raises(ValueError, match="num_envs"):
        WindTurbineInspectionVectorEnv(num_envs=num_envs)


def test_bad_per_drone_options():
    with pytest.raises(ValueError, match="winds must be a list of 2"):
        WindTurbineInspectionVectorEnv(num_envs=2, winds=["none"])
    with pytest.raises(ValueError, match=r"winds\[1\]"):
        WindTurbineInspectionVectorEnv(num_envs=2, winds=["none", "hurricane"])
    with pytest.raises(ValueError, match="per-drone standoff"):
        WindTurbineInspectionVectorEnv(num_envs=2, standoff=[6.0, 7.0])
    with pytest.raises(ValueError, match="either wind"):
        WindTurbineInspectionVectorEnv(num_envs=2, wind="none", winds=["none", "none"])


def test_bad_actions_name_the_field():
    venv = WindTurbineInspectionVectorEnv(num_envs=2)
    try:
        with pytest.raises(RuntimeError, match="reset"):
            venv.step(np.zeros((2, 4)))
        venv.reset(seed=0)
        with pytest.raises(ValueError, match=r"shape \(2, 4\)"):
            venv.step(np.zeros(4))
        bad = np.zeros((2, 4))
        bad[1, 2] = np.nan
        with pytest.raises(ValueError, match=r"actions must be finite.*actions\[1\]"):
            venv.step(bad)
        bad[1, 2] = 1.5
        with pytest.raises(ValueError, match=r"\[-1, 1\].*actions\[1\]"):
            venv.step(bad)
        with pytest.raises(ValueError, match="seed"):
            venv.reset(seed=[1])
        with pytest.raises(ValueError, match=r"unknown reset option.*\['x'\]"):
            venv.reset(options={"x": 1})
    finally:
        venv.close()


def test_drones_do_not_collide_with_each_other_but_with_the_ground():
    venv = WindTurbineInspectionVectorEnv(num_envs=2, wind="none")
    try:
        venv.reset(seed=0)
        sim = venv.sim
        # both drones in the same spot: no contact between them
        state = np.zeros(10)
        state[0:3] = sim.pos[0]
        state[9] = 1.0
        sim.reset_drone(1, state)
        sim.reset_drone(0, state)
        hover = np.tile([0.0, 0.0, 0.0, venv.params.weight], (2, 1))
        sim.step(hover)
        assert not sim.in_collision.any()
        # drone 1 dropped onto the ground: it alone is in collision
        low = state.copy()
        low[0:3] = [-40.0, -40.0, venv.params.frame_height * 0.5]
        sim.reset_drone(1, low)
        sim.step(np.array([[0.0, 0.0, 0.0, venv.params.weight], [0.0, 0.0, 0.0, 0.0]]))
        assert sim.in_collision.tolist() == [False, True]
    finally:
        venv.close()


# ---------------------------------------------------------------------------- the agent adapter
def test_batched_agent_interface_equals_the_scalar_encoder_and_decoder():
    from agents.vec_env import BatchedAgentInterface
    from agents.wrappers import AgentSpec, FeatureEncoder, ResidualHoverAction

    groups = ["ideal_body", "point_body", "velocity_body", "gravity_body", "heading", "body_rates",
              "normal_body", "integral", "last_action", "progress", "coverage"]
    env = gym.make(ENV, start_noise=2.0).unwrapped
    rng = np.random.default_rng(0)
    obs_rows = []
    for i in range(5):
        o, _ = env.reset(seed=i)
        for _ in range(int(rng.integers(1, 30))):
            o, *_ = env.step(np.clip(env.scaling.hover_action() + rng.normal(0, 0.3, 4), -1, 1))
        obs_rows.append(o)
    env.close()
    obs = {k: np.stack([o[k] for o in obs_rows]) for k in obs_rows[0]}
    for mode in ("rates", "attitude"):
        spec = AgentSpec(features={"groups": groups}, action={"mode": mode})
        batch = BatchedAgentInterface(spec, 5, standoff=7.0, dt=env.dt, scaling=env.scaling)
        encs = [FeatureEncoder(spec.features, standoff=7.0, dt=env.dt, max_rate=env.scaling.max_rate)
                for _ in range(5)]
        dec = ResidualHoverAction(spec.action, env.scaling)
        u = rng.uniform(-1, 1, (5, 4))
        batch.reset(np.arange(5))
        batch.note_action(u)
        for e, ui in zip(encs, u):
            e.reset()
            e.note_action(ui)
        for _ in range(3):      # the integral builds up over updates
            batch.update(np.arange(5), obs)
            scalar = [e.update({k: v[i] for k, v in obs.items()}) for i, e in enumerate(encs)]
        np.testing.assert_array_equal(batch.features(), np.stack(scalar))
        assert [batch.heading_cos(i) for i in range(5)] == [e.heading_cos() for e in encs]
        np.testing.assert_array_equal(batch.decode(u, obs["quaternion"]),
                                      np.stack([dec(u[i], obs["quaternion"][i]) for i in range(5)]))


@pytest.mark.slow
def test_sb3_vector_backend_steps_resets_and_reports_episodes():
    pytest.importorskip("stable_baselines3")
    from agents.recipe import default_recipe_path, load_recipe
    from agents.training import make_vec_env

    rec = load_recipe(default_recipe_path("ppo"))
    venv = make_vec_env("surface", {**rec.env, "time_limit_s": 0.5}, rec.spec, 3, backend="vector",
                        shaping=rec.shaping, seed=5)
    try:
        obs = venv.reset()
        assert obs.shape == (3, rec.spec.features.size) and venv.observation_space.contains(obs[0])
        ends = 0
        for _ in range(40):
            obs, rew, done, infos = venv.step(np.zeros((3, 4), dtype=np.float32))
            assert rew.shape == (3,) and np.isfinite(rew).all()
            for d, info in zip(done, infos):
                assert 1 <= info["env_steps"] <= rec.spec.action_repeat
                if d:
                    ends += 1
                    assert info["terminal_observation"].shape == obs[0].shape
                    assert "episode" in info and 0.0 <= info["metrics"]["coverage"] <= 1.0
        assert ends >= 3      # 0.5 s episodes at 25 decisions/s: every drone ended at least once
    finally:
        venv.close()


def test_vector_backend_refuses_non_wind_variants():
    pytest.importorskip("stable_baselines3")
    from agents.training import make_vec_env
    from agents.wrappers import AgentSpec

    with pytest.raises(ValueError, match=r"env_variants\[0\] varies \['standoff'\]"):
        make_vec_env("surface", {}, AgentSpec(), 2, variants=[{"standoff": 6.0}])
