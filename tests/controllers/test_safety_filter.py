"""The safety filter (``controllers.safety_filter``): it leaves a safe policy alone, it keeps
policies that fly at the structure away from it where they collide without it, it is reachable as
``NAME+filter`` everywhere a controller name is, and the harness reports its counts."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the env ids
from controllers.safety_filter import INTERVENTION_TOL, SafetyFilter
from wt_inspect.evaluation import registry
from wt_inspect.studies import safety_filter as adv


@pytest.mark.slow
def test_a_policy_far_from_the_structure_flies_unchanged():
    env = gym.make("WindTurbineInspection-v0", time_limit_s=5.0)
    try:
        u = env.unwrapped
        inner = registry.resolve("vtnmpc-plus")(u)
        raw = registry.resolve("vtnmpc-plus")(u)
        pol = SafetyFilter(inner, env)
        obs, _ = env.reset(seed=0)
        pol.reset(0)
        raw.reset(0)
        while True:
            a = pol.act(obs)
            np.testing.assert_allclose(a, raw.act(obs), atol=1e-4)   # unchanged up to the QP tolerance
            obs, _, term, trunc, _ = env.step(a)
            if term or trunc:
                break
        assert pol.stats.steps == 500 and pol.stats.interventions == 0 and pol.stats.fallbacks == 0
    finally:
        env.close()


# Each adversary flies once in the quick suite (tower in still air, blade in the 7 m/s gust, hold-inside
# in still air); its second seeded start, in the 4 m/s gust, runs with the slow tests.
@pytest.mark.parametrize("name,k", [("tower", 0), pytest.param("blade", 1, marks=pytest.mark.slow),
                                    ("hold-inside", 5), pytest.param("tower", 6, marks=pytest.mark.slow),
                                    ("blade", 7), pytest.param("hold-inside", 11, marks=pytest.mark.slow)])
@pytest.mark.slow
def test_adversaries_that_collide_unfiltered_keep_d_min_filtered(name, k):
    """Seeded recoverable starts of the adversarial study (winds: none, gusts, Dryden):
    unfiltered these flights hit the turbine or pass well inside d_min; filtered they stay
    above d_min - 0.1 m and never collide."""
    w = k % len(adv.WINDS)
    env = gym.make("WindTurbineInspection-v0", wind=adv.WINDS[w], time_limit_s=adv.SECONDS + 5.0)
    try:
        scene = adv.Scene(env)
        start = adv.draw_start(scene, np.random.default_rng([0, k]))
        raw = adv.fly(scene, adv.ADVERSARIES[name](scene), start, seed=k)
        safe = adv.fly(scene, SafetyFilter(adv.ADVERSARIES[name](scene), env), start, seed=k)
    finally:
        env.close()
    assert raw["collided"] or raw["min_clearance_m"] < 2.0, raw
    assert not safe["collided"] and safe["steps_below"] == 0, safe
    assert safe["min_clearance_m"] >= 3.0 - adv.TOLERANCE
    assert safe["interventions"] > 0


def test_the_filter_suffix_resolves_everywhere_a_name_does():
    assert registry.fingerprint("vtnmpc+filter") == "vtnmpc+filter" != registry.fingerprint("vtnmpc")
    assert registry.display_name("vtnmpc+filter") == "VT-NMPC + filter"
    registry.check_controller("ppo:ppo_full_vec128+filter")
    with pytest.raises(ValueError, match="unknown controller 'nope'"):
        registry.check_controller("nope+filter")
    env = gym.make("WindTurbineInspection-v0")
    try:
        pol = registry.resolve("nmpc+filter")(env.unwrapped)
        assert isinstance(pol, SafetyFilter) and type(pol.policy).__name__ == "NMPCPolicy"
    finally:
        env.close()


def test_the_harness_reports_the_filters_counts(tmp_path):
    from wt_inspect.evaluation import run_evaluation
    ev = run_evaluation("surface", ["vtnmpc+filter"], [4.0], out=tmp_path, jobs=1, max_time=3.0, figures=False,
                        progress=False)
    row = ev.results[0].row()
    assert row["filter_intervention_fraction"] == 0.0 and row["filter_median_ms"] > 0.0
    text = (tmp_path / "results.md").read_text()
    assert "## Safety filter" in text and "| VT-NMPC + filter | 4 | 0 | 0.0 % |" in text


def test_a_policy_without_act_or_predict_is_refused():
    env = gym.make("WindTurbineInspection-v0")
    try:
        with pytest.raises(ValueError, match="act\\(obs\\) or predict"):
            SafetyFilter(object(), env)
    finally:
        env.close()


@pytest.mark.slow
def test_a_passed_step_is_the_qps_own_answer():
    """Pass-through skips the QP only where the QP would return the policy's command: beside the
    filter that passes, a filter with pass-through off is fed the same observations; on every
    passed step its QP answer is the policy's command (to the QP's tolerance), the flight - VT-NMPC+
    on the paper mission in the 7 m/s gust, 3 s (6 s passed every step too, the largest QP-to-command
    difference, 1.1e-5, already in the first 3) - passes most steps, and a policy driven at the
    tower is not passed through while the filter corrects it."""
    env = gym.make("WindTurbineInspection-v0", wind={"type": "gust", "mean_speed": 7.0}, time_limit_s=3.0)
    try:
        u = env.unwrapped
        fast = SafetyFilter(registry.resolve("vtnmpc-plus")(u), env)
        slow = SafetyFilter(registry.resolve("vtnmpc-plus")(u), env, pass_through=False)
        obs, _ = env.reset(seed=1)
        fast.reset(1)
        slow.reset(1)
        passed = 0
        while True:
            a = fast.act(obs)
            b = slow.act(obs)
            if fast.mpc.last_stats.status == "PASSED_THROUGH":
                passed += 1
                np.testing.assert_array_equal(a, fast.last_policy_action.astype(np.float32))
                # the QP's interior-point answer, within what would not count as an intervention
                np.testing.assert_allclose(b, a, atol=INTERVENTION_TOL)
            obs, _, term, trunc, _ = env.step(a)
            if term or trunc:
                break
        assert slow.stats.passed == 0 and passed == fast.stats.passed > 0.5 * fast.stats.steps
    finally:
        env.close()
    env = gym.make("WindTurbineInspection-v0", time_limit_s=adv.SECONDS + 5.0)
    try:
        scene = adv.Scene(env)
        start = adv.draw_start(scene, np.random.default_rng([0, 0]))
        pol = SafetyFilter(adv.ADVERSARIES["tower"](scene), env)
        safe = adv.fly(scene, pol, start, seed=0)
        assert safe["interventions"] > 0 and pol.stats.passed < pol.stats.steps - pol.stats.interventions + 1
    finally:
        env.close()


@pytest.mark.parametrize("bad", [{"pass_through": 1}, {"pass_through_margin": -0.1},
                                 {"pass_through_margin": float("nan")}, {"pass_through_margin": "0.1"},
                                 {"model_drag": "yes"}, {"observer_model": "kalman"}])
def test_bad_filter_settings_name_the_field(bad):
    env = gym.make("WindTurbineInspection-v0")
    try:
        with pytest.raises(ValueError, match=next(iter(bad))):
            SafetyFilter(registry.resolve("nmpc")(env.unwrapped), env, **bad)
    finally:
        env.close()


def test_the_last_resort_brake_levels_a_tilted_drone_and_stops_it():
    """What the filter flies once a failed QP's backup plan is used up: from 10 m/s, tilted 40 deg
    into the motion and rolling, the filter's own model (its OCP dynamics, 10 ms stages) under
    :func:`brake_command` comes to rest (6 s) within the stopping distance the filter's constraint
    allows for, and holds its altitude to within a few metres (the RTI core's generic last resort,
    hover with zero rates, keeps the tilt and accelerates away)."""
    from controllers.safety_filter import FilterMPC, brake_command
    env = gym.make("WindTurbineInspection-v0")
    try:
        mpc = SafetyFilter(registry.resolve("nmpc")(env.unwrapped), env).mpc
    finally:
        env.close()
    assert isinstance(mpc, FilterMPC)
    f = mpc.base_ocp.dynamics
    p = np.zeros(mpc.base_ocp.np)
    half = np.radians(40.0) / 2                                   # pitched 40 deg towards +x
    x = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, np.sin(half), 0.0, np.cos(half)])
    from wt_inspect_env.physics.dynamics import quat_to_rotmat_np
    x[3:6] = quat_to_rotmat_np(x[6:10]).T @ np.array([10.0, 0.0, 0.0])   # 10 m/s along +x
    travel = 0.0
    for _ in range(600):
        u = brake_command(x, mpc.config)
        assert np.all(u >= mpc.config.scaling.lower) and np.all(u <= mpc.config.scaling.upper)
        x = np.asarray(f(x, u, p)).ravel()
        travel = max(travel, x[0])
    v = quat_to_rotmat_np(x[6:10]) @ x[3:6]
    assert np.linalg.norm(v) < 0.2 and abs(x[2] - 50.0) < 5.0
    # within the stopping distance the filter's constraint allows for: clearance_reaction at the
    # present acceleration (g tan 40 deg along the motion), then clearance_brake
    cfg = mpc.config
    a0, t_r = 9.81 * np.tan(np.radians(40.0)), cfg.clearance_reaction
    v_r = 10.0 + a0 * t_r
    assert travel < 10.0 * t_r + 0.5 * a0 * t_r ** 2 + v_r ** 2 / (2 * cfg.clearance_brake)


def _state_obs(x, point):
    """An observation of the drone state x = [p, v_B, q] at rest in its body rates, inspecting
    ``point`` on a surface facing +x."""
    return {"position": x[0:3], "velocity_body": x[3:6], "quaternion": x[6:10], "body_rates": np.zeros(3),
            "point": np.array(point, dtype=float), "normal": np.array([1.0, 0.0, 0.0]),
            "point_velocity": np.zeros(3), "coverage": np.array([0.0]), "progress": np.array([0.0])}


def _wall(x0, y0, x1, y1, normal):
    """Two triangles of a vertical wall from (x0, y0) to (x1, y1), z in [0, 100], facing ``normal``."""
    a, b = np.array([x0, y0, 0.0]), np.array([x1, y1, 0.0])
    up = np.array([0.0, 0.0, 100.0])
    tris = np.array([[a, b, b + up], [a, b + up, a + up]])
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    return tris if np.dot(n[0], normal) > 0 else tris[:, ::-1]


@pytest.mark.parametrize("speed,facing", [(0.0, (1.0, 0.0, 0.0)), (8.0, (0.0, -1.0, 0.0))])
def test_a_stage_keeps_clear_of_the_surface_it_flies_at(speed, facing):
    """An inside corner: wall A (x = 0, facing +x) 4 m to the side, wall B (y = 6, facing -y) 6 m
    ahead. The first half-space is always the nearest wall, A; the second is the wall at the
    look-ahead point: A again at rest, B when flying at it at 8 m/s (its stopping distance far
    beyond 6 m), which it would not see from its position (A is nearer) - so a stage flying at
    one wall of a corner keeps both (with one slot for the tighter of the two, a hub adversary
    braking for the surface ahead drifted into the one beside it, to 2.69 m). All are the exact
    supporting planes: offset n.c + d_min + back-off."""
    from controllers.safety_filter import FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = np.concatenate([_wall(0, -50, 0, 6, (1, 0, 0)), _wall(0, 6, 50, 6, (0, -1, 0))])
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]))
    x0 = np.array([4.0, 0.0, 50.0, 0.0, speed, 0.0, 0.0, 0.0, 0.0, 1.0])    # level, flying +y
    mpc.solver.initialize(x0)
    P = mpc._with_clearance(np.zeros((mpc.config.horizon + 1, mpc.base_ocp.np)), x0)
    npar, cfg = mpc.base_ocp.np, mpc.config
    keep = cfg.d_min + cfg.clearance_backoff
    np.testing.assert_allclose(P[0, npar:npar + 3], (1.0, 0.0, 0.0), atol=1e-9)
    assert P[0, npar + 3] == pytest.approx(keep)
    np.testing.assert_allclose(P[0, npar + 4:npar + 7], facing, atol=1e-9)
    plane = 0.0 if facing[0] else -6.0                                     # n.c of the wall
    assert P[0, npar + 7] == pytest.approx(plane + keep)


@pytest.mark.parametrize("speed", [0.0, 3.0, 10.0])
def test_a_stage_flying_along_a_wall_must_stop_within_the_free_ray_ahead(speed):
    """Wall A (x = 0) 3.6 m to the side, wall B (y = 12) ahead. Flying along A, A stays the nearest
    surface at the position and at the look-ahead point (0.9 x 3.6 m ahead), so the first two
    half-spaces are A's whatever the speed; the third bounds the stop along the ray ahead by the
    free length L = step + d1 the two balls prove (step: the stopping distance, at most 0.9 x 3.6 m;
    inactive at rest). At 3 m/s the
    drone stops within it (the policy's hover passes); at 10 m/s it cannot, and the filter brakes."""
    from controllers.safety_filter import INACTIVE, FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = np.concatenate([_wall(0, -50, 0, 12, (1, 0, 0)), _wall(0, 12, 50, 12, (0, -1, 0))])
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]))
    cfg = mpc.config
    keep = cfg.d_min + cfg.clearance_backoff
    x0 = np.array([3.6, 0.0, 50.0, 0.0, speed, 0.0, 0.0, 0.0, 0.0, 1.0])    # level, flying +y
    # the plan: flying on at the speed (hover thrust, no slack)
    plan = np.tile(x0, (cfg.horizon + 1, 1))
    plan[:, 1] = speed * cfg.dt * np.arange(cfg.horizon + 1)
    mpc.solver.initialize(x0, inputs=np.tile(mpc.ocp.fallback_input, (cfg.horizon, 1)), states=plan)
    P = mpc._with_clearance(np.zeros((cfg.horizon + 1, mpc.base_ocp.np)), x0)
    npar = mpc.base_ocp.np
    for j in (0, 1):
        np.testing.assert_allclose(P[0, npar + 4 * j:npar + 4 * j + 3], (1.0, 0.0, 0.0), atol=1e-9)
        assert P[0, npar + 4 * j + 3] == pytest.approx(keep)
    if speed == 0.0:
        np.testing.assert_allclose(P[0, npar + 8:npar + 11], (0.0, 0.0, 1.0))
        assert P[0, npar + 11] == -INACTIVE
        return
    np.testing.assert_allclose(P[0, npar + 8:npar + 11], (0.0, -1.0, 0.0), atol=1e-9)
    reach = speed * cfg.clearance_reaction + speed ** 2 / (2.0 * cfg.clearance_brake)
    assert P[0, npar + 11] == pytest.approx(-(min(reach, 0.9 * 3.6) + 3.6) + keep, abs=1e-6)
    obs = _state_obs(x0, point=(0.0, 0.0, 50.0))
    hover = mpc.config.hover_input
    u = mpc.filter_command(hover, obs)
    if speed == 3.0:
        assert mpc.last_stats.status == "PASSED_THROUGH"
        np.testing.assert_allclose(u, hover, atol=1e-9)
    else:
        assert mpc.last_stats.status != "PASSED_THROUGH"
        # braking along -y: tilt back (body x rate about -x for a level drone flying +y)
        assert abs(u[0]) > 0.1 or u[3] > hover[3] + 0.1


