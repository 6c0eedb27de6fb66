"""RL agents: features, residual-hover actions, recipes, training/checkpoint/resume, the policy
adaptor and its equivalence with the training wrapper, bad names."""
from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the env ids
from agents.policy import load_sb3_policy, sidecar_paths
from agents.recipe import Recipe, default_recipe_path, load_recipe
from agents.wrappers import (
    ActionConfig,
    AgentSpec,
    FeatureConfig,
    FeatureEncoder,
    InspectionAgentEnv,
    ResidualHoverAction,
)
from wt_inspect_env.physics.dynamics import yaw_to_quat
from wt_inspect_env.physics.quadrotor import GRAVITY
from wt_inspect_env.task.spaces import ActionScaling

SURFACE = "WindTurbineInspection-Surface-v0"
ALL_GROUPS = ("ideal_body", "point_body", "velocity_body", "gravity_body", "heading", "body_rates",
              "normal_body", "integral", "last_action", "progress", "coverage")


def _obs(position, quaternion, point=(0.0, 0.0, 10.0), normal=(0.0, 1.0, 0.0), velocity_body=(0, 0, 0),
         point_velocity=(0, 0, 0), body_rates=(0, 0, 0)):
    return {"position": np.array(position, float), "velocity_body": np.array(velocity_body, float),
            "quaternion": np.array(quaternion, float), "body_rates": np.array(body_rates, float),
            "point": np.array(point, float), "normal": np.array(normal, float),
            "point_velocity": np.array(point_velocity, float), "coverage": np.array([0.25]),
            "progress": np.array([0.5])}


def _split(cfg: FeatureConfig, f: np.ndarray) -> dict[str, np.ndarray]:
    out, i = {}, 0
    from agents.wrappers import FEATURE_SIZES
    for g in cfg.groups:
        out[g] = f[i:i + FEATURE_SIZES[g]]
        i += FEATURE_SIZES[g]
    return out


def _encoder(**kw) -> FeatureEncoder:
    cfg = FeatureConfig(groups=ALL_GROUPS, **kw)
    return FeatureEncoder(cfg, standoff=7.0, dt=0.01, max_rate=np.deg2rad(100))


# ---------------------------------------------------------------------------------------- features
def test_features_are_zero_at_the_ideal_pose_of_the_env():
    env = gym.make(SURFACE, wind="none")
    wrapped = InspectionAgentEnv(env, AgentSpec(features=FeatureConfig(groups=ALL_GROUPS)))
    f, info = wrapped.reset(seed=0)
    parts = _split(wrapped.spec_.features, f)
    np.testing.assert_allclose(parts["ideal_body"], 0.0, atol=1e-6)     # start = ideal pose
    np.testing.assert_allclose(parts["velocity_body"], 0.0, atol=1e-6)
    np.testing.assert_allclose(parts["gravity_body"], [0, 0, -1], atol=1e-6)   # level
    np.testing.assert_allclose(parts["heading"], [0, 1], atol=1e-6)     # camera on the point
    np.testing.assert_allclose(parts["point_body"], [1, 0, 0], atol=1e-6)  # d_ref straight ahead
    np.testing.assert_allclose(parts["normal_body"], [-1, 0, 0], atol=1e-6)  # surface faces the drone
    np.testing.assert_allclose(parts["integral"], 0.0, atol=1e-9)
    # the encoder's ideal pose is the env's
    raw_obs = {k: v[0] for k, v in env.unwrapped.world.observations(np.zeros(1, dtype=bool)).items()}
    np.testing.assert_allclose(wrapped.encoder.ideal_position(raw_obs), info["ideal_position"], atol=1e-5)
    env.close()


def test_relative_position_is_rotated_into_the_body_frame():
    enc = _encoder(position_scale=2.0)
    ideal = np.array([0.0, 7.0, 10.0])
    q = yaw_to_quat(-math.pi / 2)           # facing -y: body x = world -y, body y = world +x
    f = _split(enc.config, enc.update(_obs(ideal + [1.0, 0.0, 0.5], q)))
    # error ideal - x = (-1, 0, -0.5) world -> body (0, -1, -0.5), scaled by 2 m
    np.testing.assert_allclose(f["ideal_body"], [0.0, -0.5, -0.25], atol=1e-12)
    # the point is 7 m along -y and 1 m along -x: ahead and to the right (negative sin)
    s, c = f["heading"]
    assert s == pytest.approx(-1 / math.hypot(1, 7)) and c == pytest.approx(7 / math.hypot(1, 7))
    np.testing.assert_allclose(f["progress"], [0.5]) and np.testing.assert_allclose(f["coverage"], [0.25])


