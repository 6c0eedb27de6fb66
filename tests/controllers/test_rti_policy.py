"""The one RTI policy base: a new MPC is its OCP, weights and parameters; the base does the rest
(solver choice, reset, weights, normal fallback, quaternion sign, preparation/feedback)."""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import pytest
from closed_loop import ModelPlant, SurfacePass, make_observation, offset_start, run_closed_loop

from controllers.nmpc import NMPCPolicy
from controllers.pampc import PAMPCPolicy
from controllers.rti import OCP, RTIOptions
from controllers.rti_policy import LSQWeights, MPCConfig, RTIPolicy
from controllers.vtnmpc import VTNMPC_PLUS, VTNMPCPolicy
from wt_inspect_env.physics.dynamics import NU, NX, QuadrotorModel
from wt_inspect_env.physics.quadrotor import get_preset
from wt_inspect_env.task.geometry import heading_and_distance, standoff_position

UNCOMPILED = RTIOptions(qp_mode="speed_abs", compiled=False)


# -- a whole new MPC in a few lines: hold the stand-off position, level, at hover ---------------
@dataclass(frozen=True)
class HoldWeights(LSQWeights):
    position: float = 40.0
    velocity: float = 3.0
    tilt: float = 60.0
    inputs: tuple[float, ...] = (1.0, 1.0, 1.0, 0.05)
    TERMINAL = (("position", 3), ("velocity", 3), ("tilt", 2))
    STAGE = TERMINAL + (("inputs", 4),)


@dataclass(frozen=True)
class HoldConfig(MPCConfig):
    WEIGHTS = HoldWeights
    WEIGHT_SETS = {"default": HoldWeights()}
    weights: HoldWeights | str = "default"


class HoldPolicy(RTIPolicy):
    config_class = HoldConfig

    def build_ocp(self, config: HoldConfig) -> OCP:
        x, u, p = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("p", 3)
        state_res = ca.vertcat(x[0:3] - p, x[3:6], x[6:8])
        F = ca.Function("hold_F", [x, u, p], [QuadrotorModel(config.params).rk4_expr(x, u, config.dt)])
        r = ca.Function("hold_r", [x, u, p], [ca.vertcat(state_res, u - ca.DM(config.hover_input))])
        rN = ca.Function("hold_rN", [x, p], [state_res])
        return OCP("hold", F, r, rN, config.horizon, config.dt, config.scaling.lower, config.scaling.upper,
                   config.hover_input)

    def parameters(self, obs, state, normal_xy):
        return standoff_position(obs["point"], normal_xy, self.config.d_ref)


def test_a_new_mpc_is_its_ocp_and_parameters():
    params = get_preset("matrice100")
    policy = HoldPolicy(params=params, solver=UNCOMPILED)
    sc = SurfacePass(speed=0.0)
    res = run_closed_loop(policy, ModelPlant(params), sc, 400, offset_start(sc, 7.0), policy.scaling)
    target = standoff_position(sc.point(0), sc.normal[:2], 7.0)
    assert np.linalg.norm(res.states[0, :3] - target) > 1.0
    assert np.linalg.norm(res.states[-1, :3] - target) < 0.1      # flown to the pose and held
    assert res.fallbacks == 0
    # the base's machinery comes with it: weights by name or object, overrides, reset
    policy.set_weights(HoldWeights(position=10.0))
    assert policy.solver.stage_weights[0] == 10.0
    with pytest.raises(ValueError, match="weights"):
        policy.set_weights("nonsense")
    with pytest.raises(ValueError, match="unknown HoldConfig option"):
        HoldPolicy(horizn=3)
    with pytest.raises(ValueError, match=r"weights\.inputs\[3\]"):
        HoldWeights(inputs=(1.0, 1.0, 1.0, 0.0))


@pytest.mark.parametrize("cls", [VTNMPCPolicy, NMPCPolicy, PAMPCPolicy])
def test_every_controller_has_weights_of_one_shape(cls):
    policy = cls(solver=UNCOMPILED)
    w = policy.config.weights
    assert isinstance(w, LSQWeights)
    assert w.stage_vector().shape == (policy.ocp.ny,) and w.terminal_vector().shape == (policy.ocp.ny_terminal,)
    np.testing.assert_array_equal(policy.solver.stage_weights, w.stage_vector())


def test_quaternion_sign_is_aligned_for_every_controller():
    """-q is the same attitude: a simulator returning it mid-flight must not change the command
    (the VT-NMPC did not align before the base did)."""
    sc = SurfacePass()
    x = offset_start(sc, 7.0)
    for cls in (VTNMPCPolicy, NMPCPolicy):
        a, b = cls(solver=UNCOMPILED), cls(solver=UNCOMPILED)
        obs = make_observation(x, sc.point(0), np.asarray(sc.normal), sc.velocity())
        a.act(obs), b.act(obs)
        flipped = dict(obs, quaternion=-obs["quaternion"])
        np.testing.assert_allclose(a.act(obs), b.act(flipped), atol=1e-9)


