"""VT-NMPC: residual definitions and signs, weights, the policy interface and closed-loop behaviour
on the model plant (with rotor drag) and, when available, the PyBullet simulator."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from closed_loop import ModelPlant, SurfacePass, inspection_geometry, make_observation, offset_start, run_closed_loop

from controllers.rti import RTIOptions
from controllers.vtnmpc import (
    STAGE_RESIDUAL_NAMES,
    WEIGHT_SETS,
    VTNMPCConfig,
    VTNMPCPolicy,
    VTNMPCWeights,
    attitude_residual,
    build_ocp,
    residual_functions,
    visual_terms,
    vtnmpc_parameters,
)
from wt_inspect_env.physics.dynamics import quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import GRAVITY, get_preset
from wt_inspect_env.physics.wind import GustWind
from wt_inspect_env.policy import Policy
from wt_inspect_env.task.geometry import horizontal_normal
from wt_inspect_env.task.geometry import standoff_state as ideal_state

D_REF = 7.0


@pytest.fixture(scope="module")
def solver_options(qp_cache_dir) -> RTIOptions:
    return RTIOptions(cache_dir=qp_cache_dir)


@pytest.fixture(scope="module")
def policy(solver_options) -> VTNMPCPolicy:
    return VTNMPCPolicy(VTNMPCConfig(solver=solver_options))


def _stage(cfg: VTNMPCConfig, x, u, params) -> np.ndarray:
    stage, _ = residual_functions(cfg)
    return np.asarray(stage(x, u, params)).ravel()


NORMALS = [(1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.6, 0.8, 0.0), (-0.8, 0.3, 0.52)]


@pytest.mark.parametrize("normal", NORMALS)
def test_residuals_at_reference_at_the_ideal_pose(normal):
    cfg = VTNMPCConfig()
    point = np.array([3.0, -2.0, 40.0])
    v_point = np.array([0.4, -0.3, 0.5])
    nxy = horizontal_normal(np.array(normal), None)
    x = ideal_state(point, normal, D_REF)
    # moving with the point: body velocity = R^T v_point
    x[3:6] = quat_to_rotmat_np(x[6:10]).T @ v_point
    params = vtnmpc_parameters(x, point, nxy, v_point)
    r = _stage(cfg, x, cfg.hover_input, params)
    # every residual at its reference; o is sqrt(eps) there (the guarded norm)
    np.testing.assert_allclose(r, 0.0, atol=2e-3)
    assert abs(r[STAGE_RESIDUAL_NAMES.index("o")]) == pytest.approx(np.sqrt(cfg.norm_eps))
    h, d, roi, o = np.asarray(visual_terms(x, params, cfg.norm_eps)).ravel()
    assert h == pytest.approx(1.0, abs=1e-6)
    assert d == pytest.approx(D_REF, abs=1e-6)
    assert roi == pytest.approx(-D_REF, abs=1e-9)     # outward normal: the drone sits at -d_ref
    assert o == pytest.approx(0.0, abs=2e-3)
    _, terminal = residual_functions(cfg)
    np.testing.assert_allclose(np.asarray(terminal(x, params)).ravel(), 0.0, atol=1e-9)


def test_residual_signs_away_from_the_ideal_pose():
    cfg = VTNMPCConfig()
    point, normal = np.array([0.0, 0.0, 10.0]), np.array([1.0, 0.0, 0.0])
    params = vtnmpc_parameters(ideal_state(point, normal, D_REF), point, normal[:2], np.zeros(3))
    # behind the surface (wrong side): r = +d_ref, facing away from the point: h = -1
    wrong = ideal_state(point, -normal, D_REF)
    wrong[6:10] = ideal_state(point, normal, D_REF)[6:10]   # yaw towards -x: away from the point
    h, d, roi, o = np.asarray(visual_terms(wrong, params, cfg.norm_eps)).ravel()
    assert roi == pytest.approx(D_REF) and h == pytest.approx(-1.0) and d == pytest.approx(D_REF)
    # 2 m above the ideal pose: d and r unchanged (horizontal), o = 2 (vertical offset counts)
    high = ideal_state(point, normal, D_REF)
    high[2] += 2.0
    h, d, roi, o = np.asarray(visual_terms(high, params, cfg.norm_eps)).ravel()
    assert (h, d, roi) == pytest.approx((1.0, D_REF, -D_REF)) and o == pytest.approx(2.0, abs=1e-6)
    # sideways along the surface by 1 m: o = 1, d = sqrt(50), heading cos(atan(1/7))
    side = ideal_state(point, normal, D_REF)
    side[1] += 1.0
    h, d, roi, o = np.asarray(visual_terms(side, params, cfg.norm_eps)).ravel()
    assert o == pytest.approx(1.0, abs=1e-6) and d == pytest.approx(np.sqrt(50.0))
    assert h == pytest.approx(np.cos(np.arctan(1 / 7))) and roi == pytest.approx(-D_REF)
    # pitched by 10 deg: the heading counts the full attitude (paper's R e_x), h = cos(10 deg)
    pitched = ideal_state(point, normal, D_REF)
    qp = np.array([0.0, np.sin(np.deg2rad(5)), 0.0, np.cos(np.deg2rad(5))])
    qy = pitched[6:10]   # yaw quaternion; pitch about the body y axis after the yaw
    pitched[6:10] = np.asarray(ca.DM(_qmul(qy, qp))).ravel()
    h = float(np.asarray(visual_terms(pitched, params, cfg.norm_eps)).ravel()[0])
    assert h == pytest.approx(np.cos(np.deg2rad(10)), abs=1e-7)   # eps guard in ||a_xy||


def test_camera_heading_ignores_tilt_and_equals_the_env_camera_heading():
    """heading_model="camera": the gimbal camera's yaw-only heading (the metric's h), unchanged by
    roll and pitch, and equal to the environment's camera heading for any attitude."""
    cfg = VTNMPCConfig(heading_model="camera")
    point, normal = np.array([0.0, 0.0, 10.0]), np.array([1.0, 0.0, 0.0])
    base = ideal_state(point, normal, D_REF)
    params = vtnmpc_parameters(base, point, normal[:2], np.zeros(3))
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = base.copy()
        x[:3] += rng.normal(0.0, 1.0, 3)
        q = rng.normal(size=4)
        x[6:10] = q / np.linalg.norm(q)
        h_cam = float(np.asarray(visual_terms(x, params, 1e-12, "camera")).ravel()[0])
        R = quat_to_rotmat_np(x[6:10])
        fwd = R[:2, 0] / np.linalg.norm(R[:2, 0])
        a = point[:2] - x[:2]
        assert h_cam == pytest.approx(float(fwd @ a / np.linalg.norm(a)), abs=1e-6)
    # pitched by 10 deg and rolled by 20 deg at the ideal pose: still h = 1 (body model: < 1)
    tilted = base.copy()
    q_tilt = _qmul(np.array([0.0, np.sin(np.deg2rad(5)), 0.0, np.cos(np.deg2rad(5))]),
                   np.array([np.sin(np.deg2rad(10)), 0.0, 0.0, np.cos(np.deg2rad(10))]))
    tilted[6:10] = np.asarray(ca.DM(_qmul(base[6:10], q_tilt))).ravel()
    h_cam = float(np.asarray(visual_terms(tilted, params, cfg.norm_eps, "camera")).ravel()[0])
    h_body = float(np.asarray(visual_terms(tilted, params, cfg.norm_eps, "body")).ravel()[0])
    assert h_cam == pytest.approx(1.0, abs=1e-6) and h_body < 0.99
    # chord heading residual: |f - a_hat| = 2 sin(err / 2), reference 0; the rest unchanged
    stage_paper, _ = residual_functions(VTNMPCConfig(heading_model="camera", norm_eps=1e-12))
    stage_chord, _ = residual_functions(VTNMPCConfig(heading_model="camera", norm_eps=1e-12,
                                                     heading_residual="chord"))
    yawed = base.copy()
    err = np.deg2rad(12.0)
    yawed[6:10] = np.asarray(ca.DM(_qmul(base[6:10], np.array([0, 0, np.sin(err / 2), np.cos(err / 2)])))).ravel()
    u0 = VTNMPCConfig().hover_input
    r_p = np.asarray(stage_paper(yawed, u0, params)).ravel()
    r_c = np.asarray(stage_chord(yawed, u0, params)).ravel()
    assert r_p[0] == pytest.approx(np.cos(err) - 1.0, abs=1e-9)
    assert r_c[0] == pytest.approx(2 * np.sin(err / 2), abs=1e-5)
    np.testing.assert_allclose(r_c[1:], r_p[1:])
    with pytest.raises(ValueError, match="heading_residual"):
        VTNMPCConfig(heading_residual="angle")
    with pytest.raises(ValueError, match="heading_model"):
        VTNMPCConfig(heading_model="gimbal")
    with pytest.raises(ValueError, match="observer_max_accel"):
        VTNMPCConfig(observer_max_accel=10.0)


