"""Behaviour digests decide whether a study is current (``wt_inspect.behaviour``): the digest of a
flight, its comparison, the runs a study's commands fly, and - end to end on a tiny checkout - a
deliberate change of one controller's weight makes exactly the studies that fly it stale."""
from __future__ import annotations

import io
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from wt_inspect import behaviour, reproduce


def _trajectory(n: int = 2501, dt: float = 0.01):
    t = np.arange(n) * dt
    pos = np.stack([np.sin(t), np.cos(t), 0.1 * t], axis=1) * 10.0
    vel = np.gradient(pos, dt, axis=0)
    return t, pos, vel


def test_the_digest_samples_every_whole_second_of_the_prefix():
    t, pos, vel = _trajectory()
    d = behaviour.digest(t, pos, vel, seconds=20.0)
    assert d["t"] == pytest.approx(np.arange(1.0, 21.0))
    np.testing.assert_allclose(d["position"], pos[100:2001:100], atol=0.5 * 10 ** -behaviour.DECIMALS)
    short = behaviour.digest(t[:550], pos[:550], vel[:550], seconds=20.0)   # a run that ended at 5.49 s
    assert len(short["t"]) == 5


def test_compare_agrees_within_the_tolerance_and_names_the_first_difference():
    t, pos, vel = _trajectory()
    d = behaviour.digest(t, pos, vel)
    noise = behaviour.digest(t, pos + 1e-7, vel - 1e-7)          # far beyond cross-machine rounding
    assert behaviour.compare(d, noise) == ""
    moved = pos.copy()
    moved[700:] += [0.0, 0.0, 0.01]                              # 1 cm from t = 7 s on
    why = behaviour.compare(d, behaviour.digest(t, moved, vel))
    assert why.startswith("position at t = 7 s differs by 0.01 m"), why
    why = behaviour.compare(d, behaviour.digest(t[:550], pos[:550], vel[:550]))
    assert "5 samples flown, 20 recorded" in why


