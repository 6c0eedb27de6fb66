"""``wt-inspect study pose-sweep``: the grid it plans, what it calls a shortfall, and a short sweep
end to end (resumed on the second call, the behaviour digests planned from its command)."""
from __future__ import annotations

import csv

import pytest

from wt_inspect.behaviour import study_runs
from wt_inspect.studies import pose_sweep


def test_grid_parses_ranges_and_lists_and_names_bad_input():
    assert pose_sweep._grid("0:170:10", "--azimuths") == [float(a) for a in range(0, 171, 10)]
    assert pose_sweep._grid("-60,0,60", "--facings") == [-60.0, 0.0, 60.0]
    for bad in ("0:10:0", "10:0:5", "a,b", ""):
        with pytest.raises(ValueError, match="--azimuths must be"):
            pose_sweep._grid(bad, "--azimuths")


def test_default_plan_is_every_azimuth_by_every_facing_on_the_chosen_turbine():
    specs = pose_sweep.planned_specs(["--turbine", "nrel-5mw", "--out", "x"])
    assert len(specs) == 18 * 3
    poses = {(s.env_options["turbine"]["rotor_azimuth_deg"], s.env_options["turbine"]["facing_deg"]) for s in specs}
    assert poses == {(float(a), float(f)) for a in range(0, 171, 10) for f in (-60, 0, 60)}
    assert all(s.env_options["turbine"]["preset"] == "nrel-5mw" and s.wind == 4.0 for s in specs)
    assert len({s.filename for s in specs}) == len(specs)        # one run file per mission
    # the digests of the study are planned from the same command
    runs = study_runs(["wt-inspect study pose-sweep --turbine nrel-5mw --out x"])
    assert [r.spec.key for r in runs] == [s.key for s in specs]


def test_shortfalls_name_each_missed_target():
    ok = {"complete": True, "termination": "mission_complete", "coverage": 0.995, "collisions": 0, "stalls": 0,
          "clearance_min_m": 3.05}
    assert pose_sweep.shortfalls(ok, 3.0) == []
    bad = ok | {"complete": False, "termination": "max_time", "coverage": 0.5, "stalls": 1, "clearance_min_m": 2.8}
    assert pose_sweep.shortfalls(bad, 3.0) == ["ended: max_time", "coverage 50.0 %", "1 stall(s)", "clearance 2.80 m"]


@pytest.mark.slow
def test_short_sweep_writes_its_tables_and_resumes(tmp_path, capsys):
    argv = ["--azimuths", "40:50:10", "--facings", "0", "--max-time", "3", "--out", str(tmp_path), "--jobs", "1",
            "--no-progress"]
    assert pose_sweep.main(argv) == 0
    assert "2 flown, 0 resumed" in capsys.readouterr().out
    with open(tmp_path / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [(float(r["azimuth_deg"]), r["termination"]) for r in rows] == [(40.0, "max_time"), (50.0, "max_time")]
    assert (tmp_path / "coverage.png").stat().st_size > 0
    assert "ended: max_time" in (tmp_path / "results.md").read_text()
    assert pose_sweep.main(argv) == 0
    assert "0 flown, 2 resumed" in capsys.readouterr().out


def test_a_mission_that_raises_is_recorded_and_the_sweep_goes_on(tmp_path, monkeypatch):
    """One mission raising (as the planner did for the NREL 5-MW preset at azimuth 70 before its
    grid routing) is a row with its error; the other missions are flown and tabulated."""
    from wt_inspect.evaluation import runner
    real = runner.execute

    def execute(spec, policy=None, **kw):
        if spec.env_options["turbine"]["rotor_azimuth_deg"] == 50.0:
            raise ValueError("no route here\nsecond line")
        return real(spec, policy, **kw)
    monkeypatch.setattr(runner, "execute", execute)
    argv = ["--azimuths", "40:50:10", "--facings", "0", "--max-time", "1", "--out", str(tmp_path), "--jobs", "1",
            "--no-progress"]
    assert pose_sweep.main(argv) == 0
    with open(tmp_path / "results.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["termination"] for r in rows] == ["max_time", "exception"]
    md = (tmp_path / "results.md").read_text()
    assert "azimuth 50, facing 0: ended: exception (ValueError: no route here (test_pose_sweep.py:" in md
    assert "| 50 | - * |" in md
