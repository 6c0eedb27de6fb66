"""The approach router (``wt_inspect_env.planner.approach``) against a brute-force distance over
every triangle, and a far start behind a blade flown end to end (the campaign's stalled NREL 5-MW
missions)."""
from __future__ import annotations

import numpy as np
import pytest
from oracles import brute_distance

from wt_inspect_env.planner.approach import APPROACH_MARGIN, ApproachRouter
from wt_inspect_env.planner.clearance import sample_polyline


def _box(lo, hi) -> np.ndarray:
    import trimesh
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2.0)
    return np.asarray(m.triangles)


# a "blade": a long thin slab standing between the start and the goal
SLAB = _box((-20.0, -0.5, 10.0), (20.0, 0.5, 60.0))
AXIS = np.array([0.0, 1.0, 0.0])


def test_a_clear_segment_stays_straight():
    router = ApproachRouter(SLAB, AXIS, d_min=3.0, standoff=7.0)
    a, b = np.array([0.0, -10.0, 30.0]), np.array([5.0, -12.0, 40.0])
    np.testing.assert_array_equal(router(a, b), np.stack([a, b]))


@pytest.mark.parametrize("start", [(0.0, 10.0, 30.0), (15.0, 8.0, 50.0), (-5.0, 7.0, 15.0)])
def test_a_route_around_a_slab_keeps_d_min_plus_margin_by_brute_force(start):
    router = ApproachRouter(SLAB, AXIS, d_min=3.0, standoff=7.0)
    a, b = np.array(start), np.array([0.0, -7.0, 35.0])
    straight = sample_polyline(np.stack([a, b]), 0.05)
    assert brute_distance(straight, SLAB).min() < 1.0                  # the straight line crosses it
    route = router(a, b)
    assert 3 <= len(route) <= 4 and np.allclose(route[0], a) and np.allclose(route[-1], b)
    samples = sample_polyline(route, 0.05)
    clear = brute_distance(samples, SLAB)
    assert clear.min() >= 3.0 + APPROACH_MARGIN - 0.01, clear.min()
    assert samples[:, 2].min() >= 3.0                                     # and above the ground


def test_ends_closer_than_the_margin_lower_the_ask_to_what_they_have():
    router = ApproachRouter(SLAB, AXIS, d_min=3.0, standoff=7.0)
    a, b = np.array([0.0, 3.2, 30.0]), np.array([0.0, -3.3, 35.0])        # 2.7 / 2.8 m from the slab
    route = router(a, b)
    assert len(route) >= 3
    assert brute_distance(sample_polyline(route, 0.05), SLAB).min() >= 2.7 - 0.01


def test_the_ground_is_an_obstacle():
    router = ApproachRouter(SLAB, AXIS, d_min=3.0, standoff=7.0)
    a, b = np.array([0.0, 10.0, 4.0]), np.array([0.0, -7.0, 6.0])
    route = router(a, b)
    samples = sample_polyline(route, 0.05)
    assert samples[:, 2].min() >= min(4.0, 6.0) - 0.01
    assert brute_distance(samples, SLAB).min() >= 3.0


@pytest.mark.slow
@pytest.mark.parametrize("episode", [8, 9, 12])
def test_the_campaigns_stalled_nrel_starts_now_reach_the_path(episode, tmp_path):
    """Campaign episodes 8, 9 and 12 (master seed 0: NREL 5-MW turbines, full and scaled, starts
    11-18 m off behind a blade) ended on a reference stall at 0 % coverage when the approach was a
    straight segment through the blade. Routed, VT-NMPC+ reaches the path and inspects."""
    from dataclasses import replace

    from wt_inspect.commands.campaign import CampaignConfig, campaign_specs, run_episode
    cfg = CampaignConfig(episodes=20, controller="vtnmpc-plus", seed=0, task="full", max_wind=10.0,
                         max_offset=30.0, only=(episode,))
    spec = replace(campaign_specs(cfg)[1][0], max_time=45.0)
    res = run_episode(spec, record=False)
    assert res.termination == "max_time", (res.termination, res.metrics)
    assert res.metrics["stalls"] == 0 and res.metrics["coverage"] > 0.01
    assert res.metrics["clearance_min_m"] >= 3.0 - 0.1