def _qmul(a, b):
    from wt_inspect_env.physics.dynamics import quat_product
    return quat_product(a, b)


def test_guarded_norms_keep_gauss_newton_data_finite():
    """Drone exactly above the point: ||a_xy|| = 0 and o's vector = 0; Jacobians stay finite."""
    cfg = VTNMPCConfig()
    stage, _ = residual_functions(cfg)
    x = ca.SX.sym("x", 10)
    u = ca.SX.sym("u", 4)
    p = ca.SX.sym("p", 11)
    J = ca.Function("J", [x, u, p], [ca.jacobian(stage(x, u, p), ca.vertcat(x, u))])
    state = np.array([0.0, 0.0, 10.0, 0, 0, 0, 0, 0, 0, 1.0])
    params = np.concatenate([[0.0, 0.0, 10.0], [1.0, 0.0], np.zeros(6)])
    assert np.all(np.isfinite(np.asarray(J(state, cfg.hover_input, params))))
    assert np.all(np.isfinite(_stage(cfg, state, cfg.hover_input, params)))


def test_attitude_reference_with_disturbance():
    """With a_ext the (qx, qy) residual vanishes at the tilt whose thrust cancels it, any yaw."""
    a_ext = np.array([2.0, -1.0, 0.0])
    z_des = np.array([-a_ext[0], -a_ext[1], GRAVITY])
    z_des /= np.linalg.norm(z_des)
    for yaw in (0.0, 1.0, -2.5):
        # tilt (world) after yaw: q = q_tilt (x) q_yaw, body z = z_des
        axis = np.cross([0, 0, 1.0], z_des)
        ang = np.arccos(z_des[2])
        q_t = np.concatenate([np.sin(ang / 2) * axis / np.linalg.norm(axis), [np.cos(ang / 2)]])
        q = np.asarray(ca.DM(_qmul(q_t, [0, 0, np.sin(yaw / 2), np.cos(yaw / 2)]))).ravel()
        np.testing.assert_allclose(quat_to_rotmat_np(q)[:, 2], z_des, atol=1e-12)
        res = np.asarray(attitude_residual(ca.DM(q), ca.DM(a_ext))).ravel()
        np.testing.assert_allclose(res, 0.0, atol=1e-12)
    # no disturbance: exactly the paper's (qx, qy)
    q = np.array([0.1, -0.2, 0.3, 0.927])
    np.testing.assert_allclose(np.asarray(attitude_residual(ca.DM(q), ca.DM.zeros(3))).ravel(),
                               q[:2], atol=1e-15)