@pytest.mark.parametrize("cls, min_heading", [(NMPCPolicy, 0.999), (PAMPCPolicy, 0.99)])
def test_tracking_baselines_follow_a_moving_point(cls, min_heading, params):
    """0.7 m/s along the surface (the paper's speed) on the model with drag: the clock state moves
    the reference over the horizon, so only the unmodelled drag leaves a small lag."""
    scenario = SurfacePass(speed=0.7)
    policy = cls(params=params)
    res = run_closed_loop(policy, ModelPlant(params), scenario, 500, scenario.ideal_state(0.0, 7.0), policy.scaling)
    assert res.fallbacks == 0
    assert np.all(np.abs(res.distance - 7.0) < 0.05)
    assert np.all(res.heading > min_heading)
    lag = scenario.point(5.0)[0] - res.states[-1][0]
    assert 0.0 < lag < 0.3


def test_set_weights_rebuilds_ipopt():
    policy = NMPCPolicy(backend="ipopt")
    sc = SurfacePass()
    obs = make_observation(offset_start(sc, 7.0), sc.point(0), np.asarray(sc.normal), sc.velocity())
    u0 = policy.act(obs)
    policy.reset()
    policy.set_weights(type(policy.config.weights)(position=(1.0, 1.0, 1.0)))
    assert not np.allclose(policy.act(obs), u0)


@pytest.mark.slow
@pytest.mark.parametrize("options", [{}, VTNMPC_PLUS])
def test_prepare_ahead_runs_only_the_feedback_after_the_command(options):
    """With prepare_ahead each act runs the feedback QP first and prepares the next step after
    the command exists (at the predicted state); the closed loop is as good as without."""
    params = get_preset("matrice100")
    sc = SurfacePass()
    x0 = offset_start(sc, 7.0)
    runs, orders = {}, {}
    for ahead in (False, True):
        policy = VTNMPCPolicy(params=params, prepare_ahead=ahead, solver=UNCOMPILED, **options)
        calls: list[str] = []
        for name in ("prepare", "feedback"):
            original = getattr(policy.solver, name)
            setattr(policy.solver, name,
                    lambda *a, _f=original, _n=name, _calls=calls: (_calls.append(_n), _f(*a))[1])
        act = policy.act
        order: list[list[str]] = []

        def logged(obs, act=act, calls=calls, order=order):
            calls.clear()
            out = act(obs)
            order.append(list(calls))
            return out
        policy.act = logged
        runs[ahead] = run_closed_loop(policy, ModelPlant(params), sc, 800, x0, policy.scaling)
        orders[ahead] = order
    assert orders[False][5] == ["prepare", "feedback"]
    assert orders[True][0] == ["prepare", "feedback", "prepare"]        # first step: nothing prepared yet
    assert all(o == ["feedback", "prepare"] for o in orders[True][1:])  # then the QP is ready on arrival
    for r in runs.values():   # (VT-NMPC+ settles 0.15 m off on this drag-only pass, either way)
        assert r.fallbacks == 0 and abs(r.distance[-1] - 7.0) < 0.2 and r.heading[-1] > 0.99
    # one step of parameter lag (an observer update one step later), nothing more
    assert np.max(np.abs(runs[True].states[:, :3] - runs[False].states[:, :3])) < 0.01
    assert abs(runs[True].distance[-1] - runs[False].distance[-1]) < 0.01


def test_prepare_ahead_with_the_tangential_predictor_flies_the_same_loop(params):
    """prepare_ahead + tangential_predictor: the feedback is the predictor (the QP was solved in
    the preparation) and the closed loop is the full-QP loop's to QP tolerance."""
    sc = SurfacePass()
    x0 = offset_start(sc, 7.0)
    fast = dict(qp_mode="speed_abs", qp_solver="hpipm", qp_mu0=1.0)
    runs, predicted = {}, []
    for pred in (False, True):
        policy = VTNMPCPolicy(params=params, prepare_ahead=True,
                              solver=RTIOptions(tangential_predictor=pred, **fast))
        act = policy.act

        def logged(obs, act=act, policy=policy):
            out = act(obs)
            predicted.append(policy.last_stats.predicted)
            return out
        policy.act = logged
        runs[pred] = run_closed_loop(policy, ModelPlant(params), sc, 400, x0, policy.scaling)
    assert not any(predicted[:400]) and np.mean(predicted[401:]) > 0.9   # first step: nothing prepared
    assert runs[True].fallbacks == 0
    np.testing.assert_allclose(runs[True].states, runs[False].states, atol=1e-6)


def test_prepare_ahead_is_off_for_ipopt_and_validated():
    with pytest.raises(ValueError, match="prepare_ahead"):
        VTNMPCPolicy(prepare_ahead="yes")
    sc = SurfacePass()
    policy = VTNMPCPolicy(backend="ipopt", prepare_ahead=True)
    obs = make_observation(offset_start(sc, 7.0), sc.point(0), np.asarray(sc.normal), sc.velocity())
    policy.act(obs)
    h, d = heading_and_distance(obs["position"], obs["quaternion"], obs["point"])
    assert not policy.last_stats.fallback and d > 0