def test_the_runs_of_a_study_are_planned_from_its_commands():
    paper = behaviour.study_runs(["wt-inspect evaluate --scenario paper --controllers vtnmpc,nmpc --winds 0,4 "
                                  "--out results/x --no-progress"])
    assert [(r.runner, r.spec.controller, r.spec.wind) for r in paper] == [
        ("evaluate", "vtnmpc", 0.0), ("evaluate", "nmpc", 0.0), ("evaluate", "vtnmpc", 4.0), ("evaluate", "nmpc", 4.0)]
    camp = behaviour.study_runs(["wt-inspect campaign --episodes 3 --controllers vtnmpc-plus,nmpc --out x"])
    assert [r.spec.controller for r in camp] == ["vtnmpc-plus"] * 3 + ["nmpc"] * 3
    assert [r.spec.seed for r in camp[:3]] == [r.spec.seed for r in camp[3:]]   # the same episodes
    assert {r.runner for r in camp} == {"campaign"}
    abl = behaviour.study_runs(["wt-inspect ablation --out x --task surface --winds 4 --rows 2"])
    assert {r.spec.scenario for r in abl} == {"paper-faithful-surface"} and len(abl) >= 3
    adv = behaviour.study_runs(["wt-inspect study safety-filter --starts 3 --out x"])
    assert [(r.runner, r.spec["start"], r.spec["filtered"]) for r in adv] == [
        ("adversary", k, f) for k in range(3) for f in (False, True)]
    # a tuning study: its first trial (the controller's own weights) on each of its winds, flown as the
    # registered controller's evaluation run
    tune = behaviour.study_runs(["wt-inspect tune --controller pampc --scenario lab --trials 3 --winds 4,7 --out x"])
    assert [(r.runner, r.spec.controller, r.spec.scenario, r.spec.wind) for r in tune] == [
        ("evaluate", "pampc", "lab", 4.0), ("evaluate", "pampc", "lab", 7.0)]
    sweep = behaviour.study_runs(["wt-inspect study pose-sweep --azimuths 0:20:10 --facings=0 --out x"])
    assert [r.spec.env_options["turbine"]["rotor_azimuth_deg"] for r in sweep] == [0.0, 10.0, 20.0]
    # the planner study plans (no flight): its runs are its drawn turbines, its digest their stand-off path
    planned = behaviour.digested_runs(["wt-inspect study planner-clearance --turbines 3 --out x"])
    assert [(r.runner, r.spec["episode"]) for r in planned] == [("planner", 0), ("planner", 2)]
    d = behaviour.fly_prefix(planned[0])
    assert len(d["t"]) == 21 and d["t"][0] == 0.0 and behaviour.compare(d, behaviour.fly_prefix(planned[0])) == ""
    moved = {**d, "position": [[x + 0.01, y, z] for x, y, z in d["position"]]}   # a plan 1 cm off
    assert "position" in behaviour.compare(d, moved)
    # the imitation study is digested by its expert on the paper mission in the 4 m/s gust
    imit = behaviour.digested_runs(["wt-inspect study imitation --out x --rounds 3"])
    assert [(r.runner, r.spec.controller, r.spec.scenario, r.spec.wind) for r in imit] == [
        ("evaluate", "vtnmpc-plus", "paper", 4.0)]
    tight = behaviour.digested_runs(["wt-inspect study imitation --out x --expert vtnmpc-plus:backoff=0.5 --seeds 0,1"])
    assert [r.spec.controller for r in tight] == ["vtnmpc-plus:backoff=0.5"]
    assert [r.spec.controller for r in behaviour.digested_runs(
        ["wt-inspect study imitation --out x --expert=nmpc --rounds 2"])] == ["nmpc"]   # read by the study's parser
    # commands that fly nothing have no digest; the first and the last run carry it
    assert behaviour.digested_runs(["wt-inspect study sm-vs-wind --results results"]) == []
    assert [r.spec.controller for r in behaviour.digested_runs(
        ["wt-inspect evaluate --scenario surface --controllers vtnmpc,nmpc,pampc --winds 4 --out x"])] == \
        ["vtnmpc", "pampc"]
    with pytest.raises(ValueError, match="do not parse"):
        behaviour.study_runs(["wt-inspect evaluate --scenario paper --nope --out x"])


def _checkout(tmp_path: Path, seconds: float) -> tuple[Path, list[reproduce.Study]]:
    """Two one-run studies (VT-NMPC and NMPC on the surface scenario) with provenance whose
    behaviour digests the current code flew."""
    studies = []
    for name, ctrl in (("a", "vtnmpc"), ("b", "nmpc")):
        folder = tmp_path / "results" / name
        folder.mkdir(parents=True)
        cmd = f"wt-inspect evaluate --scenario surface --controllers {ctrl} --winds 4 --out results/{name}"
        study = reproduce.Study(name, f"results/{name}", (cmd,))
        (folder / reproduce.PROVENANCE).write_text(json.dumps(
            {"study": name, "commands": [cmd], "code": "x", "complete": True,
             "behaviour": behaviour.record([cmd], seconds=seconds)}))
        studies.append(study)
    return tmp_path, studies


@pytest.mark.slow
def test_a_changed_weight_makes_exactly_the_studies_that_fly_it_stale(tmp_path, monkeypatch):
    from controllers import vtnmpc
    root, studies = _checkout(tmp_path, seconds=4.0)
    assert [reproduce.staleness(root, s) for s in studies] == ["", ""]     # the code is not what made "x"
    paper = vtnmpc.WEIGHT_SETS["paper"]
    monkeypatch.setitem(vtnmpc.WEIGHT_SETS, "paper", replace(paper, distance=2.0 * paper.distance))
    why_a, why_b = (reproduce.staleness(root, s) for s in studies)
    assert why_a.startswith("behaviour differs: surface vtnmpc wind 4 seed 0:"), why_a
    assert why_b == ""
    # without flying, the recorded behaviour is taken as it is
    assert reproduce.staleness(root, studies[0], fly=False) == ""