def test_point_velocity_reference_is_in_the_body_frame():
    x = ideal_state([0, 0, 10], [0, -1, 0], D_REF)       # yaw +90 deg: body x = world y
    params = vtnmpc_parameters(x, np.array([0, 0, 10.0]), np.array([0.0, -1.0]),
                               np.array([0.7, 0.0, 0.2]))
    np.testing.assert_allclose(params[5:8], [0.0, -0.7, 0.2], atol=1e-12)


def test_normal_handling():
    np.testing.assert_allclose(horizontal_normal(np.array([0.6, 0.0, 0.8]), None), [1.0, 0.0])
    fallback = np.array([0.0, 1.0])
    assert horizontal_normal(np.array([0.0, 0.0, 1.0]), fallback) is fallback
    assert horizontal_normal(np.array([1e-9, 0.0, -1.0]), None) is None


def test_paper_weights_are_the_default():
    w = VTNMPCConfig().weights
    assert w == VTNMPCWeights.paper() == WEIGHT_SETS["paper"]
    np.testing.assert_array_equal(w.stage_vector(),
                                  [80, 30, 25, 60, 0.3, 0.3, 1, 80, 80, 1, 1, 0.25, 0.03])
    np.testing.assert_allclose(w.terminal_vector(), 1.5 * np.array([0.3, 0.3, 1, 80, 80]))
    t = VTNMPCWeights.later_tuning()
    np.testing.assert_array_equal(t.stage_vector(),
                                  [120, 70, 30, 70, 3, 3, 5, 60, 60, 10, 10, 1.7, 0.025])
    assert VTNMPCConfig(weights="later_tuning").weights == t


@pytest.mark.parametrize("kwargs, field", [
    (dict(heading=-1.0), "weights.heading"),
    (dict(distance=float("nan")), "weights.distance"),
    (dict(x_star=(1, 1, 1, 1)), "weights.x_star"),
    (dict(inputs=(1, 1, 0, 1)), r"weights.inputs\[2\]"),
    (dict(terminal_factor=-2), "weights.terminal_factor"),
])
def test_invalid_weights_name_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        VTNMPCWeights(**kwargs)


