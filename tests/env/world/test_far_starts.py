"""Far starts (``start_far``): a share of the episodes starts at the path's start moved by a random
offset of up to ``start_far_distance`` - the randomised campaign's starts - clear of the structure,
and the reference approaches from there; without the option the seeded starts are unchanged."""
from __future__ import annotations

import numpy as np
import pytest
from side_by_side import _run_side_by_side

from wt_inspect_env.planner.clearance import DistanceField
from wt_inspect_env.task.env_config import EnvConfig
from wt_inspect_env.vector import WindTurbineInspectionVectorEnv

N = 128
R = 30.0


def _starts(**options) -> dict[str, np.ndarray]:
    """Each drone's start position, its progress, whether its reference approaches, the start's
    distance to the first rotor position's mesh and to the path's first ideal pose."""
    env = WindTurbineInspectionVectorEnv(num_envs=N, task="full", wind="none", start_progress=0.9, **options)
    try:
        env.reset(seed=5)
        w = env.world
        start = w._reset_state[:, 0:3].copy()
        w.reference.reset(0, 0.0)
        first = w.reference.sample.ideal_position[0].copy()
        env.reset(seed=5)
        s = w.reference.sample
        return {"start": start, "progress": s.progress.copy(), "approaching": w.reference.approaching.copy(),
                "clearance": DistanceField(w.mission.turbines[0].mesh.triangles).closest(start)[1],
                "offset": np.linalg.norm(start - first, axis=1), "d_min": np.float64(w.config.d_min)}
    finally:
        env.close()


@pytest.mark.slow
def test_far_starts_lie_within_the_distance_clear_of_the_structure_and_approach():
    far = _starts(start_far=1.0, start_far_distance=R)
    assert np.all(far["offset"] <= R + 1e-9)
    assert np.all(far["clearance"] >= far["d_min"])
    assert np.all(far["start"][:, 2] >= far["d_min"])
    assert np.all(far["progress"] == 0.0)
    # a length uniform in [0, 30] m is beyond the reference's stop threshold for nearly all
    # drones; each such start approaches (median offset ~15 m, far from the threshold)
    assert np.median(far["offset"]) > 0.3 * R
    assert np.mean(far["approaching"]) > 0.9
    assert np.all(far["approaching"][far["offset"] > 2.0])


@pytest.mark.slow
def test_a_share_of_far_starts_and_without_the_option_the_stream_is_unchanged():
    half = _starts(start_far=0.5, start_far_distance=R)
    # binomial(128, 0.5): between 0.3 and 0.7 except with probability < 1e-5; a uniform start is at
    # progress 0 with probability 0
    assert 0.3 < np.mean(half["progress"] == 0.0) < 0.7
    again = _starts(start_far=0.5, start_far_distance=R)
    np.testing.assert_array_equal(half["start"], again["start"])      # seeded
    plain = _starts()
    zero = _starts(start_far=0.0, start_far_distance=R)
    np.testing.assert_array_equal(plain["start"], zero["start"])     # share 0 draws nothing more
    assert not plain["approaching"].any()


@pytest.mark.parametrize("options, match", [
    ({"start_far": 1.5}, "start_far must be a share"),
    ({"start_far": -0.1}, "start_far"),
    ({"start_far_distance": 0.0}, "start_far_distance"),
    ({"start_far": 0.5, "reference_approach_speed": None}, "start_far .* needs a reference_approach_speed"),
])
def test_bad_far_start_options_are_named(options, match):
    with pytest.raises(ValueError, match=match):
        EnvConfig.from_kwargs(**options)


@pytest.mark.slow
def test_vector_env_drone_i_with_far_starts_is_the_single_env_across_autoresets():
    """Far starts, their approach and the pose limit on it, per drone as in the single env."""
    seen = _run_side_by_side(2, 120, start_far=1.0, start_far_distance=R, start_noise=0.3, time_limit_s=0.4,
                             pose_error_limit=3.0)
    assert seen["resets"] >= 2