@pytest.mark.slow
def test_check_reports_a_study_whose_behaviour_changed(tmp_path, monkeypatch):
    from controllers import vtnmpc
    root, studies = _checkout(tmp_path, seconds=2.0)
    out = io.StringIO()
    assert reproduce.check(root, studies, out=out) == 0, out.getvalue()
    paper = vtnmpc.WEIGHT_SETS["paper"]
    monkeypatch.setitem(vtnmpc.WEIGHT_SETS, "paper", replace(paper, distance=2.0 * paper.distance))
    out = io.StringIO()
    assert reproduce.check(root, studies, out=out) == 1
    assert "stale, not in results/STALE.md: a (results/a): behaviour differs" in out.getvalue()
    assert "1 current, 1 stale" in out.getvalue()


def test_the_noise_envelope_is_the_largest_spread_of_the_twins_so_far():
    t, pos, vel = _trajectory()
    flown = behaviour.digest(t, pos, vel)
    bump = pos.copy()
    bump[500:600] += [0.0, 0.003, 0.0]                  # a twin 3 mm off at t = 5 s only
    late = pos.copy()
    late[1200:] += [0.001, 0.0, 0.0]                     # another 1 mm off from t = 12 s
    short = behaviour.digest(t[:1050], pos[:1050], vel[:1050])    # a twin that ended at 10.49 s
    env = behaviour.noise_envelope(flown, [behaviour.digest(t, bump, vel), behaviour.digest(t, late, vel)])
    expected = np.where(np.arange(1, 21) >= 5, 0.003, 0.0)       # never forgotten once reached
    np.testing.assert_allclose(env["position"], expected, atol=1e-9)
    np.testing.assert_allclose(env["velocity"], 0.0, atol=1e-9)
    env = behaviour.noise_envelope(flown, [short])
    assert np.all(np.isinf(env["position"][10:])) and np.all(env["position"][:10] == 0.0)


def test_compare_forgives_a_difference_within_the_runs_own_noise_and_nothing_more():
    t, pos, vel = _trajectory()
    recorded = behaviour.digest(t, pos, vel)
    moved = pos.copy()
    moved[700:] += [0.0, 0.0, 0.01]                                  # 1 cm from t = 7 s on
    flown = behaviour.digest(t, moved, vel)
    noise = {"position": np.where(np.arange(1, 21) >= 7, 0.004, 0.0), "velocity": np.zeros(20)}
    assert behaviour.compare(recorded, flown) != ""                 # beyond 2 mm without the twins
    assert behaviour.compare(recorded, flown, noise=noise) == ""    # 1 cm < 5 x 4 mm
    quiet = {"position": np.full(20, 0.001), "velocity": np.zeros(20)}
    assert behaviour.compare(recorded, flown, noise=quiet).startswith("position at t = 7 s")   # 1 cm > 5 x 1 mm


def test_a_noise_twin_moves_only_the_start():
    run = behaviour.study_runs(["wt-inspect evaluate --scenario paper --controllers vtnmpc --winds 4 "
                                "--out results/x --no-progress"])[0]
    twin = behaviour.noise_twin(run, 1e-10)
    assert twin.spec.env_options["start_offset"] == pytest.approx([1e-10] * 3, abs=0)
    assert {k: v for k, v in twin.spec.env_options.items() if k != "start_offset"} == {
        k: v for k, v in run.spec.env_options.items() if k != "start_offset"}
    assert replace(twin.spec, env_options=run.spec.env_options) == run.spec
    adv = behaviour.study_runs(["wt-inspect study safety-filter --starts 1 --out x"])[0]
    assert behaviour.noise_twin(adv, 1e-8).spec == {**adv.spec, "start_offset_m": 1e-8}
    camp = behaviour.study_runs(["wt-inspect campaign --episodes 1 --controllers vtnmpc --out x"])[0]
    assert behaviour.noise_twin(camp, 1e-10) is None                  # a campaign chooses its own start