def test_velocity_is_relative_to_the_moving_point_and_gravity_shows_the_tilt():
    enc = _encoder(velocity_scale=2.0)
    roll = 0.3
    q = [math.sin(roll / 2), 0.0, 0.0, math.cos(roll / 2)]   # roll right-wing down about body x
    # body velocity equal to the point's world velocity expressed in the body frame -> zero feature
    R = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
    vp = np.array([0.7, -0.2, 0.1])
    f = _split(enc.config, enc.update(_obs([0, 7, 10], q, velocity_body=R.T @ vp, point_velocity=vp)))
    np.testing.assert_allclose(f["velocity_body"], 0.0, atol=1e-12)
    np.testing.assert_allclose(f["gravity_body"], R.T @ [0, 0, -1], atol=1e-12)
    assert f["gravity_body"][1] == pytest.approx(-math.sin(roll))


def test_pose_velocity_is_the_swing_of_the_pose_round_a_turning_normal():
    """Round a blade tip the point stands still while its normal turns at omega: the stand-off pose
    q = p + d n moves at d omega (tangential). A drone flying with q sees a zero pose velocity
    (to the finite difference's O(omega dt) error) and a velocity relative to the point of d omega;
    on an episode's first update (no previous normal) the pose velocity is the point's."""
    cfg = FeatureConfig(groups=("velocity_body", "pose_velocity_body"), velocity_scale=1.0)
    enc = FeatureEncoder(cfg, standoff=7.0, dt=0.01, max_rate=np.deg2rad(100))
    omega, p = 0.5, np.array([0.0, 0.0, 10.0])
    q = yaw_to_quat(0.0)                      # body = world: velocities compare directly

    def at(t):
        n = np.array([math.cos(omega * t), math.sin(omega * t), 0.0])
        v = 7.0 * omega * np.array([-math.sin(omega * t), math.cos(omega * t), 0.0])
        return _obs(p + 7.0 * n, q, point=p, normal=n, velocity_body=v)

    first = _split(cfg, enc.update(at(0.0)))
    np.testing.assert_allclose(first["pose_velocity_body"], first["velocity_body"], atol=1e-12)
    for k in range(1, 50):
        f = _split(cfg, enc.update(at(0.01 * k)))
    assert np.linalg.norm(f["velocity_body"]) == pytest.approx(3.5, rel=1e-5)    # float32 features
    assert np.linalg.norm(f["pose_velocity_body"]) < 0.02       # d omega^2 dt / 2 = 0.0088 m/s
    enc.reset()                                                 # a new episode forgets the turn
    again = _split(cfg, enc.update(at(1.0)))
    np.testing.assert_allclose(again["pose_velocity_body"], again["velocity_body"], atol=1e-12)


def test_integral_feature_approaches_the_error_and_clip_bounds_everything():
    enc = _encoder(position_scale=2.0, integral_time_s=1.0, clip=5.0)
    o = _obs([0.0, 8.0, 10.0], [0, 0, 0, 1])       # 1 m beyond the stand-off along +y
    for _ in range(1000):                           # 10 s = 10 time constants
        f = _split(enc.config, enc.update(o))
    np.testing.assert_allclose(f["integral"], f["ideal_body"], rtol=1e-4)   # leaky integral -> error
    far = _split(enc.config, enc.update(_obs([0.0, 500.0, 10.0], [0, 0, 0, 1])))
    assert far["ideal_body"][1] == -5.0             # saturated, not 246
    enc.reset()
    again = _split(enc.config, enc.update(o))
    np.testing.assert_allclose(again["integral"], (1 - math.exp(-0.01)) * f["ideal_body"], rtol=1e-6)


def test_feature_config_rejects_unknown_groups_listing_valid_ones():
    with pytest.raises(ValueError, match="ideal_body"):
        FeatureConfig(groups=("ideal_body", "wind"))
    with pytest.raises(ValueError, match="repeat"):
        FeatureConfig(groups=("ideal_body", "ideal_body"))


