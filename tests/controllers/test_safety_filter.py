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


@pytest.mark.parametrize("name,k", [("tower", 0), ("blade", 1), ("hold-inside", 5), ("tower", 6), ("blade", 7),
                                    ("hold-inside", 11)])
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


def test_a_passed_step_is_the_qps_own_answer():
    """Pass-through skips the QP only where the QP would return the policy's command: beside the
    filter that passes, a filter with pass-through off is fed the same observations; on every
    passed step its QP answer is the policy's command (to the QP's tolerance), the flight - VT-NMPC+
    on the paper mission in the 7 m/s gust, 6 s - passes most steps, and a policy driven at the
    tower is not passed through while the filter corrects it."""
    env = gym.make("WindTurbineInspection-v0", wind={"type": "gust", "mean_speed": 7.0}, time_limit_s=6.0)
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
                                 {"pass_through_margin": float("nan")}, {"pass_through_margin": "0.1"}])
def test_bad_pass_through_settings_name_the_field(bad):
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
    ahead. At rest the filter keeps the nearest wall, A; flying at B at 8 m/s (its stopping distance
    far beyond 6 m) it keeps B, which it would not see from its position (A is nearer) - the
    look-ahead point towards its stopping point finds it. Both are the exact supporting planes:
    offset n.c + d_min + back-off."""
    from controllers.safety_filter import FilterMPC
    from wt_inspect_env.planner.proximity import TurbineProximity
    tris = np.concatenate([_wall(0, -50, 0, 6, (1, 0, 0)), _wall(0, 6, 50, 6, (0, -1, 0))])
    mpc = FilterMPC(d_ref=7.0, obstacles=TurbineProximity([tris]))
    x0 = np.array([4.0, 0.0, 50.0, 0.0, speed, 0.0, 0.0, 0.0, 0.0, 1.0])    # level, flying +y
    mpc.solver.initialize(x0)
    P = mpc._with_clearance(np.zeros((mpc.config.horizon + 1, mpc.base_ocp.np)), x0)
    npar, cfg = mpc.base_ocp.np, mpc.config
    np.testing.assert_allclose(P[0, npar:npar + 3], facing, atol=1e-9)
    plane = 0.0 if facing[0] else -6.0                                     # n.c of the wall
    assert P[0, npar + 3] == pytest.approx(plane + cfg.d_min + cfg.clearance_backoff)