@pytest.mark.parametrize("kwargs, field", [
    (dict(horizon=0), "horizon"), (dict(horizon=12.5), "horizon"), (dict(dt=0.0), "dt"),
    (dict(d_ref=-7), "d_ref"), (dict(weights="best"), "weights"), (dict(backend="acados"), "backend"),
    (dict(norm_eps=0), "norm_eps"), (dict(rk4_steps=0), "rk4_steps"),
])
def test_invalid_config_names_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        VTNMPCConfig(**kwargs)
    with pytest.raises(ValueError, match="unknown VTNMPCConfig"):
        VTNMPCPolicy(VTNMPCConfig(), horizonn=3)


def test_ocp_matches_paper_setup():
    cfg = VTNMPCConfig()
    ocp = build_ocp(cfg)
    m = get_preset("matrice100").mass
    assert (ocp.horizon, ocp.dt, ocp.nx, ocp.nu) == (30, 0.01, 10, 4)
    np.testing.assert_allclose(ocp.u_lower, [-np.deg2rad(100)] * 3 + [0.3 * m * GRAVITY])
    np.testing.assert_allclose(ocp.u_upper, [np.deg2rad(100)] * 3 + [2.0 * m * GRAVITY])
    np.testing.assert_allclose(ocp.fallback_input, [0, 0, 0, m * GRAVITY])


def test_policy_interface(policy):
    assert isinstance(policy, Policy)
    sc = SurfacePass()
    x = offset_start(sc, D_REF)
    obs = make_observation(x, sc.point(0.0), np.array(sc.normal), sc.velocity())
    policy.reset(seed=3)
    a = policy.act(obs)
    assert a.dtype == np.float32 and a.shape == (4,) and np.all(np.abs(a) <= 1)
    st = policy.last_stats
    assert st.status == "SUCCESS" and not st.fallback and st.qp_iterations > 0
    assert st.solve_ms > 0 and st.feedback_ms > 0 and st.prepare_ms > 0
    # sb3 predict: unbatched and batched (one env), episode_start resets the warm start
    a2, state = policy.predict(obs, state=None, episode_start=np.array([True]))
    assert state is None
    np.testing.assert_allclose(a2, a, atol=1e-6)     # same obs after a reset: same action
    batched = {k: v[None] for k, v in obs.items()}
    a3, _ = policy.predict(batched, episode_start=np.array([True]))
    assert a3.shape == (1, 4)
    np.testing.assert_allclose(a3[0], a, atol=1e-6)
    with pytest.raises(ValueError, match="one environment"):
        policy.predict({k: np.stack([v, v]) for k, v in obs.items()})
    bad = dict(obs, point=np.array([np.nan, 0, 0], dtype=np.float32))
    with pytest.raises(ValueError, match="point"):
        policy.act(bad)
    with pytest.raises(ValueError, match="normal"):
        policy.act({k: v for k, v in obs.items() if k != "normal"})


def test_at_the_ideal_pose_the_command_is_hover(policy):
    sc = SurfacePass(speed=0.0)
    x = sc.ideal_state(0.0, D_REF)
    obs = make_observation(x, sc.point(0.0), np.array(sc.normal), np.zeros(3))
    policy.reset()
    for _ in range(30):   # let the warm start settle on the equilibrium
        policy.act(obs)
    np.testing.assert_allclose(policy.last_command, policy.config.hover_input, atol=1e-3)
    np.testing.assert_allclose(policy.act(obs), policy.scaling.hover_action(), atol=1e-4)


def test_weights_switch_without_recompiling(policy):
    lib = policy.solver.qp_data.path
    policy.set_weights("later_tuning")
    np.testing.assert_array_equal(policy.solver.stage_weights,
                                  VTNMPCWeights.later_tuning().stage_vector())
    assert policy.solver.qp_data.path == lib
    policy.set_weights(VTNMPCWeights())
    with pytest.raises(ValueError, match="weights"):
        policy.set_weights("nonsense")


@pytest.mark.slow
def test_closed_loop_settles_on_a_moving_point(policy):
    """Model plant with rotor drag, no wind; point moving at 0.7 m/s along the surface."""
    cfg = policy.config
    sc = SurfacePass(speed=0.7)
    plant = ModelPlant(cfg.params, dt=cfg.dt)
    res = run_closed_loop(policy, plant, sc, 1000, offset_start(sc, D_REF), cfg.scaling, cfg.dt)
    assert res.fallbacks == 0
    last = slice(-300, None)    # the last 3 s of 10
    assert np.max(np.abs(res.distance[last] - D_REF)) < 0.1
    assert np.min(res.heading[last]) > 0.99
    assert abs(res.distance[0] - D_REF) > 0.5    # it really had to move


