"""``start_offset``: a deterministic 3-vector added to the start pose (single and vector env)."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.task.env_config import EnvConfig, check_start_offset

SURFACE = "WindTurbineInspection-Surface-v0"


@pytest.mark.parametrize("approach", ["auto", None])
def test_offset_moves_the_start_and_the_drone_still_faces_the_point(approach):
    base = gym.make(SURFACE).unwrapped
    moved = gym.make(SURFACE, start_offset=[3.0, -2.0, 30.0], reference_approach_speed=approach).unwrapped
    try:
        o0, i0 = base.reset(seed=0)
        o1, i1 = moved.reset(seed=0)
        np.testing.assert_allclose(o1["position"] - o0["position"], [3.0, -2.0, 30.0], atol=1e-5)
        if approach is None:   # the first stand-off pose is the target from the start
            np.testing.assert_array_equal(i1["ideal_position"], i0["ideal_position"])
            assert not i1["approaching"]
        else:                  # the approach starts where the drone does, the point carried with it
            np.testing.assert_allclose(i1["ideal_position"], o1["position"], atol=1e-5)
            np.testing.assert_allclose(o1["point"] - i1["ideal_position"], o0["point"] - i0["ideal_position"],
                                       atol=1e-9)
            assert i1["approaching"] and not i0["approaching"]
        # yaw faces the inspection point from the offset start (horizontally)
        q = moved.sim.state[0, 6:10]
        yaw = 2.0 * np.arctan2(q[2], q[3])
        a = o1["point"] - moved.sim.state[0, 0:3]
        assert abs(np.angle(np.exp(1j * (yaw - np.arctan2(a[1], a[0]))))) < 1e-5
        # deterministic: the same start on every reset and every seed
        o2, _ = moved.reset(seed=5)
        np.testing.assert_array_equal(o2["position"], o1["position"])
    finally:
        base.close()
        moved.close()


def test_zero_offset_is_the_default_bit_for_bit():
    a = gym.make(SURFACE, start_noise=0.3).unwrapped
    b = gym.make(SURFACE, start_noise=0.3, start_offset=(0.0, 0.0, 0.0)).unwrapped
    try:
        oa, _ = a.reset(seed=2)
        ob, _ = b.reset(seed=2)
        for k in oa:
            assert np.array_equal(oa[k], ob[k]), k
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("bad", [(1.0, 2.0), [0.0, 0.0, float("nan")], (0.0, float("inf"), 0.0), "up", None,
                                 [[0.0, 0.0, 1.0]], 5.0])
def test_bad_offsets_are_one_line_errors_naming_the_field(bad):
    with pytest.raises(ValueError, match="start_offset") as exc:
        EnvConfig(start_offset=bad)
    assert "\n" not in str(exc.value)
    with pytest.raises(ValueError, match="reset start_offset"):
        check_start_offset(bad, "reset start_offset")


def test_vector_env_applies_the_same_offset_as_the_single_env():
    off = (0.0, 4.0, 12.0)
    venv = gym.make_vec(SURFACE, num_envs=2, vectorization_mode="vector_entry_point", start_offset=off,
                        start_noise=0.2)
    singles = [gym.make(SURFACE, start_offset=off, start_noise=0.2).unwrapped for _ in range(2)]
    try:
        vobs, _ = venv.reset(seed=7)
        for i, env in enumerate(singles):
            obs, _ = env.reset(seed=7 + i)
            for k in obs:
                assert np.array_equal(vobs[k][i], obs[k]), (k, i)
        with pytest.raises(ValueError, match="start_offset"):
            gym.make_vec(SURFACE, num_envs=2, vectorization_mode="vector_entry_point",
                         start_offset=[(0.0, 0.0, 1.0), (0.0, 0.0, 2.0)])
    finally:
        venv.close()
        for env in singles:
            env.close()
