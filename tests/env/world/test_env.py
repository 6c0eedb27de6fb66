"""The Gymnasium environments: API conformance, determinism, independence, termination, bad input."""
import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from gymnasium.utils.env_checker import check_env

import wt_inspect_env  # noqa: F401  (registers the ids)
from wt_inspect_env import ENV_IDS
from wt_inspect_env.world.batched_sim import ray_mask


def make(env_id="WindTurbineInspection-Surface-v0", **kw):
    return gym.make(env_id, **kw)


@pytest.mark.parametrize("env_id", list(ENV_IDS))
def test_check_env(env_id, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)      # headless, as CI: check_env with its defaults
    env = make(env_id)
    assert env.unwrapped.metadata["render_modes"] == ["rgb_array"]
    check_env(env.unwrapped)
    env.close()
    with pytest.raises(ValueError, match="needs a display"):
        make(env_id, render_mode="human")


def test_render_fps_is_the_control_rate_so_videos_play_in_real_time():
    env = make(ctrl_hz=50.0, physics_hz=400.0)
    assert env.unwrapped.metadata["render_fps"] == 50.0
    env.close()


def test_sb3_check_env():
    sb3 = pytest.importorskip("stable_baselines3.common.env_checker")
    env = make()
    sb3.check_env(env.unwrapped, warn=True)
    env.close()


def _rollout(env, seed, n=150):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(123)
    hover = env.unwrapped.scaling.hover_action()
    traj = [obs["position"].copy()]
    for _ in range(n):
        a = np.clip(hover + rng.normal(0, 0.05, 4), -1, 1).astype(np.float32)
        obs, r, term, trunc, info = env.step(a)
        traj.append(np.concatenate([obs["position"], obs["quaternion"], [r]]))
        if term or trunc:
            break
    return np.concatenate([np.ravel(t) for t in traj])


def test_same_seed_same_trajectory_different_seed_differs():
    kw = dict(wind={"type": "dryden", "mean_speed": 4.0}, start_noise=0.3)
    a, b = make(**kw), make(**kw)
    ta, tb = _rollout(a, seed=7), _rollout(b, seed=7)
    np.testing.assert_array_equal(ta, tb)
    tc = _rollout(a, seed=8)
    assert ta.shape != tc.shape or not np.allclose(ta, tc)
    a.close()
    b.close()


def test_environments_in_one_process_are_independent():
    kw = dict(wind={"type": "dryden", "mean_speed": 4.0})
    solo = make(**kw)
    ref = _rollout(solo, seed=3, n=80)
    solo.close()
    e1, e2 = make(**kw), make(**kw)
    e1.reset(seed=3)
    e2.reset(seed=99)
    hover = e1.unwrapped.scaling.hover_action()
    # interleave: e2 takes wild actions between e1's steps; e1 must not notice
    rng = np.random.default_rng(123)
    obs, _ = e1.reset(seed=3)
    out = [obs["position"].copy()]
    for _ in range(80):
        e2.step(e2.action_space.sample())
        act = np.clip(hover + rng.normal(0, 0.05, 4), -1, 1).astype(np.float32)
        obs, r, term, trunc, _ = e1.step(act)
        out.append(np.concatenate([obs["position"], obs["quaternion"], [r]]))
        if term or trunc:
            break
    np.testing.assert_array_equal(np.concatenate([np.ravel(t) for t in out]), ref)
    e1.close()
    e2.close()


def test_close_frees_the_pybullet_client():
    env = make()
    env.reset(seed=0)
    cid = env.unwrapped.sim.client
    assert p.getConnectionInfo(physicsClientId=cid)["isConnected"] == 1
    env.close()
    assert p.getConnectionInfo(physicsClientId=cid)["isConnected"] == 0


def test_observation_layout_and_hover_start():
    env = make(wind="none")
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    assert set(obs) == set(u.observation_space.spaces)
    # starts at the ideal stand-off pose d_ref from the point along the horizontal normal
    a = obs["point"] - obs["position"]
    assert np.hypot(a[0], a[1]) == pytest.approx(u.config.standoff, abs=1e-4)
    obs2, r, term, trunc, info = env.step(u.scaling.hover_action())
    assert not term and not trunc
    assert np.linalg.norm(obs2["position"] - obs["position"]) < 0.01
    assert r == pytest.approx(sum(info["reward_terms"].values()))
    env.close()