@pytest.mark.parametrize("model_drag", [False, True])
@pytest.mark.parametrize("push", [0.0, 2.0, 5.0])
def test_a_disturbance_towards_the_structure_lengthens_the_stopping_distance(push, model_drag):
    """The filter's clearance constraint with the observer's disturbance a_ext: approaching a wall
    at 4 m/s, a push of ``push`` m/s^2 towards it leaves clearance_brake - push to brake with (at
    least BRAKE_FLOOR of it), so h falls by exactly the longer stop; a push away from the wall
    changes nothing. With the model's drag the stop is v^2 / 2 (a + k v / 2), k the body's drag
    along the wall's normal at the braking tilt atan(a / g) (d_xy cos^2 + d_z sin^2)."""
    from controllers.rti_policy.clearance import BRAKE_FLOOR
    from controllers.safety_filter import A_EXT, FilterMPC
    from wt_inspect_env.physics.quadrotor import GRAVITY
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = _wall(0, -50, 0, 50, (1, 0, 0))
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]), clearance_reaction=0.0, model_drag=model_drag)
    cfg = mpc.config
    x = np.array([5.0, 0.0, 50.0, -4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])      # level, 4 m/s at the wall
    u = np.append(cfg.hover_input, 0.0)
    p = np.zeros(mpc.ocp.np)
    p[mpc.base_ocp.np:mpc.base_ocp.np + 4] = (1.0, 0.0, 0.0, 3.1)          # the wall's half-space
    p[mpc.base_ocp.np + 4:mpc.base_ocp.np + 8] = (0.0, 0.0, 1.0, -1e3)     # inactive second and third ones
    p[mpc.base_ocp.np + 8:mpc.base_ocp.np + 12] = (0.0, 0.0, 1.0, -1e3)

    def h(a_ext):
        p[A_EXT] = a_ext
        return float(np.asarray(mpc.ocp.path_constraint(x, u, p)).ravel()[0])

    a = cfg.clearance_brake
    k = 0.0
    if model_drag:
        drag, mass = cfg.params.drag_coefficients[0], cfg.params.mass
        d_xy, d_z = drag[0] / mass, drag[2] / mass
        tilt = np.arctan2(a, GRAVITY)
        k = d_xy * np.cos(tilt) ** 2 + d_z * np.sin(tilt) ** 2

    def stop(brake):
        return 16.0 / (2 * (brake + 0.5 * k * 4.0))

    calm = h((0.0, 0.0, 0.0))
    assert calm == pytest.approx(5.0 - 3.1 - stop(a), abs=1e-9)
    left = max(a - push, BRAKE_FLOOR * a)
    assert h((-push, 0.0, 0.0)) == pytest.approx(calm - stop(left) + stop(a), abs=1e-9)
    assert h((push, 0.0, 0.0)) == pytest.approx(calm, abs=1e-9)