# ----------------------------------------------------------------------------------------- actions
def test_zero_policy_action_is_hover_and_tilt_compensated():
    scaling = ActionScaling(mass=3.6)
    dec = ResidualHoverAction(ActionConfig(tilt_compensation=True, thrust_scale=0.5), scaling)
    np.testing.assert_allclose(dec(np.zeros(4), [0, 0, 0, 1]), scaling.hover_action(), atol=1e-6)
    tilt = 0.4
    cmd = dec.command(np.zeros(4), [math.sin(tilt / 2), 0, 0, math.cos(tilt / 2)])
    assert cmd[3] * math.cos(tilt) == pytest.approx(3.6 * GRAVITY)   # vertical thrust = weight
    cmd = dec.command([0.5, -1.0, 0.25, 1.0], [0, 0, 0, 1])
    np.testing.assert_allclose(cmd, [0.5 * scaling.max_rate, -scaling.max_rate, 0.25 * scaling.max_rate,
                                     1.5 * 3.6 * GRAVITY])
    with pytest.raises(ValueError, match="policy action"):
        dec(np.array([0, 0, 0, 1.5]), [0, 0, 0, 1])
    with pytest.raises(ValueError, match="thrust_scale"):
        ActionConfig(thrust_scale=0.9)


@pytest.mark.slow
def test_a_pd_law_on_the_features_holds_the_pose_in_the_gust():
    """The features and the action mapping are consistent (signs, frames, scales): a textbook
    cascaded PD on them, through the wrapper, tracks the moving stand-off pose in the paper's gust."""
    spec = AgentSpec(features=FeatureConfig(groups=("ideal_body", "velocity_body", "gravity_body", "heading",
                                                    "integral")),
                     action=ActionConfig(tilt_compensation=False), action_repeat=2)
    env = InspectionAgentEnv(gym.make(SURFACE, wind={"type": "gust", "mean_speed": 4.0}), spec)
    f, _ = env.reset(seed=0)
    max_rate = np.deg2rad(100)
    errors = []
    for _ in range(1000):                      # 20 s
        e, v, g, sin_h, integ = f[0:3] * 2, f[3:6] * 2, f[6:9], f[9], f[11:14] * 10
        acc = 2.0 * e - 2.5 * v + 0.5 * integ
        t = acc - GRAVITY * g
        th = t / np.linalg.norm(t)
        u = np.clip([-6 * th[1] / max_rate, 6 * th[0] / max_rate, 2 * sin_h / max_rate,
                     (np.linalg.norm(t) / GRAVITY - 1) / 0.5], -1, 1)
        f, _, term, trunc, info = env.step(u)
        assert not term
        errors.append(np.linalg.norm(f[0:3] * 2))
    assert np.mean(errors[500:]) < 1.0          # within the SM band while tracking, wind included
    assert info["metrics"]["safety_sm"] > 0.8 and info["metrics"]["centering_cm"] > 0.95
    assert info["coverage"] > 0.3
    env.close()


def test_attitude_mode_points_the_thrust_at_the_set_point():
    scaling = ActionScaling(mass=3.6)
    dec = ResidualHoverAction(ActionConfig(mode="attitude", max_tilt_deg=30.0, attitude_gain=5.0), scaling)
    level = [0, 0, 0, 1]
    np.testing.assert_allclose(dec(np.zeros(4), level), scaling.hover_action(), atol=1e-6)
    # pitch set-point forward (u[1] = 1 -> 30 deg): positive pitch rate q, no roll rate
    cmd = dec.command([0.0, 1.0, 0.0, 0.0], level)
    assert cmd[0] == pytest.approx(0.0, abs=1e-12) and cmd[1] == pytest.approx(5.0 * math.sin(math.radians(30)))
    # roll set-point +1 (right wing down, thrust axis towards -y): positive roll rate p, no pitch rate
    cmd = dec.command([1.0, 0.0, 0.0, 0.0], level)
    assert cmd[0] == pytest.approx(5.0 * math.sin(math.radians(30))) and cmd[1] == pytest.approx(0.0, abs=1e-12)
    # already at the set-point (yawed, rolled 30 deg): no rate command; the yaw rate comes from u[2]
    yaw, roll = 1.0, math.radians(30)
    qy = np.array([0, 0, math.sin(yaw / 2), math.cos(yaw / 2)])
    qr = np.array([math.sin(roll / 2), 0, 0, math.cos(roll / 2)])
    from wt_inspect_env.physics.dynamics import quat_product
    q = np.asarray(quat_product(qy, qr), dtype=float).reshape(4)
    cmd = dec.command([1.0, 0.0, 0.5, 0.0], q)
    np.testing.assert_allclose(cmd[:2], 0.0, atol=1e-12)
    assert cmd[2] == pytest.approx(0.5 * scaling.max_rate)


