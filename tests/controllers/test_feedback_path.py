"""The short cuts on the MPCs' per-step path give what the full checks give.

check_observation's fast path (a dict of float arrays of the right shapes), RTISolver.prepare's
for the policies' own float64 parameters, the solver's state view and the policy's action map
change no number: the results equal the general code's bit for bit, and everything the general
checks refuse is still refused with the same message.
"""
from __future__ import annotations

import numpy as np
import pytest

from controllers.vtnmpc import VTNMPCPolicy
from wt_inspect_env import policy as policy_module
from wt_inspect_env.policy import check_observation
from wt_inspect_env.task.spaces import OBS_KEYS, OBS_SHAPES


def _obs(dtype=np.float32, seed=0):
    rng = np.random.default_rng(seed)
    obs = {k: rng.standard_normal(OBS_SHAPES[k]).astype(dtype) for k in OBS_KEYS}
    obs["quaternion"] = np.array([0.0, 0.0, 0.3, 0.95], dtype=dtype)
    obs["position"] = np.array([0.5, -6.5, 30.0], dtype=dtype)
    obs["point"] = np.array([0.0, 0.0, 30.0], dtype=dtype)
    obs["normal"] = np.array([0.0, -1.0, 0.0], dtype=dtype)
    return obs


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fast_observation_equals_the_full_check(dtype, monkeypatch):
    obs = _obs(dtype)
    fast = check_observation(obs)
    monkeypatch.setattr(policy_module, "_fast_observation", lambda o: None)
    full = check_observation(obs)
    assert fast.keys() == full.keys()
    for k in full:
        assert fast[k].dtype == np.float64 and fast[k].shape == full[k].shape
        assert np.array_equal(fast[k], full[k])


@pytest.mark.parametrize("change, message", [
    (lambda o: o.pop("point"), "missing key 'point'"),
    (lambda o: o.__setitem__("normal", np.array([np.nan, 0, 0], np.float32)),
     r"observation\[.normal.\] must be finite"),
    (lambda o: o.__setitem__("position", np.zeros(4, np.float32)), r"must have shape \(3,\)"),
    (lambda o: o.__setitem__("coverage", np.array(["x"])), "must be numeric"),
])
def test_what_the_full_check_refuses_is_still_refused(change, message):
    obs = _obs()
    change(obs)
    with pytest.raises(ValueError, match=message):
        check_observation(obs)


def test_a_batch_of_one_and_lists_still_go_through_the_full_check():
    obs = _obs(np.float64)
    batched = {k: v[None, :] for k, v in obs.items()}
    listed = {k: v.tolist() for k, v in obs.items()}
    for other in (batched, listed):
        got = check_observation(other)
        assert all(np.array_equal(got[k], obs[k]) for k in OBS_KEYS)


def test_state_view_follows_the_iterate_and_is_read_only():
    pol = VTNMPCPolicy(clearance=False)
    obs = _obs()
    pol.act(obs)
    view = pol.solver.state_view
    assert np.array_equal(view, pol.solver.states)
    pol.act(obs)
    assert np.array_equal(view, pol.solver.states)
    with pytest.raises(ValueError):
        view[0, 0] = 1.0


def test_action_map_equals_the_scaling_and_prepare_still_checks_params():
    pol = VTNMPCPolicy(clearance=False)
    a = pol.act(_obs())
    assert a.dtype == np.float32 and np.array_equal(a, pol.scaling.to_action(pol.last_command))
    bad = np.full(pol.ocp.np, np.nan)
    with pytest.raises(ValueError, match="params must be finite"):
        pol.solver.prepare(bad)