@pytest.mark.parametrize("brake", [0.75, 3.0, 6.0])
@pytest.mark.parametrize("k", [0.0, 0.14, 0.8, 2.0])
def test_the_stopping_distance_with_drag_bounds_the_integrated_stop(brake, k):
    """stopping_distance against the stop integrated from first principles (dv/dt = -(a + k v),
    dx/dt = v, small steps): never shorter, and at most what braking without drag needs."""
    from controllers.rti_policy.clearance import stopping_distance
    for v0 in (0.5, 2.0, 5.0, 12.0):
        v, x, dt = v0, 0.0, 1e-5
        while v > 0.0:
            dv = (brake + k * v) * dt
            x += (v - 0.5 * dv) * dt if dv < v else v * v / (2.0 * (brake + k * v))
            v -= dv
        bound = stopping_distance(v0, brake, k)
        assert bound >= x - 1e-4
        assert bound <= v0 ** 2 / (2.0 * brake) + 1e-12
        if k == 0.0:
            assert bound == pytest.approx(x, rel=1e-3)


def _model_plant(cfg):
    """The filter's model as the plant (RK4 at 10 ms) with the airframe's linear drag D / m,
    whatever the filter's own ``model_drag``, and its first-order rotor lag on the collective
    thrust (from hover, as the simulator starts; 100 sub-steps a step); ``plant(x, u, a_ext)``."""
    import casadi as ca

    from wt_inspect_env.physics.dynamics import QuadrotorModel
    model = QuadrotorModel(cfg.params)
    xs, us, ae = ca.SX.sym("x", 10), ca.SX.sym("u", 4), ca.SX.sym("a", 3)
    d = np.asarray(cfg.params.drag_coefficients[0]) / cfg.params.mass
    step = ca.Function("plant", [xs, us, ae], [model.rk4_expr(xs, us, 0.01, a_ext=ae, steps=1, drag=d)])
    t_m, sub = cfg.params.motor_time_constant, 100
    rotor = [float(cfg.hover_input[3])]

    def plant(x, u, a_ext):
        thrusts = []
        for _ in range(sub):
            rotor[0] += (u[3] - rotor[0]) * (0.01 / sub) / t_m
            thrusts.append(rotor[0])
        applied = np.array(u, dtype=float)
        applied[3] = np.mean(thrusts)
        return step(x, applied, a_ext)
    return plant