# The gust flights below last GUST_STEPS: the sudden onset and, after the 3 s the observer takes, one
# whole 10 s gust period; the flight is periodic from then on (over 20 s the largest deviation after
# 3 s, 0.20 m, recurs at 12.1 s, inside this window).
GUST_STEPS = 1300


@pytest.mark.slow
def test_gust_keeps_safety_metric_with_disturbance_observer(solver_options):
    """The paper's wind (4 m/s mean + sinusoid, along y) blowing along the surface normal, the
    hardest direction; a surface pass starting at the ideal pose (13 s)."""
    pol = VTNMPCPolicy(VTNMPCConfig(solver=solver_options, disturbance_observer=True))
    cfg = pol.config
    sc = SurfacePass(normal=(0.0, -1.0, 0.0), direction=(1.0, 0.0, 0.0))
    plant = ModelPlant(cfg.params, dt=cfg.dt, wind=GustWind(4.0))
    res = run_closed_loop(pol, plant, sc, GUST_STEPS, sc.ideal_state(0.0, D_REF), cfg.scaling, cfg.dt)
    assert res.safety_metric(D_REF, margin=1.0) == 1.0
    # once the observer has caught the sudden wind (first 3 s: up to 0.62 m), within 0.3 m
    assert np.max(np.abs(res.distance[300:] - D_REF)) < 0.3
    assert res.fallbacks == 0
    assert np.linalg.norm(pol.disturbance_estimate) > 1.0   # it did estimate the drag


@pytest.mark.slow
def test_gust_across_the_normal_keeps_safety_metric_with_paper_controller(policy):
    """Paper's controller unchanged: wind along y across a surface facing +x (blade edges)."""
    cfg = policy.config
    sc = SurfacePass(normal=(1.0, 0.0, 0.0), direction=(0.0, 0.0, 1.0))
    plant = ModelPlant(cfg.params, dt=cfg.dt, wind=GustWind(4.0))
    res = run_closed_loop(policy, plant, sc, GUST_STEPS, sc.ideal_state(0.0, D_REF), cfg.scaling, cfg.dt)
    assert res.safety_metric(D_REF, margin=1.0) == 1.0
    assert res.fallbacks == 0


def _sim():
    sim_mod = pytest.importorskip("wt_inspect_env.world.sim")
    return sim_mod.QuadrotorSim, sim_mod.SimConfig


def test_closed_loop_in_pybullet_sim_settles(policy):
    QuadrotorSim, SimConfig = _sim()
    cfg = policy.config
    sc = SurfacePass(normal=(1.0, 0.0, 0.0), direction=(0.0, 1.0, 0.0))
    sim = QuadrotorSim(cfg.params, SimConfig(), wind=None)
    try:
        res = run_closed_loop(policy, sim, sc, 1000, offset_start(sc, D_REF), cfg.scaling, cfg.dt)
    finally:
        if hasattr(sim, "close"):
            sim.close()
    last = slice(-300, None)
    assert np.max(np.abs(res.distance[last] - D_REF)) < 0.1
    assert np.min(res.heading[last]) > 0.99
    assert res.fallbacks == 0


@pytest.mark.slow
def test_gust_in_pybullet_sim_keeps_safety_metric(solver_options):
    QuadrotorSim, SimConfig = _sim()
    pol = VTNMPCPolicy(VTNMPCConfig(solver=solver_options, disturbance_observer=True))
    cfg = pol.config
    sc = SurfacePass(normal=(0.0, -1.0, 0.0), direction=(1.0, 0.0, 0.0))
    sim = QuadrotorSim(cfg.params, SimConfig(), wind=GustWind(4.0))
    try:
        res = run_closed_loop(pol, sim, sc, GUST_STEPS, sc.ideal_state(0.0, D_REF), cfg.scaling, cfg.dt)
    finally:
        if hasattr(sim, "close"):
            sim.close()
    assert res.safety_metric(D_REF, margin=1.0) == 1.0
    assert res.fallbacks == 0


def test_inspection_geometry_helper():
    x = ideal_state([1.0, 2.0, 3.0], [0.0, 1.0, 0.0], D_REF)
    d, h = inspection_geometry(x, np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0]))
    assert d == pytest.approx(D_REF) and h == pytest.approx(1.0)
