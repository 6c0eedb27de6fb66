"""The analyses of wt_inspect.studies run on tiny inputs (each the way ``wt-inspect study NAME``
runs it) and write what their results/ folders hold; results/ itself holds no Python."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from wt_inspect.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]


def test_results_hold_no_python():
    tracked = subprocess.run(["git", "ls-files", "results"], cwd=ROOT, capture_output=True, text=True)
    files = tracked.stdout.split() if tracked.returncode == 0 else [
        str(p.relative_to(ROOT)) for p in (ROOT / "results").rglob("*")]
    assert [f for f in files if f.endswith((".py", ".ipynb", ".sh"))] == []


def test_study_lists_and_refuses_unknown(capsys):
    assert cli_main(["study", "--help"]) == 0
    assert "sm-vs-wind" in capsys.readouterr().out
    assert cli_main(["study", "nope"]) == 2
    assert "unknown study 'nope'" in capsys.readouterr().err


def test_sm_vs_wind_reproduces_the_committed_table(tmp_path):
    res = tmp_path / "results"
    for d in ("paper_faithful", "paper_faithful_wind"):
        (res / d).mkdir(parents=True)
        shutil.copy(ROOT / "results" / d / "results.csv", res / d / "results.csv")
    assert cli_main(["study", "sm-vs-wind", "--results", str(res)]) == 0
    out = res / "paper_faithful_wind"
    assert (out / "sm_vs_wind.csv").read_text() == (ROOT / "results/paper_faithful_wind/sm_vs_wind.csv").read_text()
    assert (out / "sm_vs_wind.png").stat().st_size > 0


def test_sm_vs_wind_names_a_missing_input(tmp_path, capsys):
    assert cli_main(["study", "sm-vs-wind", "--results", str(tmp_path)]) == 2
    assert "not found" in capsys.readouterr().err


def test_sm_vs_wind_interpolation():
    from wt_inspect.studies.sm_vs_wind import wind_for
    assert wind_for(0.5, {0.0: 1.0, 4.0: 0.0}) == pytest.approx(2.0)
    assert wind_for(0.5, {0.0: 1.0, 4.0: 0.9}) != wind_for(0.5, {0.0: 1.0, 4.0: 0.9})   # NaN: never crossed


def test_routes_redraws_from_json_and_extracts_runs(tmp_path):
    from wt_inspect.studies.routes import ROUTES
    out = tmp_path / "routes"
    out.mkdir()
    kept = [{"env_steps": 4000000, "wall_min": 38.5, "coverage": 1.0, "safety_sm": 0.9, "centering_cm": 0.99},
            {"env_steps": 6000000, "wall_min": 55.3, "coverage": 1.0, "safety_sm": 1.0, "centering_cm": 0.987}]
    fixture = {"runs": ROUTES, "target": {"coverage": 0.99, "safety_sm": 0.99, "centering_cm": 0.995},
               "routes": {"PPO from scratch, full task": [{"env_steps": 5, "wall_min": 0.5, "coverage": 0.0,
                                                           "safety_sm": 0.0, "centering_cm": 0.5}],
                          "PPO curriculum: surface -> blade -> full -> fine centering": kept}}
    (out / "routes.json").write_text(json.dumps(fixture))
    assert cli_main(["study", "routes", "--out", str(out), "--from-json"]) == 0
    assert (out / "routes.png").stat().st_size > 0
    assert json.loads((out / "routes.json").read_text()) == fixture          # --from-json only redraws
    # --add: one route's run extracted from a runs root, the others keep their points
    runs = tmp_path / "runs" / "ppo_scratch"
    runs.mkdir(parents=True)
    (runs / "evaluations.json").write_text(json.dumps([{"env_steps": 10, "wall_time_s": 60.0, "mean": {
        "coverage": 0.5, "safety_sm": 0.25, "centering_cm": 0.9}}]))
    assert cli_main(["study", "routes", "--out", str(out), "--add", str(tmp_path / "runs"),
                     "PPO from scratch, full task"]) == 0
    routes = json.loads((out / "routes.json").read_text())["routes"]
    assert routes["PPO from scratch, full task"] == [{"env_steps": 10, "wall_min": 1.0, "coverage": 0.5,
                                                      "safety_sm": 0.25, "centering_cm": 0.9}]
    assert routes["PPO curriculum: surface -> blade -> full -> fine centering"] == kept
    assert cli_main(["study", "routes", "--out", str(out), "--add", str(tmp_path / "runs"), "nope"]) == 2


@pytest.mark.slow
def test_wind_offset_one_case_matches_the_committed_csv(tmp_path):
    out = tmp_path / "wind_offset.csv"
    assert cli_main(["study", "wind-offset", "--controllers", "nmpc", "--cases", "1", "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    committed = next(csv.DictReader((ROOT / "results/lab/wind_offset.csv").open()))
    assert len(rows) == 1 and rows[0]["controller"] == committed["controller"] == "nmpc"
    assert float(rows[0]["settled_error_m"]) == pytest.approx(float(committed["settled_error_m"]), abs=2e-3)


@pytest.mark.slow
def test_hold_check_runs_from_another_directory(tmp_path):
    res = subprocess.run([sys.executable, "-m", "wt_inspect.cli", "study", "hold-check", "--seconds", "0.2"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env={**__import__("os").environ, "MPLBACKEND": "Agg"})
    assert res.returncode == 0, res.stderr[-2000:]
    last = json.loads(res.stdout.strip().splitlines()[-1])
    assert set(last) == {"4", "1"} and last["4"]["flight_s"] == pytest.approx(0.2, abs=0.011)
    assert list(tmp_path.iterdir()) == []


def test_hold_check_in_strong_wind_reports_clearance_and_saturated_decisions():
    from wt_inspect.studies import hold_check
    out = hold_check.run(0.3, (2,), wind=7.0, expert="vtnmpc-plus:backoff=0.5")
    row = out[2]
    assert row["flight_s"] == pytest.approx(0.3, abs=0.011) and row["termination"] is None
    # the mission starts on the stand-off pose, 7 m from the blade, far from d_min (3 m)
    assert 5.0 < row["least_clearance_m"] < 9.0
    assert len(row["saturated_share"]) == 4 and all(0.0 <= v <= 1.0 for v in row["saturated_share"])


@pytest.mark.parametrize("argv, match", [(["--holds", "4,x"], "--holds must be comma-separated"),
                                         (["--holds", "0"], "--holds must be positive"),
                                         (["--wind", "-1"], "--wind must be a non-negative"),
                                         (["--expert", "nope"], "is not a registered controller")])
def test_hold_check_refuses_bad_input_naming_it(argv, match, capsys):
    from wt_inspect.studies import hold_check
    with pytest.raises(SystemExit) as exc:
        hold_check.main(["--seconds", "0.1", *argv])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and match in err and "Traceback" not in err
