"""Re-scoring a recorded flight under another camera / coverage rule gives exactly what flying it
under those options gives (the flight itself does not depend on them)."""
from __future__ import annotations

import numpy as np
import pytest

from wt_inspect.evaluation import evaluate_policy
from wt_inspect.evaluation.runner import make_env, rescore_coverage
from wt_inspect.evaluation.scenarios import env_options

OTHER = {"camera": {"focal_length_mm": 24.0, "incidence_reference": "ray", "range_reference": "vertices"},
         "occlusion": True}


@pytest.fixture(scope="module")
def flown():
    return evaluate_policy("vtnmpc", scenario="paper-faithful-surface", wind=4.0, max_time=2.0)


def test_rescoring_under_the_runs_own_options_reproduces_its_counts(flown):
    score = rescore_coverage(flown, flown.spec.env_options)
    np.testing.assert_array_equal(score["counts"], flown.arrays["coverage_counts"])
    assert score["coverage"] == flown.metrics["coverage"] > 0.0


def test_rescoring_under_other_options_equals_flying_under_them(flown):
    other = evaluate_policy("vtnmpc", scenario="paper-faithful-surface", wind=4.0, max_time=2.0, env_overrides=OTHER)
    # the camera and the rule do not act on the flight ...
    np.testing.assert_array_equal(other.arrays["position"], flown.arrays["position"])
    # ... so the re-scored frames are what the other flight counted, triangle by triangle
    score = rescore_coverage(flown, env_options("paper-faithful-surface", 4.0, overrides=OTHER))
    np.testing.assert_array_equal(score["counts"], other.arrays["coverage_counts"])
    assert score["coverage"] == other.metrics["coverage"] != flown.metrics["coverage"]


def test_a_hold_uses_the_next_phases_geometry():
    """From the first sample of a phase-change hold the env inspects the turned rotor, while the
    reference still reports the old phase (with waiting set)."""
    env = make_env(env_options("paper", 0.0))
    try:
        env.reset(seed=0)
        u = env.unwrapped
        t1 = u.mission.turbines[1]
        # a pose 7 m in front of a phase-2 triangle, looking at it (yaw only: the gimbal levels the camera)
        c = t1.blade_vertices[u.mission.inspected][0].mean(axis=0)
        n = t1.blade_normals[u.mission.inspected][0]
        p = c + 7.0 * n / np.linalg.norm(n)
        yaw = np.arctan2(-n[1], -n[0])
        q = np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])     # [x, y, z, w]
        k = 3 * u.world.camera_every
        pos, quat = np.tile(p, (k, 1)), np.tile(q, (k, 1))
        waiting = u.replay_coverage(pos, quat, np.ones(k, int), np.ones(k, bool)).counts
        phase2 = u.replay_coverage(pos, quat, np.full(k, 2), np.zeros(k, bool)).counts
        phase1 = u.replay_coverage(pos, quat, np.ones(k, int), np.zeros(k, bool)).counts
        np.testing.assert_array_equal(waiting, phase2)
        assert phase2.sum() > 0 and not np.array_equal(phase1, phase2)
    finally:
        env.close()


def test_a_thinned_run_is_refused(flown):
    thin = evaluate_policy("vtnmpc", scenario="paper-faithful-surface", wind=4.0, max_time=0.05, record_every=2)
    with pytest.raises(ValueError, match="record_every=2"):
        rescore_coverage(thin, thin.spec.env_options)
    # options that change the flight itself cannot be answered by re-scoring
    with pytest.raises(ValueError, match="differ from the run's beyond camera, occlusion"):
        rescore_coverage(flown, {**flown.spec.env_options, "ctrl_hz": 100.0})
    with pytest.raises(ValueError, match="phase must have one entry per row"):
        env = make_env(flown.spec.env_options)
        try:
            env.reset(seed=0)
            env.unwrapped.replay_coverage(np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)), np.ones(2), np.zeros(3))
        finally:
            env.close()


def test_rescore_command_prints_writes_csv_and_refuses_bad_input(flown, tmp_path, capsys):
    import csv

    from wt_inspect.cli import main
    from wt_inspect.evaluation.runner import save_run
    run = save_run(flown, tmp_path / "runs" / flown.spec.filename)
    out = tmp_path / "rescored.csv"
    assert main(["rescore", str(tmp_path), "--camera", '{"focal_length_mm": 24}', "--occlusion", "on",
                 "--out", str(out)]) == 0
    expected = rescore_coverage(flown, {**flown.spec.env_options, "occlusion": True,
                                        "camera": {**flown.spec.env_options["camera"], "focal_length_mm": 24.0}})
    rows = list(csv.DictReader(out.open()))
    assert [r["run_file"] for r in rows] == [run.name]
    assert float(rows[0]["coverage_rescored"]) == expected["coverage"]
    assert float(rows[0]["coverage_flown"]) == flown.metrics["coverage"]
    assert f"{100 * expected['coverage']:.1f} % re-scored" in capsys.readouterr().out
    for argv, msg in ((["rescore", str(run)], "nothing to change"),
                      (["rescore", str(tmp_path / "nope"), "--occlusion", "on"], "neither a run file nor a directory"),
                      (["rescore", str(run), "--camera", "{oops"], "--camera must be JSON"),
                      (["rescore", str(run), "--camera", '{"focal": 3}'], "unknown camera option(s) ['focal']"),
                      (["rescore", str(run), "--occlusion", "on", "--out", str(tmp_path)], "is a directory")):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and msg in err, (argv, err)
