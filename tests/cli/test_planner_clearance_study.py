"""The planner's clearance promise: the path certificate on crafted geometry, the property on
turbines the campaign draws (against brute force), and the study's files and resumption."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from oracles import brute_distance

from wt_inspect.studies import planner_clearance as pc
from wt_inspect_env.planner.clearance import DistanceField

# one small triangle at the origin, in the plane z = 0
TINY = np.array([[[-0.05, -0.05, 0.0], [0.05, -0.05, 0.0], [0.0, 0.05, 0.0]]])
FAR = np.array([[[100.0, 100.0, 0.0], [101.0, 100.0, 0.0], [100.0, 101.0, 0.0]]])


def test_a_long_segment_is_sampled_where_its_bound_does_not_certify_it():
    """Poses 5.8 m from a small obstacle, the segment between them passing 3 m over it: the
    Lipschitz bound (0.83 m) cannot certify it, the sampled segment gives the true 3 m."""
    poses = np.array([[-5.0, 0.0, 3.0], [5.0, 0.0, 3.0]])
    r = pc.check_mission(poses, np.array([1, 1]), [DistanceField(TINY)], d_min=2.0)
    assert r["pose_min_m"] == pytest.approx(math.hypot(4.95, 3.0), abs=0.06)
    assert r["refined_segments"] == 1
    assert 3.0 - pc.REFINE_STEP <= r["path_min_m"] <= 3.0 + 1e-9
    assert r["hold_min_m"] == math.inf


def test_short_segments_are_certified_by_the_bound_and_never_overstated():
    """A densely sampled path: no segment needs sampling, and the bound is below the true least
    distance of the continuous path by at most half a segment."""
    x = np.linspace(-5.0, 5.0, 101)
    poses = np.column_stack([x, np.zeros_like(x), np.full_like(x, 3.0)])
    r = pc.check_mission(poses, np.ones(len(x), dtype=int), [DistanceField(TINY)], d_min=2.0)
    assert r["refined_segments"] == 0
    assert 3.0 - 0.05 - 1e-9 <= r["path_min_m"] <= 3.0


def test_a_rotor_turn_hold_is_checked_against_the_turned_rotor():
    """The last pose of phase 1 is where the drone waits while the rotor turns: 1 m from the
    phase-2 geometry, the study reports it and calls the turbine below d_min."""
    poses = np.array([[50.0, 50.0, 5.0], [0.0, 0.0, 1.0], [0.0, 0.0, 4.0]])
    r = pc.check_mission(poses, np.array([1, 1, 2]), [DistanceField(FAR), DistanceField(TINY)], d_min=3.0)
    assert r["hold_min_m"] == pytest.approx(1.0, abs=1e-9)
    assert r["path_min_m"] <= 1.0 + 1e-9      # the segment leaving the hold starts 1 m from it
    row = {"refused": "", "d_min_m": 3.0, **r}
    assert pc.failures(row) == ["path 1.000 m from the turbine", "turn hold 1.000 m from the turbine"]
    assert pc.failures({**row, "refused": "surface 3 cannot be inspected"}) == []


@pytest.mark.parametrize("phase, fields, match", [
    ([1], 1, "one length"), ([1, 1, 2], 1, "non-decreasing"), ([2, 1, 1], 2, "non-decreasing")])
def test_bad_missions_name_the_problem(phase, fields, match):
    with pytest.raises(ValueError, match=match):
        pc.check_mission(np.zeros((3, 3)), np.array(phase), [DistanceField(TINY)] * fields, d_min=3.0)


@pytest.fixture(scope="module")
def drawn_rows():
    """The first campaign draws planned as the environment plans them (the whole study does 1,000)."""
    return [pc.check_draw(d) for d in pc.draws(6, seed=0)]


@pytest.mark.slow
def test_drawn_turbines_keep_d_min_on_every_pose_and_path(drawn_rows):
    kinds = {r["turbine"] for r in drawn_rows}
    assert {"generated", "nrel-5mw-scaled"} <= kinds
    for r in drawn_rows:
        assert not r["refused"], r
        assert pc.failures(r) == [], r
        assert r["samples"] > 1000 and r["phases"] >= 2


def test_the_distances_behind_the_verdict_equal_brute_force():
    """The poses nearest the structure on a drawn turbine, re-measured over every triangle."""
    from wt_inspect_env.task.reference import standoff_poses
    cfg, m = pc.drawn_mission(pc.draws(1, seed=0)[0])
    poses = standoff_poses(m.points, m.normals, cfg.standoff)
    sel = m.phase == 1
    tris = m.turbines[0].all_triangles
    d = DistanceField(tris).distance(poses[sel], math.inf)
    near = np.argsort(d)[:40]
    np.testing.assert_allclose(d[near], brute_distance(poses[sel][near], tris), rtol=0, atol=1e-9)
    assert d.min() >= cfg.d_min


@pytest.mark.slow
def test_the_study_writes_its_files_and_resumes(tmp_path, monkeypatch):
    argv = ["--turbines", "2", "--out", str(tmp_path), "--jobs", "1", "--no-progress"]
    assert pc.main(argv) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["turbines"] == 2 and summary["below_d_min"] == 0
    assert summary["least_path_clearance_m"] >= 3.0
    assert (tmp_path / "clearance.png").stat().st_size > 0
    assert "below d_min: **0** of 2" in (tmp_path / "results.md").read_text()
    first = (tmp_path / "results.csv").read_text()

    def no_planning(draw):
        raise AssertionError("a saved chunk was planned again")
    monkeypatch.setattr(pc, "check_draw", no_planning)
    assert pc.main(argv) == 0
    assert (tmp_path / "results.csv").read_text() == first


@pytest.mark.parametrize("argv, match", [(["--turbines", "0"], "--turbines"), (["--seed", "-1"], "--seed")])
def test_bad_arguments_name_the_option(tmp_path, capsys, argv, match):
    with pytest.raises(SystemExit):
        pc.main(argv + ["--out", str(tmp_path)])
    assert match in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("azimuth", [70.0, 90.0])
def test_nrel_5mw_poses_whose_transit_needed_the_grid_search_get_clear_missions(azimuth):
    """The rotor-pose sweep found these: a root-end stand-off in the pocket between a blade root
    and the hub, which no one- or two-via detour leaves (the planner raised NoRouteError)."""
    from wt_inspect_env.task.env_config import EnvConfig
    from wt_inspect_env.task.mission import build_mission
    from wt_inspect_env.task.reference import standoff_poses
    cfg = EnvConfig(task="full", wind="none", rotor_turn_deg=None,
                    turbine={"preset": "nrel-5mw", "rotor_azimuth_deg": azimuth, "facing_deg": 0.0})
    m = build_mission(cfg)
    poses = standoff_poses(m.points, m.normals, cfg.standoff)
    r = pc.check_mission(poses, m.phase, [DistanceField(t.all_triangles) for t in m.turbines], cfg.d_min)
    assert pc.failures({"refused": "", "d_min_m": cfg.d_min, **r}) == [], r
