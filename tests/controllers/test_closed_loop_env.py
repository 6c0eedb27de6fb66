"""The MPC policies flying the Gymnasium environment (closed loop through PyBullet, rate loop,
motor lag and drag): the issue-level acceptance checks of VT-NMPC and the baselines."""
import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401
from controllers.nmpc import NMPCPolicy
from controllers.pampc import PAMPCPolicy
from controllers.vtnmpc import VTNMPC_PLUS, VTNMPCPolicy


def fly(policy, **env_kw):
    env = gym.make("WindTurbineInspection-Surface-v0", **env_kw)
    u = env.unwrapped
    obs, info = env.reset(seed=0)
    policy.reset()
    d_err, heads = [], []
    while True:
        obs, r, term, trunc, info = env.step(policy.act(obs))
        a = obs["point"] - obs["position"]
        d = float(np.hypot(a[0], a[1]))
        R = wt_inspect_env.physics.dynamics.quat_to_rotmat_np(obs["quaternion"].astype(float))
        d_err.append(d - u.config.standoff)
        heads.append(float(R[:, 0] @ np.array([a[0], a[1], 0.0]) / d))
        if term or trunc:
            break
    env.close()
    return np.array(d_err), np.array(heads), info


def test_vtnmpc_settles_facing_the_surface_without_wind():
    # the point is held still for the first seconds? no: it moves at 0.7 m/s; the drone starts at the
    # ideal pose and must stay there while tracking the moving point
    d_err, h, info = fly(VTNMPCPolicy(), wind="none", time_limit_s=15.0)
    assert info["termination"] is None
    assert np.abs(d_err[-300:]).max() < 0.1
    assert h[-300:].min() > 0.99


@pytest.mark.slow
def test_vtnmpc_keeps_safety_over_a_surface_in_the_paper_gust():
    """The paper's 4 m/s gust (sinusoid 10 s, std 0.5 m/s, along y = along this surface's normal).

    With the disturbance observer (the wind-drag estimate fed to the model, see VTNMPCConfig) the
    VT-NMPC keeps SM = 100 % over the whole surface pass; the paper-faithful controller without it
    holds the distance within the margin too but with a steady offset, measured and documented in
    the README rather than asserted here."""
    d_err, h, info = fly(VTNMPCPolicy(disturbance_observer=True), wind={"type": "gust", "mean_speed": 4.0})
    m = info["metrics"]
    assert info["mission_complete"] and info["termination"] is None
    assert m["safety_sm"] == 1.0
    assert m["coverage"] > 0.95
    assert m["centering_cm"] > 0.99


@pytest.mark.slow
def test_vtnmpc_plus_meets_the_targets_in_the_7_mps_gust_where_the_paper_form_does_not():
    """7 m/s gust along this surface's normal: the paper-faithful VT-NMPC is blown ~1 m off
    d_ref (SM collapses), VT-NMPC+ (observer, gimbal-camera heading, chord heading residual) keeps
    SM 100 % and CM >= 99.9 % over the whole surface."""
    wind = {"type": "gust", "mean_speed": 7.0}
    *_, plain = fly(VTNMPCPolicy(), wind=wind, time_limit_s=30.0)
    *_, plus = fly(VTNMPCPolicy(**VTNMPC_PLUS), wind=wind)
    assert plain["metrics"]["safety_sm"] < 0.5
    m = plus["metrics"]
    assert plus["mission_complete"] and plus["termination"] is None
    assert m["safety_sm"] == 1.0 and m["coverage"] == 1.0 and m["centering_cm"] >= 0.999


@pytest.mark.parametrize("policy_cls", [NMPCPolicy, PAMPCPolicy])
def test_baselines_hold_their_standoff_without_wind(policy_cls):
    d_err, h, info = fly(policy_cls(), wind="none", time_limit_s=10.0)
    assert info["termination"] is None
    assert np.abs(d_err[-200:]).max() < 0.2
    assert h[-200:].min() > 0.98
