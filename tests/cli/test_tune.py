"""``wt-inspect tune``: the search space, the score, bad arguments, and a tiny resumable study."""
from __future__ import annotations

import csv
import json
import subprocess
import sys
from types import SimpleNamespace

import pytest

optuna = pytest.importorskip("optuna")

from controllers.pampc import PAMPCWeights  # noqa: E402
from controllers.vtnmpc import VTNMPCWeights  # noqa: E402
from wt_inspect.commands import tune  # noqa: E402


def test_blocks_scale_as_a_whole_and_zero_rows_stay_zero():
    w = PAMPCWeights()
    assert "heading" not in tune.blocks(w) and "perception" in tune.blocks(w)   # heading 0, perception (0.05, 0)
    s = tune.scaled(w, {"perception": 4.0, "inputs": 0.5})
    assert s.perception == (0.2, 0.0) and s.inputs == (1.5, 1.5, 0.5, 0.0175) and s.position == w.position
    assert tune.scaled(w, {k: 1.0 for k in tune.blocks(w)}) == w


def _result(termination, collisions=0, cov=0.5, sm=0.25, cm=float("nan")):
    return SimpleNamespace(termination=termination, metrics={"coverage": cov, "safety_sm": sm, "centering_cm": cm,
                                                             "collisions": collisions})


def test_score_sums_the_fractions_and_penalises_a_crash():
    assert tune.run_score(_result("max_time"), 1.0) == pytest.approx(0.75)        # undefined CM counts 0
    assert tune.run_score(_result("mission_complete", cm=1.0), 1.0) == pytest.approx(1.75)
    assert tune.run_score(_result("collision"), 2.0) == pytest.approx(-1.25)
    assert tune.run_score(_result("time_limit", collisions=3), 1.0) == pytest.approx(-0.25)


@pytest.mark.parametrize("args,message", [
    (["--controller", "ppo"], "'ppo' takes no weights file"),
    (["--controller", "lqr"], "'lqr' is not a registered controller"),
    (["--controller", "vtnmpc:weights=x.json"], "give the plain name"),
    (["--controller", "vtnmpc", "--trials", "0"], "--trials must be a positive integer, got 0"),
    (["--controller", "vtnmpc", "--scenario", "nope"], "unknown scenario 'nope'"),
    (["--controller", "vtnmpc", "--spread", "1"], "--spread must be a number above 1, got 1.0"),
    (["--controller", "vtnmpc", "--max-time", "-2"], "--max-time must be a positive number"),
    (["--controller", "vtnmpc", "--winds", "-1"], "--winds must be non-negative numbers"),
    (["--controller", "vtnmpc", "--storage", "nosuch://db"], "--storage 'nosuch://db' cannot be opened"),
])
def test_bad_arguments_are_one_line_exit_2_nothing_written(tmp_path, capsys, args, message):
    out = tmp_path / "out"
    if "--trials" not in args:
        args = [*args, "--trials", "1"]
    assert tune.main([*args, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_without_optuna_the_missing_extra_line():
    code = ("import sys; sys.modules['optuna'] = None; from wt_inspect.cli import main; "
            "sys.exit(main(['tune', '--controller', 'vtnmpc', '--trials', '1']))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("pybullet build time")]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "'optuna'" in lines[0] and "wt-inspect[tune]" in lines[0]


@pytest.mark.slow
def test_two_trials_write_best_weights_that_build_a_controller_and_a_rerun_resumes(tmp_path, capsys):
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    from wt_inspect.evaluation import registry
    out = tmp_path / "tune"
    args = ["--controller", "vtnmpc", "--scenario", "surface", "--max-time", "0.3", "--out", str(out),
            "--no-progress"]
    assert tune.main([*args, "--trials", "2"]) == 0
    best = out / "best_weights.json"
    weights = VTNMPCWeights.load(best)
    rows = list(csv.DictReader((out / "trials.csv").open()))
    assert [r["number"] for r in rows] == ["0", "1"] and all(r["state"] == "COMPLETE" for r in rows)
    # trial 0 is the controller's own weights
    assert json.loads((out / "trials" / "vtnmpc-surface" / "trial-0.json").read_text()) == VTNMPCWeights().to_dict()
    summary = json.loads((out / "tune.json").read_text())
    assert summary["best"]["weights"] == weights.to_dict() and summary["trials"] == 2
    assert summary["best"]["value"] == max(float(r["value"]) for r in rows)
    # each wind's score is the sum of its coverage, SM and CM, all three in the table
    for r in rows:
        assert float(r["score_w4"]) == pytest.approx(sum(float(r[f"{m}_w4"]) for m in ("coverage", "sm", "cm")))
    assert (out / "optimisation_history.png").stat().st_size > 0
    env = gym.make("WindTurbineInspection-Surface-v0")
    try:
        assert registry.resolve(f"vtnmpc:weights={best}")(env.unwrapped).config.weights == weights
    finally:
        env.close()

    # same storage and study name, --trials 4: the two missing trials, in two worker processes
    # sharing the storage; the same command again adds none
    assert tune.main([*args, "--trials", "4", "--jobs", "2"]) == 0
    study = optuna.load_study(study_name="vtnmpc-surface", storage=f"sqlite:///{out.resolve() / 'study.db'}")
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 4
    assert study.trials[0].params == {k: 1.0 for k in tune.blocks(VTNMPCWeights())}
    assert len({tuple(sorted(t.params.items())) for t in study.trials}) == 4     # no point flown twice
    assert len(list(csv.DictReader((out / "trials.csv").open()))) == 4
    assert json.loads((out / "tune.json").read_text())["added_now"] == 2
    assert tune.main([*args, "--trials", "4"]) == 0
    assert "0 trials added (4 in total" in capsys.readouterr().out
    assert len(optuna.load_study(study_name="vtnmpc-surface",
                                 storage=f"sqlite:///{out.resolve() / 'study.db'}").trials) == 4


@pytest.mark.slow
def test_a_trial_below_the_median_after_the_first_wind_is_pruned(tmp_path, monkeypatch):
    """The objective reports the running mean per wind; MedianPruner stops a poor trial before its
    second wind (the harness is replaced by a stub: the scores are set, not flown)."""
    flown: list[tuple[int, float]] = []

    def fake_evaluate(name, *, scenario, wind, seed, max_time, record):
        trial = int(name.rsplit("trial-", 1)[1].split(".")[0])
        flown.append((trial, wind))
        cov = 0.1 if trial == 4 else 0.9
        return _result("max_time", cov=cov, sm=0.0, cm=0.0)

    monkeypatch.setattr(tune, "evaluate_policy", fake_evaluate)
    cfg = tune.TuneConfig(controller="vtnmpc", winds=(0.0, 4.0), out=str(tmp_path), trials=5)
    (tmp_path / "trials" / "vtnmpc-surface").mkdir(parents=True)
    study = tune._study(cfg)
    study.optimize(tune.Objective(cfg, VTNMPCWeights()), n_trials=5)
    states = [t.state for t in study.trials]
    assert states[:4] == [optuna.trial.TrialState.COMPLETE] * 4 and states[4] == optuna.trial.TrialState.PRUNED
    assert (4, 4.0) not in flown and (4, 0.0) in flown and (3, 4.0) in flown
    assert study.trials[0].value == pytest.approx(0.9) and study.trials[0].intermediate_values == {0: 0.9, 1: 0.9}
