"""``wt-inspect ablation``: the chain really goes from paper-faithful to the project default one
change at a time, the report says what changed, and bad input is a one-line error."""
from __future__ import annotations

import json

import pytest

from wt_inspect.ablation import BASE_CONTROLLERS, STEPS, main, markdown, plan_rows, run_ablation
from wt_inspect.evaluation.scenarios import env_options
from wt_inspect_env.task.env_config import EnvConfig


def _config(scenario: str, overrides: dict) -> EnvConfig:
    return EnvConfig.from_kwargs(**env_options(scenario, 4.0, overrides=overrides))


def test_chain_starts_paper_faithful_and_ends_at_the_project_default():
    rows = plan_rows()
    assert rows[0]["env"] == {} and rows[0]["controllers"] == BASE_CONTROLLERS
    assert _config("paper-faithful", rows[-1]["env"]) == _config("paper", {})
    assert rows[-1]["controllers"] == {"NMPC": "nmpc", "PAMPC": "pampc", "VT-NMPC": "vtnmpc-plus"}
    # one change per row: consecutive rows differ in the environment or in the controllers, never both
    for prev, row in zip(rows, rows[1:]):
        env_changed = _config("paper-faithful", prev["env"]) != _config("paper-faithful", row["env"])
        ctrl_changed = prev["controllers"] != row["controllers"]
        assert env_changed != ctrl_changed, row["key"]
    assert len({s.key for s in STEPS}) == len(STEPS)


def _doc() -> dict:
    rows = plan_rows(STEPS[:2])
    for i, row in enumerate(rows):
        row["cells"] = {f"{c}@4": {"coverage": 0.9 + 0.05 * i, "safety": 0.8, "centering": 0.99,
                                   "min_distance": 6.0, "controller": n, "termination": "mission_complete",
                                   "wall_time": 1.0} for c, n in row["controllers"].items()}
    return {"scenario": "paper-faithful-surface", "task": "surface", "winds": [4.0], "max_time": None,
            "wall_time_s": 3.0, "rows": rows, "paper": {"NMPC@4": {"coverage": 0.916}}}


def test_report_shows_each_rows_change_from_the_previous():
    md = markdown(_doc())
    assert "| 1 | lens 35 -> 24 mm | 95.0 (+5.0) / 80.0 / 99.0 / 6.00 `nmpc-authors`" in md
    assert "| 0 | paper-faithful" in md and "(+" not in md.split("| 0 |")[1].split("\n")[0]
    assert "| | paper (Gazebo, full mission) | 91.6 / - / - / -" in md


def test_bad_input_is_a_one_line_error(tmp_path, capsys):
    assert main(["--out", str(tmp_path / "a"), "--winds", "4,x"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--winds" in err and "'4,x'" in err
    assert not (tmp_path / "a" / "results.md").exists()
    assert main(["--out", str(tmp_path / "c"), "--rows", "11"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--rows must be between 1 and 10, got 11" in err
    with pytest.raises(ValueError, match="unknown task 'rotor'"):
        run_ablation(tmp_path / "b", task="rotor")


@pytest.mark.slow
def test_two_rows_fly_and_write_the_study(tmp_path):
    doc = run_ablation(tmp_path, task="surface", winds=(4.0,), jobs=1, max_time=0.05, steps=STEPS[:2])
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["rows"][1]["key"] == "lens" and (tmp_path / "ablation.png").stat().st_size > 1000
    cells = [row["cells"]["VT-NMPC@4"] for row in doc["rows"]]
    assert all(c["controller"] == "vtnmpc-later" for c in cells)
    # the wider lens sees more of the surface from the same start: coverage can only grow
    assert cells[1]["coverage"] > cells[0]["coverage"] > 0.0
    # the lens does not act on the flight: row 1 re-scores row 0's flights instead of flying
    assert cells[1]["rescored"] and not cells[0]["rescored"]
    assert [d.name for d in (tmp_path / "rows").iterdir()] == ["00_paper-faithful"]
    md = (tmp_path / "results.md").read_text()
    assert "↻" in md and "Only the first 2 of the chain's 10 rows" in md
    # the flights' own wall time, summed over the 3 flown runs (row 1 flies none)
    assert doc["n_flights"] == 3 and doc["flights_wall_s"] == pytest.approx(sum(c["wall_time"] for c in (
        doc["rows"][0]["cells"].values())))
    assert f"its 3 flights took {doc['flights_wall_s']:.0f} s of wall time in sum" in md
