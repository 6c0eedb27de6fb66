"""The conventional NMPC baseline: closed-loop hold in the PyBullet simulator, sign safety of the
yaw and attitude terms, agreement with a converged solver, validation."""
from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from closed_loop import ModelPlant, SurfacePass, check_sqp_vs_ipopt, check_standoff_hold, make_observation, offset_start

from controllers.nmpc import NMPCConfig, NMPCPolicy, NMPCWeights, build_ocp, residual_functions
from controllers.tracking import TrackingReference, standoff_reference
from wt_inspect_env.physics.dynamics import quat_to_rotmat_np

D_REF = 7.0


@pytest.fixture(scope="module")
def policy():
    return NMPCPolicy()


def test_holds_standoff_pose_in_simulator(policy, params):
    scenario = SurfacePass(speed=0.0, normal=(0.6, -0.8, 0.0), direction=(0.8, 0.6, 0.0))
    x0 = offset_start(scenario, D_REF, offset=(0.3, -0.3, 0.2), yaw_error_deg=8.0)
    heads = check_standoff_hold(policy, params, scenario, x0, D_REF, steps=400)
    assert np.all(heads[100:] > 0.99) and heads[-1] > 0.999


def test_residual_is_zero_at_the_reference(params):
    cfg = NMPCConfig(params=params)
    stage, terminal = residual_functions(cfg)
    ref = TrackingReference(position=(1.0, -2.0, 30.0), velocity=(0.5, 0.2, -0.1), yaw=2.5)
    q = np.array([0.0, 0.0, math.sin(1.25), math.cos(1.25)])
    v_body = quat_to_rotmat_np(q).T @ np.array(ref.velocity)
    tau = 0.13
    x = np.concatenate([np.array(ref.position) + tau * np.array(ref.velocity), v_body, q, [tau]])
    r = np.asarray(stage(x, cfg.hover_input, ref.parameters())).ravel()
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(terminal(x, ref.parameters())).ravel(), 0.0, atol=1e-12)
    # a 10 deg yaw error shows up in the heading rows only, as 2 sin(5 deg) in norm
    x_yaw = x.copy()
    x_yaw[6:10] = [0.0, 0.0, math.sin(1.25 + math.radians(5)), math.cos(1.25 + math.radians(5))]
    x_yaw[3:6] = quat_to_rotmat_np(x_yaw[6:10]).T @ np.array(ref.velocity)
    r = np.asarray(stage(x_yaw, cfg.hover_input, ref.parameters())).ravel()
    np.testing.assert_allclose(r[:8], 0.0, atol=1e-12)
    assert np.linalg.norm(r[8:10]) == pytest.approx(2 * math.sin(math.radians(5)), rel=1e-12)


def test_residual_is_invariant_to_quaternion_sign_and_yaw_winding(params):
    cfg = NMPCConfig(params=params)
    stage, _ = residual_functions(cfg)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        x = np.concatenate([rng.normal(size=6), q, [rng.uniform(0, 0.3)]])
        u = rng.normal(size=4)
        yaw = rng.uniform(-math.pi, math.pi)
        base = TrackingReference((1.0, 2.0, 3.0), (0.1, 0.2, 0.0), yaw).parameters()
        r = np.asarray(stage(x, u, base)).ravel()
        x_flip = x.copy()
        x_flip[6:10] = -q
        r_flip = np.asarray(stage(x_flip, u, base)).ravel()
        # the tilt rows change sign (their square does not); everything else is identical
        np.testing.assert_array_equal(np.abs(r_flip), np.abs(r))
        np.testing.assert_array_equal(np.delete(r_flip, [6, 7]), np.delete(r, [6, 7]))
        for turns in (-2, 1, 3):
            wrapped = TrackingReference((1.0, 2.0, 3.0), (0.1, 0.2, 0.0),
                                        yaw + 2 * math.pi * turns).parameters()
            np.testing.assert_allclose(np.asarray(stage(x, u, wrapped)).ravel(), r, atol=1e-13)