def test_a_pd_law_through_the_attitude_mode_tracks_the_pose():
    spec = AgentSpec(features=FeatureConfig(groups=("ideal_body", "velocity_body", "heading", "integral")),
                     action=ActionConfig(mode="attitude"), action_repeat=4)
    env = InspectionAgentEnv(gym.make(SURFACE, wind={"type": "gust", "mean_speed": 4.0}), spec)
    f, _ = env.reset(seed=0)
    errors = []
    for _ in range(500):                       # 20 s
        e, v, sin_h, integ = f[0:3] * 2, f[3:6] * 2, f[6], f[8:11] * 10
        acc = 2.0 * e - 2.5 * v + 0.5 * integ
        u = np.clip([-math.atan2(acc[1], GRAVITY) / math.radians(30), math.atan2(acc[0], GRAVITY) / math.radians(30),
                     2 * sin_h / np.deg2rad(100), acc[2] / GRAVITY / 0.5], -1, 1)
        f, _, term, _, info = env.step(u)
        assert not term
        errors.append(np.linalg.norm(f[0:3] * 2))
    assert np.mean(errors[125:]) < 1.0 and info["metrics"]["safety_sm"] > 0.8
    env.close()


def test_coarse_distance_shaping_is_added_and_reported():
    from agents.wrappers import ShapingConfig
    plain = InspectionAgentEnv(gym.make(SURFACE, wind="none", start_noise=2.0), AgentSpec())
    shaped = InspectionAgentEnv(gym.make(SURFACE, wind="none", start_noise=2.0), AgentSpec(),
                                ShapingConfig(distance_coarse_weight=2.0, distance_coarse_scale=4.0))
    plain.reset(seed=5)
    shaped.reset(seed=5)
    _, r0, *_ , i0 = plain.step(np.zeros(4))
    _, r1, *_ , i1 = shaped.step(np.zeros(4))
    e = np.linalg.norm(shaped.encoder.pose_error())
    assert i0["shaping_reward"] == 0.0
    # 4 control steps of 2 * 0.01 / (1 + (e/4)^2), e nearly constant over 40 ms
    assert i1["shaping_reward"] == pytest.approx(4 * 0.02 / (1 + (e / 4) ** 2), rel=2e-2)
    assert r1 == pytest.approx(r0 + i1["shaping_reward"])
    with pytest.raises(ValueError, match="distance_coarse_scale"):
        ShapingConfig(distance_coarse_scale=0.0)