def test_terminates_on_collision_with_the_blade():
    env = make(wind="none")
    env.reset(seed=0)
    u = env.unwrapped
    # put the drone onto the blade surface: the contact must end the episode as a crash
    state = u.sim.state[0].copy()
    state[0:3] = u.mission.points[0] + 0.05 * u.mission.normals[0]
    u.sim.reset_drone(0, state)
    _, r, term, trunc, info = env.step(u.scaling.hover_action())
    assert term and not trunc
    assert info["termination"] == "collision"
    assert info["reward_terms"]["crash"] == -u.config.reward.crash
    env.close()


def test_terminates_when_leaving_the_working_volume():
    env = make(wind="none", working_margin=1.0)
    env.reset(seed=0)
    up = np.array([0, 0, 0, 1.0], dtype=np.float32)   # full thrust: climbs out of the box
    for _ in range(2000):
        _, _, term, trunc, info = env.step(up)
        if term or trunc:
            break
    assert term and info["termination"] == "left_working_volume"
    env.close()


def test_pose_error_limit_ends_the_episode_the_first_step_beyond_it():
    # full thrust climbs away from the pose; the episode must end exactly at the first step whose
    # distance from the ideal pose exceeds the limit, with the crash penalty, and not before
    limit = 1.5
    env = make(wind="none", pose_error_limit=limit)
    env.reset(seed=0)
    u = env.unwrapped
    up = np.array([0, 0, 0, 1.0], dtype=np.float32)
    for _ in range(2000):
        _, _, term, trunc, info = env.step(up)
        err = float(np.linalg.norm(u.sim.state[0, 0:3] - info["ideal_position"]))
        if term or trunc:
            break
        assert err <= limit
    assert term and info["termination"] == "lost_pose"
    assert err > limit
    assert info["reward_terms"]["crash"] == -u.config.reward.crash
    env.close()
    # without the limit the same flight goes on past that distance
    env = make(wind="none")
    env.reset(seed=0)
    for _ in range(200):
        _, _, term, trunc, info = env.step(up)
    assert not term and np.linalg.norm(env.unwrapped.sim.state[0, 0:3] - info["ideal_position"]) > limit
    env.close()


def test_a_start_far_across_the_rotor_plane_is_inside_its_working_volume():
    # The mission's box is thin along y (the rotor axis): a start 40 m in front of the path was
    # outside it and ended the episode at its first step. The volume now holds the start.
    env = make(wind="none", start_offset=(0.0, 40.0, 0.0))
    _, info = env.reset(seed=0)
    u = env.unwrapped
    start = u.sim.state[0, 0:3].copy()
    base_lo, base_hi = u.mission.working_volume(u.config.working_margin)
    assert start[1] > base_hi[1]                       # outside the mission's own box
    assert np.all(u.world.volume_lo[0] <= start - 30.0) and np.all(u.world.volume_hi[0] >= start + 30.0)
    _, _, term, trunc, info = env.step(u.scaling.hover_action())
    assert not term and not trunc
    env.reset(seed=0, options={"start_offset": (0.0, 0.0, 0.0)})   # the next episode's own box
    assert np.array_equal(u.world.volume_hi[0], np.maximum(base_hi, u.sim.state[0, 0:3] + 30.0))
    env.close()


def test_coverage_grows_while_facing_the_surface_and_counts_new_triangles_once():
    env = make(wind="none")
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    c0 = info["coverage"]
    assert c0 > 0          # the first frame at the stand-off pose already sees triangles
    total_cov_reward = 0.0
    for _ in range(50):
        obs, r, term, trunc, info = env.step(u.scaling.hover_action())
        total_cov_reward += info["reward_terms"]["coverage"]
    # hovering in still air sees the same triangles again: no new coverage, no coverage reward
    assert info["coverage"] == pytest.approx(c0)
    assert total_cov_reward == 0.0
    assert info["metrics"]["redundancy"] > 1.0
    env.close()