class _WrappingNMPC(NMPCPolicy):
    """Hands the solver a yaw reference wound by a different multiple of 360 deg every step, as
    the authors' precomputed references did."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self._turns = itertools.cycle([0, 1, -1, 3, -2])

    def reference(self, obs, state, normal_xy):
        ref = super().reference(obs, state, normal_xy)
        return dataclasses.replace(ref, yaw=ref.yaw + 2 * math.pi * next(self._turns))


def _lockstep(policy_a, policy_b, params, flip_b_quaternion: bool, steps: int = 80):
    """Run policy_a in closed loop on the model and feed policy_b the same observations
    (optionally with -q every other step); return the largest action difference."""
    scenario = SurfacePass(speed=0.7)
    plant = ModelPlant(params)
    state = plant.reset(offset_start(scenario, D_REF))
    policy_a.reset()
    policy_b.reset()
    worst = 0.0
    for k in range(steps):
        t = k * plant.dt
        obs = make_observation(state, scenario.point(t), np.asarray(scenario.normal),
                               scenario.velocity(t))
        obs_b = dict(obs)
        if flip_b_quaternion and k % 2 == 1:
            obs_b["quaternion"] = -obs["quaternion"]
        a = policy_a.act(obs)
        b = policy_b.act(obs_b)
        worst = max(worst, float(np.max(np.abs(a - b))))
        state = plant.step(policy_a.scaling.to_command(a))
    return worst


def test_yaw_wrap_leaves_the_action_unchanged(policy, params):
    assert _lockstep(policy, _WrappingNMPC(), params, flip_b_quaternion=False) < 1e-8


def test_quaternion_sign_flip_leaves_the_action_unchanged(policy, params):
    assert _lockstep(policy, NMPCPolicy(), params, flip_b_quaternion=True) < 1e-12
    # a fresh controller (no warm start) is exactly mirrored as well
    scenario = SurfacePass()
    x = offset_start(scenario, D_REF)
    obs = make_observation(x, scenario.point(0), np.asarray(scenario.normal), scenario.velocity())
    flipped = dict(obs, quaternion=-obs["quaternion"])
    policy.reset()
    a = policy.act(obs)
    policy.reset()
    np.testing.assert_array_equal(policy.act(flipped), a)


def test_rti_sqp_matches_ipopt(params):
    """The OCP solved to convergence by the RTI core's SQP mode and by IPOPT agrees."""
    cfg = NMPCConfig(params=params, horizon=20)
    scenario = SurfacePass(speed=0.7)
    x0 = np.append(offset_start(scenario, D_REF, offset=(0.5, -0.8, 0.3), yaw_error_deg=20), 0.0)
    p = standoff_reference(scenario.point(0), np.array([0.0, -1.0]), scenario.velocity(),
                           D_REF).parameters()
    rti, ip = check_sqp_vs_ipopt(build_ocp(cfg), cfg, x0, p)
    np.testing.assert_allclose(rti.iterate, ip.iterate, atol=1e-4)


@pytest.mark.parametrize("kwargs, field", [
    ({"position": (1.0, 2.0)}, r"weights\.position"),
    ({"velocity": (1.0, -2.0, 3.0)}, r"weights\.velocity\[1\]"),
    ({"tilt": ("a", 1.0)}, r"weights\.tilt"),
    ({"heading": float("nan")}, r"weights\.heading"),
    ({"inputs": (1.0, 1.0, 1.0, 0.0)}, r"weights\.inputs\[3\]"),
    ({"terminal_factor": -1.0}, r"weights\.terminal_factor"),
])
def test_bad_weights_raise(kwargs, field):
    with pytest.raises(ValueError, match=field):
        NMPCWeights(**kwargs)


@pytest.mark.parametrize("kwargs, field", [
    ({"horizon": 0}, "horizon"),
    ({"horizon": 2.5}, "horizon"),
    ({"horizon": True}, "horizon"),
    ({"dt": -0.01}, "dt"),
    ({"control_dt": 0.015}, "control_dt"),
    ({"rk4_steps": 0}, "rk4_steps"),
    ({"d_ref": 0.0}, "d_ref"),
    ({"weights": "tuned"}, "weights"),
    ({"backend": "acados"}, "backend"),
])
def test_bad_config_raises(kwargs, field):
    with pytest.raises(ValueError, match=field):
        NMPCConfig(**kwargs)


def test_bad_overrides_and_observations_raise(policy):
    with pytest.raises(ValueError, match="horizn"):
        NMPCPolicy(horizn=10)
    with pytest.raises(ValueError, match="weights"):
        policy.set_weights("nope")
    obs = make_observation(np.zeros(10) + [0, 0, 0, 0, 0, 0, 0, 0, 0, 1], np.ones(3),
                           np.array([1.0, 0, 0]), np.zeros(3))
    obs["point"] = np.array([np.nan, 0, 0], dtype=np.float32)
    with pytest.raises(ValueError, match="point"):
        policy.act(obs)


def test_policy_interface_and_ipopt_backend(policy, params):
    scenario = SurfacePass()
    x = offset_start(scenario, D_REF)
    obs = make_observation(x, scenario.point(0), np.asarray(scenario.normal), scenario.velocity())
    batched = {k: v[None] for k, v in obs.items()}
    action, _ = policy.predict(batched, episode_start=np.array([True]))
    assert action.shape == (1, 4) and np.all(np.abs(action) <= 1.0)
    assert policy.predicted_states.shape == (policy.config.horizon + 1, 10)
    u_rti = policy.last_command
    ip = NMPCPolicy(params=params, backend="ipopt")
    ip.act(obs)
    assert not ip.last_stats.fallback
    # one RTI step from a hover guess is not converged, but it points the same way
    assert np.sign(ip.last_command[3] - policy.config.hover_input[3]) == \
        np.sign(u_rti[3] - policy.config.hover_input[3])
    assert ip.predicted_states.shape == (policy.config.horizon + 1, 10)