def test_fine_centering_shaping_follows_the_camera_heading_kernel():
    from agents.wrappers import ShapingConfig
    cfg = ShapingConfig(centering_fine_weight=3.0, centering_fine_scale_deg=5.0)
    # the kernel itself: 1 when centred, 1/e at the scale, from the cosine of the heading error
    assert cfg.centering_fine(0.01, 1.0) == pytest.approx(0.03)
    assert cfg.centering_fine(0.01, math.cos(math.radians(5.0))) == pytest.approx(0.03 / math.e)
    assert cfg.centering_fine(0.01, math.cos(math.radians(20.0))) < 0.03 * 1e-6
    spec = AgentSpec(action_repeat=1)
    plain = InspectionAgentEnv(gym.make(SURFACE, wind="none", start_noise=2.0), spec)
    shaped = InspectionAgentEnv(gym.make(SURFACE, wind="none", start_noise=2.0), spec, cfg)
    plain.reset(seed=5)
    shaped.reset(seed=5)
    _, r0, *_, i0 = plain.step(np.zeros(4))
    _, r1, *_, i1 = shaped.step(np.zeros(4))
    # the encoder's heading is the env's own camera heading (the centering metric's h)
    h = shaped.encoder.heading_cos()
    u = shaped.env.unwrapped
    assert float(np.squeeze(i1["reward_terms"]["centering"])) == pytest.approx(u.config.reward.centering * u.dt * h)
    assert i1["shaping_reward"] == pytest.approx(cfg.centering_fine(u.dt, h))
    assert r1 == pytest.approx(r0 + i1["shaping_reward"])
    for bad in ({"centering_fine_weight": -1.0}, {"centering_fine_scale_deg": 0.0},
                {"centering_fine_scale_deg": 90.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            ShapingConfig(**bad)


def test_episode_variants_draw_reproducibly_by_weight_and_check_spaces():
    from agents.wrappers import EpisodeVariants
    envs = [InspectionAgentEnv(gym.make(SURFACE, wind=w), AgentSpec()) for w in ("none", "gust")]
    var = EpisodeVariants(envs, weights=[3.0, 1.0])
    draws = []
    for k in range(40):
        _, info = var.reset(seed=11 if k == 0 else None)
        draws.append(info["variant"])
    assert set(draws) == {0, 1} and 0.5 < draws.count(0) / 40 < 0.95
    first = [var.reset(seed=11)[1]["variant"]] + [var.reset()[1]["variant"] for _ in range(39)]
    assert first == draws                       # reseeding replays the same sequence
    var.reset(seed=2)
    _, _, _, _, info = var.step(np.zeros(4))
    assert info["variant"] == var.active
    # the wind really differs between the variants
    winds = [e.env.unwrapped.config.wind for e in envs]
    assert winds[0] != winds[1]
    with pytest.raises(ValueError, match="spaces"):
        EpisodeVariants([envs[0], InspectionAgentEnv(gym.make(SURFACE), AgentSpec(action_repeat=2,
                         features=FeatureConfig(groups=("ideal_body",))))])
    with pytest.raises(ValueError, match="weights"):
        EpisodeVariants(envs, weights=[1.0])
    var.close()


# ----------------------------------------------------------------------------------------- recipes
@pytest.mark.parametrize("base_name, stage_name", [("ppo_full_many.json", "ppo_full_many_robust.json"),
                                                    ("ppo_full_many_robust.json", "ppo_full_many_wind.json"),
                                                    ("ppo_full_many_wind.json", "ppo_full_many_turbulence.json")])
def test_a_stage_recipe_can_resume_its_base_models(base_name, stage_name):
    """Each later stage fine-tunes the models of the stage before it (results/reproduce.toml):
    ``--resume`` refuses a recipe whose agent spec (features, action, repeat) differs from the
    checkpoint's, the stage must not silently change the network either, and it trains no faster
    than its base; its periodic evaluation must still count coverage (the training env may not)."""
    from agents.recipe import RECIPE_DIR
    base, stage = load_recipe(RECIPE_DIR / base_name), load_recipe(RECIPE_DIR / stage_name)
    assert stage.spec == base.spec
    assert stage.policy_kwargs == base.policy_kwargs
    assert stage.algo_kwargs["learning_rate"] <= base.algo_kwargs["learning_rate"]
    assert stage.eval_env_options().get("camera_hz", 10.0) > 0


def test_shipped_recipes_load_and_bad_keys_list_valid_ones(tmp_path):
    from agents.recipe import RECIPE_DIR
    for path in sorted(RECIPE_DIR.glob("*.json")):
        rec = load_recipe(path)
        assert rec.algo == "ppo" and rec.spec.features.size > 0
    data = json.loads(default_recipe_path("ppo").read_text())
    with pytest.raises(ValueError, match="algo_kwargs"):
        Recipe.from_dict({**data, "algo_kwrags": {}})
    with pytest.raises(ValueError, match="start_noise"):
        Recipe.from_dict({**data, "env": {"start_nois": 1.0}})
    with pytest.raises(ValueError, match="tanh"):
        Recipe.from_dict({**data, "policy_kwargs": {"activation_fn": "swish"}})
    with pytest.raises(ValueError, match="not found"):
        load_recipe(tmp_path / "nope.json")
    with pytest.raises(ValueError, match="mean_sped"):
        Recipe.from_dict({**data, "env_variants": [{"wind": {"type": "gust", "mean_sped": 3}}]})
    with pytest.raises(ValueError, match="env_variant_weights"):
        Recipe.from_dict({**data, "env_variants": [{"wind": "none"}], "env_variant_weights": [1.0, 2.0]})
    with pytest.raises(ValueError, match="mean_sped"):
        Recipe.from_dict({**data, "eval_variants": [{"wind": {"type": "gust", "mean_sped": 3}}]})
    with pytest.raises(ValueError, match=r"eval_variants\[0\] must not set 'task'"):
        Recipe.from_dict({**data, "eval_variants": [{"task": "full"}]})
    with pytest.raises(ValueError, match="eval_variants must be a list of dicts"):
        Recipe.from_dict({**data, "eval_variants": {"wind": "none"}})


def test_eval_variants_merge_over_the_evaluation_options_and_are_absent_from_old_recipes():
    rec = load_recipe("agents/recipes/dagger_full_gusty.json")
    assert rec.eval_options_list() == [rec.eval_env_options()] and "eval_variants" not in rec.to_dict()
    d = rec.to_dict()
    d["eval_variants"] = [{"wind": "none"}, {}]
    two = Recipe.from_dict(d)
    calm, gust = two.eval_options_list()
    assert calm == {**rec.eval_env_options(), "wind": "none"} and gust == rec.eval_env_options()
    assert calm["structure_observation"] is True          # the evaluation's other options are kept
    assert Recipe.from_dict(two.to_dict()) == two


# ------------------------------------------------------------------------------------------ names
def test_bad_algorithm_or_task_names_list_the_valid_ones(tmp_path, capsys):
    from agents.train_cli import main
    from agents.training import train
    with pytest.raises(ValueError, match="valid: ppo$"):
        train("dqn", "surface", 1000, 1, tmp_path)
    with pytest.raises(ValueError, match="full, blade, surface"):
        train("ppo", "rotor", 1000, 1, tmp_path)
    with pytest.raises(ValueError, match="valid: ppo$"):
        load_sb3_policy("a2c", tmp_path / "m.zip")
    assert main(["--algo", "td3", "--timesteps", "10", "--out", str(tmp_path)]) == 2
    assert "valid: ppo" in capsys.readouterr().err
    assert main(["--algo", "ppo", "--task", "tower", "--timesteps", "10", "--out", str(tmp_path)]) == 2
    assert "full, blade, surface" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())        # nothing written for bad names
    with pytest.raises(ValueError, match="not found"):
        load_sb3_policy("ppo", tmp_path / "missing.zip")


# --------------------------------------------------------------------------- training and resume
def _tiny_recipe(**over) -> Recipe:
    data = json.loads(default_recipe_path("ppo").read_text())
    data["env"] = {**data["env"], "time_limit_s": 4.0}
    data["eval_env"] = {"start_noise": 0.0, "time_limit_s": 2.0}
    data["algo_kwargs"] = {**data["algo_kwargs"], "n_steps": 128, "batch_size": 64, "n_epochs": 2}
    data["policy_kwargs"] = {**data["policy_kwargs"], "net_arch": {"pi": [16], "vf": [16]}}
    data.update(eval_every_env_steps=1000, checkpoint_every_env_steps=1000, **over)
    return Recipe.from_dict(data)


@pytest.mark.slow
def test_short_training_checkpoints_resumes_and_the_model_runs_in_the_harness(tmp_path):
    from agents.training import train
    rec = _tiny_recipe()
    s1 = train("ppo", "surface", 2000, 2, tmp_path / "a", recipe=rec, progress_bar=False)
    ckpts = sorted((tmp_path / "a" / "checkpoints").glob("ckpt_*.zip"), key=lambda p: int(p.stem[5:]))
    assert ckpts, "no checkpoint written"
    for p in ckpts:
        assert all(q.is_file() for q in sidecar_paths(p))
    assert s1["env_steps"] >= 2000 and (tmp_path / "a" / "model.zip").is_file()
    assert (tmp_path / "a" / "learning_curve.png").stat().st_size > 1000
    evals = json.loads((tmp_path / "a" / "evaluations.json").read_text())
    assert len(evals) >= 2 and 0.0 <= evals[-1]["mean"]["coverage"] <= 1.0
    rows = (tmp_path / "a" / "episodes.csv").read_text().splitlines()
    assert rows[0].startswith("env_steps,") and len(rows) > 1      # 4 s episodes ended
    assert any((tmp_path / "a" / "tb").rglob("events.out.tfevents*"))

    ck = ckpts[-1]
    ck_doc = json.loads(sidecar_paths(ck)[1].read_text())
    s2 = train("ppo", "surface", 1000, 1, tmp_path / "b", resume=ck, progress_bar=False)
    assert s2["env_steps"] == ck_doc["training"]["env_steps"] + s2["env_steps_this_call"]
    assert s2["env_steps_this_call"] >= 1000
    from stable_baselines3 import PPO
    m1 = PPO.load(str(ck), device="cpu")
    m2 = PPO.load(str(tmp_path / "b" / "model.zip"), device="cpu")
    assert m2.num_timesteps > m1.num_timesteps                   # counting went on
    w1 = m1.policy.state_dict()["mlp_extractor.policy_net.0.weight"]
    w2 = m2.policy.state_dict()["mlp_extractor.policy_net.0.weight"]
    assert w1.shape == w2.shape and not np.allclose(w1.numpy(), w2.numpy())   # same net, trained on
    doc = json.loads(sidecar_paths(tmp_path / "b" / "model.zip")[1].read_text())
    assert doc["obs_normalization"] is not None and doc["spec"] == ck_doc["spec"]

    # the saved model flies through the evaluation harness by its ppo:PATH name
    from wt_inspect.evaluation.runner import execute, make_spec
    from wt_inspect.evaluation.scenarios import env_options
    path = str(tmp_path / "b" / "model.zip")
    spec = make_spec("surface", f"ppo:{path}", 4.0, 0, env_options("surface", 4.0), max_time=1.0)
    res = execute(spec, record=True)
    assert res.steps >= 1 and 0.0 <= res.metrics["coverage"] <= 1.0
    acts = res.arrays["action"][:-1]
    assert np.all(np.abs(acts) <= 1.0) and np.isfinite(acts).all()
    # rate mode: the body-rate part of the held decision is the same for steps 0-3 (repeat 4)
    np.testing.assert_array_equal(acts[0][:3], acts[3][:3])


@pytest.mark.slow
def test_policy_adaptor_reproduces_the_training_pipeline_exactly(tmp_path):
    """Raw env + load_sb3_policy flies the same trajectory as the training wrapper + VecNormalize
    statistics + the network, step for step."""
    from stable_baselines3 import PPO

    from agents.training import train
    train("ppo", "surface", 600, 1, tmp_path, recipe=_tiny_recipe(), progress_bar=False)
    path = tmp_path / "model.zip"
    doc = json.loads(sidecar_paths(path)[1].read_text())
    norm = doc["obs_normalization"]
    model = PPO.load(str(path), device="cpu")
    opts = {"wind": {"type": "gust", "mean_speed": 4.0}, "start_noise": 0.3}
    wrapped = InspectionAgentEnv(gym.make(SURFACE, **opts), AgentSpec.from_dict(doc["spec"]))
    raw = gym.make(SURFACE, **opts)
    policy = load_sb3_policy("ppo", path, raw.unwrapped)
    f, _ = wrapped.reset(seed=3)
    obs, _ = raw.reset(seed=3)
    policy.reset(3)
    mean, std = np.array(norm["mean"]), np.sqrt(np.array(norm["var"]) + norm["epsilon"])
    for _ in range(50):                       # 50 decisions = 200 control steps
        x = np.clip((f - mean) / std, -norm["clip_obs"], norm["clip_obs"]).astype(np.float32)
        u, _ = model.predict(x, deterministic=True)
        f, _, term, trunc, info = wrapped.step(u)
        for _ in range(4):
            obs, _, t2, tr2, info2 = raw.step(policy.act(obs))
        assert (term, trunc) == (t2, tr2)
        np.testing.assert_array_equal(wrapped.env.unwrapped.sim.state, raw.unwrapped.sim.state)
        if term or trunc:
            break
    assert policy.last_stats["new_decision"] is False      # 4th step of a held decision
    wrapped.close()
    raw.close()