@pytest.mark.parametrize("observer_model", ["attitude", "prediction"])
def test_the_filter_estimates_a_steady_push(observer_model):
    """The observer inside the filter: a plant with the airframe's drag and a steady 2 m/s^2 push
    along +x (the drone drifts off at the drag's terminal speed), the policy hovering far from any
    structure; after 3 s the estimate is the push within 5 %, whichever observer model."""
    from controllers.safety_filter import FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = _wall(-100, -50, -100, 50, (1, 0, 0))
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]), control_dt=0.01, observer_model=observer_model)
    cfg = mpc.config
    plant = _model_plant(cfg)
    x = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    push = np.array([2.0, 0.0, 0.0])
    for _ in range(300):
        obs = _state_obs(x, point=(-93.0, 0.0, 50.0))
        u = mpc.filter_command(cfg.hover_input, obs)
        x = np.asarray(plant(x, u, push)).ravel()
    assert np.linalg.norm(x[3:6]) > 1.0                   # it drifted: the drag was in play
    np.testing.assert_allclose(mpc.disturbance_estimate, push, atol=0.1)


@pytest.mark.parametrize("model_drag", [True, False])
def test_the_filter_does_not_take_the_drag_of_its_own_speed_for_wind(model_drag):
    """Still air, a plant with the airframe's linear drag, a policy that pitches the drone forward
    by 0.3 rad, holds, and levels again (it flies on at a few m/s, slowed by drag). With the drag in the
    filter's model (the default) the observer explains the deceleration and its estimate stays
    below 0.3 m/s^2; without it the drag of the drone's own speed looks like a push of more than
    1 m/s^2 against the flight - the push the filter once believed in, braking for wind that was
    not there."""
    from controllers.safety_filter import FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = _wall(-100, -50, -100, 50, (1, 0, 0))
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]), control_dt=0.01, model_drag=model_drag)
    cfg = mpc.config
    plant = _model_plant(cfg)
    x = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    peak = 0.0
    for k in range(250):
        cmd = np.array(cfg.hover_input, dtype=float)
        cmd[1] = 0.5 if k < 60 else (-0.5 if 120 <= k < 180 else 0.0)   # pitch forward, hold, level again
        cmd[3] *= 1.05
        u = mpc.filter_command(cmd, _state_obs(x, point=(-93.0, 0.0, 50.0)))
        x = np.asarray(plant(x, u, np.zeros(3))).ravel()
        peak = max(peak, float(np.linalg.norm(mpc.disturbance_estimate)))
    assert np.linalg.norm(x[3:6]) > 1.0                   # it flew
    if model_drag:
        assert peak < 0.3
    else:
        assert peak > 1.0