def test_without_camera_frames_the_flight_is_the_same_and_coverage_stays_zero():
    """camera_hz = 0 drops the coverage frames (a fifth of a training step's time): the flight,
    every reward term but coverage and the frame-free metrics stay what they are with frames."""
    def fly(**kw):
        env = make(wind={"type": "gust", "mean_speed": 4.0}, **kw)
        env.reset(seed=3)
        u, rows = env.unwrapped, []
        for k in range(60):
            a = u.scaling.hover_action() + 0.05 * np.sin(0.2 * k)
            obs, r, _, _, info = env.step(a.astype(np.float32))
            rows.append((obs["position"].copy(), r - info["reward_terms"]["coverage"], info["coverage"],
                         info["metrics"]["safety_sm"], info["metrics"]["redundancy"]))
        env.close()
        return rows

    framed, blind = fly(), fly(camera_hz=0.0)
    assert framed[-1][2] > 0.0 and framed[-1][4] > 0.0
    for (x, r, _, sm, _), (x0, r0, cov0, sm0, red0) in zip(framed, blind):
        np.testing.assert_array_equal(x0, x)
        assert r0 == pytest.approx(r, rel=1e-12, abs=1e-12) and sm0 == sm
        assert cov0 == 0.0 and np.isnan(red0)      # nothing seen: redundancy undefined
    env = make(camera_hz=0.0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="camera_hz"):
        env.unwrapped.replay_coverage(np.zeros((3, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)), np.ones(3),
                                      np.zeros(3, dtype=bool))
    env.close()


def test_phase_change_swaps_geometry_and_keeps_coverage():
    env = gym.make("WindTurbineInspection-v0", wind="none")
    env.reset(seed=0)
    u = env.unwrapped
    seen_before = u.coverage_counts.copy()
    v1 = u.world.visibility[0].vertices
    u.world.set_phase(0, 1)
    assert u.phase_index == 1 and u.sim.geometry[0] == 1      # collides with and sees the turned rotor
    v2 = u.world.visibility[1].vertices
    assert not np.allclose(v2, v1)       # blades turned
    np.testing.assert_array_equal(u.coverage_counts, seen_before)
    # triangle identity: triangle i turned about the rotor axis keeps its distance to the hub centre
    c = u.mission.turbines[0].rotor_center
    np.testing.assert_allclose(np.linalg.norm(v2 - c, axis=2), np.linalg.norm(v1 - c, axis=2), atol=1e-9)
    env.close()


@pytest.mark.parametrize("bad", [[np.nan, 0, 0, 0], [0, 0, 0], [0, 0, 0, 2.0]])
def test_bad_actions_raise_naming_the_action(bad):
    env = make()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.asarray(bad, dtype=np.float32))
    env.close()


@pytest.mark.parametrize("kw, field", [
    (dict(colour="red"), "colour"),
    (dict(task="hover"), "task"),
    (dict(camera={"focal_length_mm": -1}), "focal_length_mm"),
    (dict(camera={"zoom": 2}), "zoom"),
    (dict(wind={"type": "hurricane"}), "wind type"),
    (dict(wind={"type": "gust", "mean_speed": float("nan")}), "mean_speed"),
    (dict(drone="ingenuity"), "drone preset"),
    (dict(standoff=0.0), "standoff"),
    (dict(camera_hz=-1.0), "camera_hz"),
    (dict(turbine={"blade_length": -3}), "blade_length"),
    (dict(start_progress=1.0), "start_progress"),
    (dict(pose_error_limit=0.0), "pose_error_limit"),
    (dict(pose_error_limit="2"), "pose_error_limit"),
    (dict(reference_lag=2.0, reference_stop=1.0), "reference_stop"),
])
def test_bad_options_raise_naming_the_field(kw, field):
    with pytest.raises(ValueError, match=field):
        make(**kw)


