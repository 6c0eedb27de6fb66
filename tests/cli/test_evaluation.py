"""Evaluation harness: command line end to end (results, figures, resume after an interruption,
errors), the Python API on custom policies, and the local and Ray backends agreeing.

All runs use the ``surface`` scenario capped at a few simulated seconds (~0.3 s of CPU each).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stub_policies import Hover

from wt_inspect.evaluation import OutputDirError, evaluate_policy, load_run, registry, run_evaluation
from wt_inspect.evaluation.cli import main as cli_main
from wt_inspect.evaluation.report import CSV_COLUMNS, ReportContext, markdown, read_csv
from wt_inspect.evaluation.runner import save_run
from wt_inspect.evaluation.scenarios import env_options
from wt_inspect_env.policy import Policy
from wt_inspect_env.task.metrics import compute_metrics

REQUIRED = ("scenario", "controller", "wind", "seed", "coverage", "safety", "centering", "mean_distance",
            "min_distance", "collisions", "flight_time", "solve_median_ms", "solve_p99_ms")
METRICS = ("coverage", "safety", "centering", "mean_distance", "min_distance", "max_distance",
           "rms_distance_error", "collisions", "flight_time", "path_length", "steps", "sim_time")


class HoverPolicy(Policy):
    """Holds the hover command: a custom policy whose effect is known (it drifts with the wind)."""

    def __init__(self, env) -> None:
        self.hover = env.scaling.hover_action().astype(np.float32)
        self.seeds: list = []
        self.calls = 0

    def reset(self, seed=None) -> None:
        self.seeds.append(seed)

    def act(self, obs):
        assert obs["position"].shape == (3,)
        self.calls += 1
        return self.hover


def _runs(out: Path) -> dict[str, float]:
    """Finished run files (pathlib's glob also matches the hidden temporaries of writes in flight)."""
    return {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.npz") if not p.name.startswith(".")}


def _metric_rows(path: Path) -> dict[tuple, dict]:
    return {(r["controller"], r["wind"], r["seed"]): {k: r[k] for k in METRICS} for r in read_csv(path)}


@pytest.mark.slow
def test_cli_end_to_end_and_resume(tmp_path, capsys):
    out = tmp_path / "ev"
    argv = ["--scenario", "surface", "--controllers", "vtnmpc,nmpc", "--winds", "0,4", "--max-time", "2",
            "--out", str(out), "--jobs", "1", "--no-progress"]
    assert cli_main(argv) == 0
    rows = read_csv(out / "results.csv")
    assert len(rows) == 4 and set(REQUIRED) <= set(rows[0]) and list(rows[0]) == list(CSV_COLUMNS)
    assert {(r["controller"], r["wind"]) for r in rows} == {(c, w) for c in ("vtnmpc", "nmpc") for w in (0.0, 4.0)}
    for r in rows:
        for k in ("coverage", "safety", "centering"):
            assert 0.0 <= r[k] <= 1.0, (k, r)
        assert 0 < r["min_distance"] <= r["mean_distance"] and r["collisions"] == 0
        assert r["flight_time"] == pytest.approx(2.0) and r["termination"] == "max_time"
        assert 0 < r["solve_median_ms"] <= r["solve_p99_ms"]
        # the row is the run file's metrics, and they follow from its recorded trajectory
        run = load_run(out / "runs" / r["run_file"])
        a = run.arrays
        n_tri = len(a["inspected"])
        m = compute_metrics(a["t"], a["position"], a["quaternion"], a["point"], a["normal"],
                            inspecting=a["inspecting"], n_new=np.diff(np.round(a["coverage"] * n_tri), prepend=0)
                            .astype(int), n_triangles=n_tri, d_ref=7.0)
        assert m.safety_sm == pytest.approx(r["safety"], abs=2 / len(a["t"]))
        assert m.centering_cm == pytest.approx(r["centering"], abs=1e-5)
        assert m.coverage == pytest.approx(r["coverage"])
    md = (out / "results.md").read_text()
    assert "| metric | NMPC | VT-NMPC |" in md and "Safety (SM) (±1 m)" in md   # no paper numbers: no column
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == sorted(f"{k}_w{w}.png" for k in ("trajectories", "distance", "centering", "coverage", "energy")
                          for w in (0, 4))
    assert all((out / p).stat().st_size > 10_000 for p in pngs)

    # resume: a deleted run (and a leftover temporary file of an interrupted write) is redone, the
    # others are reused untouched, and the table is the same
    before, table = _runs(out), _metric_rows(out / "results.csv")
    victim = sorted(before)[0]
    (out / "runs" / victim).unlink()
    stale = out / "runs" / f".{victim}.0123456789ab.tmp.npz"   # as a SIGKILLed write leaves it
    stale.write_bytes(b"partial")
    os.utime(stale, (time.time() - 3600, time.time() - 3600))
    capsys.readouterr()
    assert cli_main(argv) == 0
    assert "(1 executed, 3 resumed)" in capsys.readouterr().out
    after = _runs(out)
    assert set(after) == set(before) and all(after[k] == before[k] for k in before if k != victim)
    assert _metric_rows(out / "results.csv") == table   # the redone run is deterministic
    # a run file made by other simulation/controller code is flagged when resumed
    old = load_run(out / "runs" / victim)
    old.code = "0ther-c0de"
    save_run(old, out / "runs" / victim)
    capsys.readouterr()
    assert cli_main(argv + ["--no-figures"]) == 0
    assert "other simulation/controller code" in capsys.readouterr().err
    assert victim in (out / "results.md").read_text()
    # a changed option is a different run, not a resumed one
    capsys.readouterr()
    assert cli_main([a if a != "2" else "1" for a in argv] + ["--no-figures"]) == 0
    assert "(4 executed, 0 resumed)" in capsys.readouterr().out


@pytest.mark.slow
def test_interrupted_evaluation_keeps_finished_runs(tmp_path):
    out = tmp_path / "ev"
    cmd = [sys.executable, "-m", "wt_inspect.cli", "evaluate", "--scenario", "surface", "--controllers",
           "vtnmpc,nmpc,pampc", "--winds", "0,4", "--max-time", "15", "--out", str(out), "--jobs", "2",
           "--no-progress", "--no-figures"]   # 15 s: each run ~1.5 s, so the interrupt lands mid-sweep
    log = tmp_path / "log.txt"
    with open(log, "w") as f:   # a file, not a pipe: a stray worker holding a pipe open cannot block us
        # SIG_DFL in the child: a test run from a background job (nohup ... &) inherits an ignored SIGINT,
        # and Python then never raises KeyboardInterrupt
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, text=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        deadline = time.time() + 60
        while time.time() < deadline and proc.poll() is None and not ((out / "runs").is_dir() and _runs(out)):
            time.sleep(0.05)
        assert proc.poll() is None, log.read_text()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    err = log.read_text()
    assert proc.returncode == 130, err
    assert "interrupted" in err
    kept = _runs(out)
    assert 1 <= len(kept) < 6, kept
    assert not [p for p in (out / "runs").iterdir() if p.suffix != ".npz" or p.name.startswith(".")]
    rows = read_csv(out / "results.csv")
    assert sorted(r["run_file"] for r in rows) == sorted(kept)
    assert "Incomplete" in (out / "results.md").read_text()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"({6 - len(kept)} executed, {len(kept)} resumed)" in done.stdout
    assert len(read_csv(out / "results.csv")) == 6
    assert all(_runs(out)[k] == v for k, v in kept.items())


def test_bad_controller_and_unwritable_out_dir(tmp_path, capsys):
    out = tmp_path / "ev"
    assert cli_main(["--scenario", "surface", "--controllers", "vtnmpc,lqr", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'lqr'" in err and all(n in err for n in ("vtnmpc", "nmpc", "pampc", "ppo:PATH"))
    assert not out.exists()
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    for bad in (blocker, blocker / "sub"):
        assert cli_main(["--scenario", "surface", "--controllers", "vtnmpc", "--max-time", "1", "--out", str(bad)]) == 2
        err = capsys.readouterr().err
        assert str(bad) in err and "output directory" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"] and blocker.read_text() == "x"
    with pytest.raises(OutputDirError, match="file.txt"):
        run_evaluation("surface", ["vtnmpc"], [0], out=blocker, max_time=1, progress=False)
    for argv, needle in ((["--winds", "4,fast"], "--winds"), (["--seeds", "-1"], "seeds"),
                         (["--turbine", '{"blade_lenght": 3}'], "blade_lenght"), (["--scenario", "moon"], "moon"),
                         (["--env", '{"wind": "none"}'], "wind"), (["--jobs", "0"], "jobs")):
        assert _exit_code(["--controllers", "vtnmpc", "--out", str(out)] + argv) == 2
        assert needle in capsys.readouterr().err
    assert not out.exists()


def _exit_code(argv: list[str]) -> int:
    """cli_main's return value, or argparse's exit code for a malformed option."""
    try:
        return cli_main(argv)
    except SystemExit as exc:
        return int(exc.code)


@pytest.mark.slow
def test_python_api_custom_policy_object_and_factory():
    env_holder = {}

    def factory(env):
        env_holder["env"] = env
        env_holder["policy"] = HoverPolicy(env)
        return env_holder["policy"]

    res = evaluate_policy(factory, scenario="surface", wind=4.0, seed=3, max_time=1.5, name="hover")
    pol = env_holder["policy"]
    assert pol.seeds == [3] and pol.calls == res.steps == 150
    a = res.arrays
    assert np.all(a["action"][:-1] == pol.hover) and np.isnan(a["action"][-1]).all()
    assert np.all(np.isnan(a["solve_ms"][:-1]))   # a custom policy reports no solver time
    assert np.isnan(res.solve["solve_median_ms"]) and res.solve["act_median_ms"] > 0
    # hovering in a 4 m/s gust along +y: the drone drifts downwind, and the metrics say so
    drift = a["position"][-1] - a["position"][0]
    assert drift[1] > 0.3 and abs(drift[0]) < 0.2 * drift[1]
    assert res.row()["controller"] == "hover"
    d_last = np.hypot(*(a["point"][-1, :2] - a["position"][-1, :2]))
    assert a["distance"][-1] == pytest.approx(d_last, rel=1e-5)
    # the same object passed directly is scored identically (same seed, same physics)
    obj = HoverPolicy(env_holder["env"])
    res2 = evaluate_policy(obj, scenario="surface", wind=4.0, seed=3, max_time=1.5)
    assert res2.metrics == res.metrics and obj.calls == 150
    # a factory that builds the registered controller scores exactly like its registry name
    from controllers.vtnmpc import VTNMPCPolicy
    mine = evaluate_policy(lambda env: VTNMPCPolicy(params=env.params, d_ref=env.config.standoff,
                                                    obstacles=env.mission),   # as registered: the clearance
                           scenario="surface", wind=4.0, seed=0, max_time=1.5, record=False)
    ref = evaluate_policy("vtnmpc", scenario="surface", wind=4.0, seed=0, max_time=1.5, record=False)
    assert mine.metrics == ref.metrics and mine.arrays == {}
    with pytest.raises(ValueError, match="reset"):
        evaluate_policy(types.SimpleNamespace(act=lambda obs: None), scenario="surface", max_time=0.1)
    with pytest.raises(ValueError, match="unknown controller 'lqr'"):
        evaluate_policy("lqr", scenario="surface")


def test_sb3_hook(tmp_path, monkeypatch):
    model = tmp_path / "agent.zip"
    model.write_bytes(b"weights")
    monkeypatch.setitem(sys.modules, "agents.policy", None)   # as if agents/policy.py did not exist
    with pytest.raises(ValueError, match="load_sb3_policy"):
        evaluate_policy(f"ppo:{model}", scenario="surface", max_time=0.1)
    calls = []

    def load_sb3_policy(algo, path, env):
        calls.append((algo, str(path)))   # a str or a resolved Path
        return HoverPolicy(env)
    monkeypatch.setitem(sys.modules, "agents.policy", types.SimpleNamespace(load_sb3_policy=load_sb3_policy))
    res = evaluate_policy(f"ppo:{model}", scenario="surface", max_time=0.2)
    assert calls == [("ppo", str(model))] and res.steps == 20
    # resuming keys on the model's content: a retrained file is a different run
    key = lambda: registry.fingerprint(f"ppo:{model}")  # noqa: E731
    k1 = key()
    model.write_bytes(b"retrained")
    assert key() != k1
    with pytest.raises(ValueError, match="neither a file nor a shipped model"):
        registry.check_controller(f"ppo:{tmp_path / 'missing.zip'}")
    with pytest.raises(ValueError, match="'dqn2' is not a registered name taking an argument"):
        registry.check_controller("dqn2:x.zip")


def test_scenarios_build_the_papers_setups():
    lab = env_options("lab", 4.0)
    assert (lab["task"], lab["standoff"], lab["safety_margin"], lab["drone"]) == ("blade", 0.5, 0.1, "lab250")
    assert lab["turbine"]["blade_length"] == 5.0 and lab["wind"] == {"type": "gust", "mean_speed": 4.0}
    paper = env_options("paper", 7.0, turbine={"blade_length": 40}, wind_options={"direction": [1, 0, 0]})
    assert paper["turbine"] == {"blade_length": 40} and paper["wind"]["direction"] == [1, 0, 0]
    assert env_options("lab", 4.0, turbine={"tower_height": 10.0})["turbine"]["blade_width"] == 0.3
    assert env_options("surface", 0.0, wind_type="dryden")["wind"] == "none"
    assert env_options("surface", 0.0)["wind"] == {"type": "gust", "mean_speed": 0.0}
    with pytest.raises(ValueError, match="task"):
        env_options("paper", 4.0, overrides={"task": "surface"})
    with pytest.raises(ValueError, match="mean_speed"):
        env_options("paper", 4.0, wind_options={"mean_speed": 3})
    with pytest.raises(ValueError, match="wind speed must be non-negative"):
        env_options("paper", -1.0)


@pytest.mark.slow
def test_local_and_ray_backends_agree(tmp_path):
    pytest.importorskip("ray")
    common = dict(scenario="surface", controllers=["vtnmpc", "pampc"], winds=[4.0], seeds=[0, 1], max_time=2.0,
                  wind_type="dryden", figures=False, progress=False, jobs=2)
    local = run_evaluation(out=tmp_path / "local", backend="local", **common)
    ray_ev = run_evaluation(out=tmp_path / "ray", backend="ray", **common)
    assert local.n_ran == ray_ev.n_ran == 4
    rows_l, rows_r = _metric_rows(tmp_path / "local" / "results.csv"), _metric_rows(tmp_path / "ray" / "results.csv")
    assert rows_l == rows_r
    for r in local.results:
        a, b = load_run(r.path), load_run(tmp_path / "ray" / "runs" / r.path.name)
        for k in ("position", "quaternion", "wind", "coverage_counts"):
            np.testing.assert_array_equal(a.arrays[k], b.arrays[k])
    # Dryden turbulence is seeded: the two seeds differ, so agreeing is not trivial
    assert rows_l[("vtnmpc", 4.0, 0.0)] != rows_l[("vtnmpc", 4.0, 1.0)]


@pytest.mark.slow
def test_ray_backend_without_an_address_runs_on_its_own_instance(tmp_path, monkeypatch):
    """Without ``address`` the backend starts a private instance even when the environment points
    Ray at some cluster (a stale ``ray start``, an exported RAY_ADDRESS): nothing listens on
    192.0.2.2 (TEST-NET-1), so joining it would fail."""
    pytest.importorskip("ray")
    monkeypatch.setenv("RAY_ADDRESS", "192.0.2.2:6379")
    ev = run_evaluation(out=tmp_path / "ray", backend="ray", scenario="surface", controllers=["vtnmpc"],
                        winds=[0.0], seeds=[0], max_time=0.5, figures=False, progress=False, jobs=1)
    assert ev.n_ran == 1 and (tmp_path / "ray" / "results.csv").is_file()


@pytest.mark.parametrize("address", ["127.0.0.1:1", "ray://127.0.0.1:1", "no-port"])
def test_ray_address_nothing_answers_on_is_refused_at_once(address):
    pytest.importorskip("ray")
    from wt_inspect_env.util.ray_session import init_ray
    with pytest.raises(ValueError, match=f"address '{address}'"):
        init_ray(address)


def test_display_names():
    from wt_inspect.evaluation.registry import display_name
    assert display_name("ppo:agents/models/ppo_blade_wind_mix.zip") == "PPO (ppo_blade_wind_mix)"
    assert display_name("vtnmpc-plus") == "VT-NMPC+" and display_name("custom") == "custom"
    # the seeds of a training study share their file names: their folders tell them apart
    seeds = [display_name(f"ppo:runs/s/seed_{i}/best_model.zip") for i in (0, 1)]
    assert seeds == ["PPO (seed_0/best_model)", "PPO (seed_1/best_model)"]
    assert display_name("ppo:runs/s/seed_0/model.zip+filter") == "PPO (seed_0/model) + filter"


def test_results_md_names_the_turbine_and_drone_given_over_the_scenario():
    from wt_inspect.evaluation.report import ReportContext, markdown
    plain = markdown([], ReportContext(scenario="paper"))
    assert "overridden" not in plain
    text = markdown([], ReportContext(scenario="paper", overrides={"turbine": {"tower_height": 90.0},
                                                                    "drone": "lab250"}))
    head = text.splitlines()[2]
    assert '**turbine overridden**: `{"tower_height": 90.0}`' in head and '**drone overridden**: `"lab250"`' in head


@pytest.mark.parametrize("overrides, frames, step", [
    ({}, "camera frames at 10 Hz, occlusion tested", "every control step (0.01 s)"),
    ({"occlusion": False, "ctrl_hz": 200.0, "camera_hz": 5.0}, "camera frames at 5 Hz, no occlusion test",
     "every control step (0.005 s)"),
])
def test_results_md_states_the_runs_own_camera_rate_occlusion_and_control_step(tmp_path, overrides, frames,
                                                                               step) -> None:
    run_evaluation("surface", ["nmpc"], [0], out=tmp_path, jobs=1, max_time=0.05, env_overrides=overrides,
                   figures=False, progress=False)
    metrics_line = next(line for line in (tmp_path / "results.md").read_text().splitlines()
                        if line.startswith("- Metrics"))
    assert frames in metrics_line and step in metrics_line


@pytest.mark.slow
def test_a_stalled_run_reports_its_stall_in_the_results_row(tmp_path):
    """A drone that only hovers: the closed-loop reference waits for it and stalls after
    reference_stall_time; by default it moves on and the mission completes without the drone, with
    ``"end"`` the run ends there. results.csv carries the stalls and the path skipped, the run's
    stall log when, where and why (a hovering drone far from its pose: not the clearance), the
    run file keeps the log and results.md lists it."""
    res = evaluate_policy(lambda env: Hover(env), scenario="surface", wind=0.0,
                          env_overrides={"reference_stall_time": 2.0, "reference_on_stall": "end"}, record=False)
    row = res.row()
    assert res.termination == "reference_stall" and row["termination"] == "reference_stall"
    assert row["stalls"] == 1.0 and row["skipped_path_m"] == 0.0
    (event,) = res.stall_log
    assert event["action"] == "ended" and event["why"].startswith("held off")
    assert event["time_s"] == pytest.approx(res.sim_time_s, abs=0.2) and event["distance_to_pose_m"] > 1.0
    assert event["clearance_m"] > 3.5 and 0.0 <= event["progress"] < 0.1
    res = evaluate_policy(lambda env: Hover(env), scenario="surface", wind=0.0,
                          env_overrides={"reference_stall_time": 2.0}, record=False)
    assert res.mission_complete and res.termination == "mission_complete"
    assert res.metrics["stalls"] >= 1 and res.metrics["skipped_path_m"] > 10.0
    assert len(res.stall_log) == res.metrics["stalls"] and {e["action"] for e in res.stall_log} == {"skipped"}
    path = save_run(res, tmp_path / "run.npz")
    assert load_run(path).stall_log == res.stall_log
    ctx = ReportContext(scenario="surface")
    text = markdown([res], ctx)
    assert "## Reference stalls" in text and text.count("| skipped |") == len(res.stall_log)
    # a stall that only the time limit's schedule finds: the point paces to the end, recorded as such
    probe = gym.make("WindTurbineInspection-v0", **env_options("surface", 0.0))
    nominal = probe.unwrapped.world.reference.ref.nominal_duration
    probe.close()
    res = evaluate_policy(lambda env: Hover(env), scenario="surface", wind=0.0, record=False,
                          env_overrides={"reference_stall_time": 1e4, "time_limit_s": nominal + 13.0})
    assert res.mission_complete and [e["action"] for e in res.stall_log] == ["paced"]
    assert res.stall_log[0]["why"].startswith("behind the schedule")
    assert {"stalls", "skipped_path_m"} <= set(CSV_COLUMNS)


def test_an_agent_that_observes_the_structure_gets_the_option_without_being_told():
    """A ``ppo:`` model whose features include the structure makes its runs' env observe it (the
    user's explicit setting wins); other controllers' runs are unchanged."""
    pytest.importorskip("stable_baselines3")
    from wt_inspect.evaluation import sweep_specs
    agent = "ppo:results/training/ppo_full_scratch_seeds/seed_2/best_model.zip"
    specs = sweep_specs("paper", [agent, "vtnmpc", "ppo:ppo_full_vec128"], [4.0], [0])
    opts = {s.controller: s.env_options for s in specs}
    assert opts[agent]["structure_observation"] is True
    assert "structure_observation" not in opts["vtnmpc"] and "structure_observation" not in opts["ppo:ppo_full_vec128"]
    told = sweep_specs("paper", [agent], [4.0], [0], env_overrides={"structure_observation": False})
    assert told[0].env_options["structure_observation"] is False