def test_the_attitude_observer_sees_a_push_present_at_the_start():
    """A 7 m/s^2 push (a 12 m/s wind on this airframe) present from the first step: the attitude
    observer takes its first residual as its estimate, so after two measurements it holds the push
    within 5 % - where a filter of time constant 0.3 s from zero would hold under 10 % of it - and
    a reset starts it over."""
    from controllers.safety_filter import FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = _wall(-100, -50, -100, 50, (1, 0, 0))
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]), control_dt=0.01)
    cfg = mpc.config
    assert cfg.observer_model == "attitude" and cfg.observer_time_constant == pytest.approx(0.3)
    plant = _model_plant(cfg)
    push = np.array([0.0, 7.0, 0.0])
    for _episode in range(2):
        mpc.reset()
        assert np.all(mpc.disturbance_estimate == 0.0)
        x = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        for _ in range(2):
            u = mpc.filter_command(cfg.hover_input, _state_obs(x, point=(-93.0, 0.0, 50.0)))
            x = np.asarray(plant(x, u, push)).ravel()
        mpc.filter_command(cfg.hover_input, _state_obs(x, point=(-93.0, 0.0, 50.0)))
        np.testing.assert_allclose(mpc.disturbance_estimate, push, atol=0.05 * 7.0)


def test_the_observer_does_not_take_the_rotor_lag_for_a_gust():
    """Still air, a plant whose rotors follow the thrust command with the airframe's lag: a
    policy that alternates +-30 % of the hover thrust every 50 ms (a filter's corrections swing
    the command like this). The observer, which passes the commands through the same lag, keeps
    its estimate below 0.05 m/s^2 (~0.004 here); an observer taking the command for the thrust,
    filtered alike, reads over 0.15 m/s^2 (~0.25) on the same flight."""
    from controllers.safety_filter import FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = _wall(-100, -50, -100, 50, (1, 0, 0))
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]), control_dt=0.01)
    cfg = mpc.config
    plant = _model_plant(cfg)
    x = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    hover = float(cfg.hover_input[3])
    peak, naive, naive_peak = 0.0, 0.0, 0.0
    tau, dt, m = cfg.observer_time_constant, 0.01, cfg.params.mass
    for k in range(100):
        cmd = np.array(cfg.hover_input, dtype=float)
        cmd[3] = hover * (1.3 if (k // 5) % 2 == 0 else 0.7)
        u = mpc.filter_command(cmd, _state_obs(x, point=(-93.0, 0.0, 50.0)))
        x_next = np.asarray(plant(x, u, np.zeros(3))).ravel()
        # the vertical estimate a command-as-thrust observer builds (level flight: body z up)
        residual = (x_next[5] - x[5]) / dt - (u[3] / m - 9.81)
        naive += (residual - naive) * dt / (tau + dt)
        naive_peak = max(naive_peak, abs(naive))
        x = x_next
        peak = max(peak, float(np.linalg.norm(mpc.disturbance_estimate)))
    assert peak < 0.05
    assert naive_peak > 0.15