def test_rgb_array_render():
    env = make(render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.dtype == np.uint8 and img.shape == (240, 640, 3)
    assert img.std() > 0     # not a blank frame
    env.close()


def test_camera_does_not_see_its_own_drone():
    """Regression: rays from the camera (on the drone's collision box) must not hit the drone."""
    env = make(wind="none")
    env.reset(seed=0)
    u = env.unwrapped
    u.sim.sync_scene()                       # the drone's body where the drone is
    state = u.sim.state[0]
    origin, R = u.camera.pose(state[0:3], state[6:10])
    # targets all around the camera, a few metres away, in open air: nothing may block them
    dirs = np.random.default_rng(0).normal(size=(200, 3))
    dirs[:, 2] = np.abs(dirs[:, 2])          # upwards: away from the ground
    targets = origin + 1.5 * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = p.rayTestBatch([origin.tolist()] * len(targets), targets.tolist(), collisionFilterMask=ray_mask(0),
                          physicsClientId=u.sim.client)
    assert all(h[0] == -1 for h in hits)
    env.close()


def test_seed_option_makes_the_first_reset_reproducible():
    kw = dict(wind={"type": "dryden", "mean_speed": 4.0}, start_noise=0.5, seed=11)
    a, b = make(**kw), make(**kw)
    oa, _ = a.reset()
    ob, _ = b.reset()
    np.testing.assert_array_equal(oa["position"], ob["position"])
    oc, _ = make(**{**kw, "seed": 12}).reset()
    assert not np.allclose(oa["position"], oc["position"])
    with pytest.raises(ValueError, match="seed"):
        make(seed=-1)
    a.close()
    b.close()


def test_start_progress_starts_on_the_path_at_the_ideal_pose():
    """Random start along the first phase: the drone starts at the stand-off pose of a path point
    (distance d_ref, facing it), the progress matches, different seeds start elsewhere."""
    env = gym.make("WindTurbineInspection-Blade-v0", wind="none", start_progress=0.9)
    u = env.unwrapped
    starts = []
    for seed in range(6):
        obs, info = env.reset(seed=seed)
        a = obs["point"] - obs["position"]
        assert np.hypot(a[0], a[1]) == pytest.approx(u.config.standoff, abs=1e-3)
        assert 0.0 <= float(obs["progress"][0]) <= 0.9
        starts.append(float(obs["progress"][0]))
    assert len(set(np.round(starts, 6))) == 6 and max(starts) > 0.3
    obs0, _ = make(task="blade", wind="none").reset(seed=0)
    assert float(obs0["progress"][0]) == 0.0
    env.close()


def test_reference_thresholds_scale_with_the_standoff():
    env = make(standoff=10.5)
    assert env.unwrapped.world.reference.config.lag_threshold == pytest.approx(1.5)
    assert env.unwrapped.world.reference.config.stop_threshold == pytest.approx(3.0)
    env.close()


def _fly_to_the_end(env, action):
    """Step ``action`` until the episode ends; (terminated, truncated, last info)."""
    info, term, trunc = {}, False, False
    while not (term or trunc):
        _, _, term, trunc, info = env.step(action)
    return term, trunc, info


@pytest.mark.slow
def test_a_mission_that_falls_behind_ends_by_its_time_limit():
    """A hovering drone, stalls only after 10,000 s without progress, and a time limit 10 s over
    the nominal mission (+ the end hold and the deadline margin): the point waits 2 m ahead until
    only the nominal speed from there reaches the end by the deadline, then keeps that speed - one
    stall, the mission completes before the time limit, nearly all of its path passed without
    the drone. A time limit shorter than the mission (an RL training episode) sets no deadline."""
    from wt_inspect_env.world.world import DEADLINE_MARGIN_S
    env = make(wind="none")
    nominal = env.unwrapped.world.reference.ref.nominal_duration
    env.close()
    limit = nominal + 2.0 + DEADLINE_MARGIN_S + 10.0
    env = make(wind="none", reference_stall_time=1e4, time_limit_s=limit)
    u = env.unwrapped
    env.reset(seed=0)
    hover = u.scaling.hover_action()
    term, trunc, info = _fly_to_the_end(env, hover)
    assert trunc and not term and info["mission_complete"] and info["stalls"] == 1
    assert info["time"] < limit - 0.5
    assert info["skipped_m"] > 0.9 * u.world.reference.total_length
    env.close()
    env = make(wind="none", reference_stall_time=1e4, time_limit_s=30.0)
    env.reset(seed=0)
    for _ in range(int(29.0 / env.unwrapped.dt)):
        _, _, _, _, info = env.step(hover)
    assert info["stalls"] == 0 and not env.unwrapped.world.reference.skipping.any()
    env.close()


@pytest.mark.slow
def test_a_drone_that_never_follows_ends_its_mission_with_a_recorded_stall():
    """The closed-loop reference does not wait for ever: a hovering drone (still air) lets it run
    2 m ahead and wait ``reference_stall_time``; by default (``reference_on_stall="skip"``) the
    point then moves on to the end without the drone - the mission ends (mission_complete) well
    before the time limit, with the stall on record; with ``"end"`` the episode ends at the stall
    (truncated, not complete)."""
    env = make(wind="none", reference_stall_time=3.0)
    u = env.unwrapped
    env.reset(seed=0)
    hover = u.scaling.hover_action()
    term, trunc, info = _fly_to_the_end(env, hover)
    assert trunc and not term and info["mission_complete"]      # a completed mission truncates
    assert info["stalls"] >= 1 and info["skipped_m"] > 0.5 * u.world.reference.total_length
    assert info["time"] < 0.6 * u.world.time_limit        # the nominal time plus the stall, not the limit
    env.close()
    env = make(wind="none", reference_stall_time=3.0, reference_on_stall="end")
    env.reset(seed=0)
    hover = env.unwrapped.scaling.hover_action()
    for _ in range(2000):
        _, _, term, trunc, info = env.step(hover)
        if term or trunc:
            break
    assert trunc and not term and not info["mission_complete"] and info["stalls"] == 1
    assert info["time"] == pytest.approx(3.0 + 2.0 / 0.7, abs=1.5)    # ~2 m ahead, then 3 s without progress
    env.close()
    env = make(wind="none", reference_stall_time=3.0, reference_on_stall="skip")
    env.reset(seed=0)
    _, _, _, _, info = env.step(env.unwrapped.scaling.hover_action())
    assert info["stalls"] == 0 and info["skipped_m"] == 0.0
    env.close()
    with pytest.raises(ValueError, match="reference_stall_time"):
        make(reference_stall_time=-1.0)
    with pytest.raises(ValueError, match="d_min"):
        make(d_min=8.0)
    with pytest.raises(ValueError, match="reference_on_stall"):
        make(reference_on_stall="wait")


def test_reference_approach_speed_option():
    """"auto" is the braking bound sqrt(2 a (standoff - d_min)); bad values name the field."""
    from wt_inspect_env.task.env_config import EnvConfig

    assert EnvConfig().reference_approach_speed == pytest.approx((2.0 * 3.0 * (7.0 - 3.0)) ** 0.5)
    assert EnvConfig(standoff=10.0, d_min=4.0).reference_approach_speed == pytest.approx(6.0)
    assert EnvConfig(reference_approach_speed=None).reference_approach_speed is None
    assert EnvConfig(reference_approach_speed=2.5).reference_approach_speed == 2.5
    for bad in ("fast", 0.0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match="reference_approach_speed"):
            EnvConfig(reference_approach_speed=bad)


def test_clearance_shortfall_matches_a_brute_force_distance():
    """The reference's allowance for ideal poses inside d_min, against trimesh's closest point on
    every triangle (no spatial search). At the default d_min the planner's clearance is d_min, so
    no ideal pose falls short; a stricter d_min (5 m) makes the blade roots fall short."""
    from trimesh import triangles as tt

    from wt_inspect_env.task.reference import standoff_poses
    env = make("WindTurbineInspection-v0")
    u = env.unwrapped
    m = u.mission
    assert m.clearance_shortfall(u.config.standoff, u.config.d_min).max() == 0.0
    d_min = 5.0
    short = m.clearance_shortfall(u.config.standoff, d_min)
    assert (short > 0).any()
    ideal = standoff_poses(m.points, m.normals, u.config.standoff)
    rng = np.random.default_rng(0)
    pick = np.concatenate([np.flatnonzero(short > 0)[:40], rng.choice(len(ideal), 40, replace=False)])
    for ph in np.unique(m.phase[pick]):
        sel = pick[m.phase[pick] == ph]
        tri = np.asarray(m.turbines[int(ph) - 1].all_triangles, dtype=float).reshape(-1, 3, 3)
        d = np.array([np.linalg.norm(tt.closest_point(tri, np.repeat(q[None], len(tri), 0)) - q, axis=1).min()
                      for q in ideal[sel]])
        np.testing.assert_allclose(short[sel], np.maximum(0.0, d_min - d), atol=1e-6)
    env.close()
