"""Hardening, round two (issue 33): a report survives every signal, bounds on what a user can make
large, validation before work, one validation for every entry point.

The signal tests run the real command line in a subprocess whose driver sends the signal to the
process itself at a chosen phase (before run ``k`` starts, while a figure is drawn, at the first
training step): the phase is exact, no sleep decides what was finished. Each asserts what a user
sees: exit code 130, one line naming the signal and no traceback, and results.md / results.csv
listing exactly the finished runs, marked "Incomplete: k of n".
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from wt_inspect.evaluation.report import read_csv

ROOT = Path(__file__).resolve().parents[1]

DRIVER = textwrap.dedent('''
    import os, signal, sys
    sig, phase, argv = getattr(signal, sys.argv[1]), sys.argv[2], sys.argv[3:]

    def kill():
        os.kill(os.getpid(), sig)

    if phase.startswith("run:"):            # the signal arrives as run / episode k is about to start
        k = int(phase[4:])
        if argv[0] == "campaign":
            import wt_inspect.commands.campaign.running as mod
            name = "run_episode"
        else:
            import wt_inspect.evaluation.backends as mod
            name = "execute"
        real, count = getattr(mod, name), [0]

        def wrapped(*a, **kw):
            if count[0] == k:
                kill()
            count[0] += 1
            return real(*a, **kw)
        setattr(mod, name, wrapped)
    elif phase == "figures":                # ... while the figures are drawn (after the first)
        import wt_inspect.evaluation.figures as fig
        real_distance = fig.distance

        def distance(*a, **kw):
            kill()
            return real_distance(*a, **kw)
        fig.distance = distance
    elif phase == "train":                  # ... at the first training step (long before a checkpoint)
        import agents.training as tr
        real_class = tr._callback_class

        def callback_class():
            base = real_class()

            class Killing(base):
                def _on_step(self):
                    kill()
                    return super()._on_step()
            return Killing
        tr._callback_class = callback_class
    from wt_inspect.cli import main
    sys.exit(main(argv))
''')


def _run(tmp_path: Path, sig: str, phase: str, argv: list[str], timeout: float = 240) -> subprocess.CompletedProcess:
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    # SIG_DFL: a test run from a background job inherits an ignored SIGINT, which Python keeps
    return subprocess.run([sys.executable, str(driver), sig, phase, *argv], capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=tmp_path,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _interrupted(proc: subprocess.CompletedProcess, sig: str) -> None:
    assert proc.returncode == 130, (proc.returncode, proc.stderr[-3000:])
    assert f"interrupted ({sig})" in proc.stderr, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]


EVALUATE = ["evaluate", "--scenario", "surface", "--controllers", "nmpc,pampc", "--winds", "0", "--max-time",
            "0.3", "--no-progress"]


@pytest.mark.parametrize("sig,k", [("SIGTERM", 1), ("SIGINT", 1), ("SIGTERM", 0), ("SIGINT", 0)])
def test_evaluate_jobs_1_interrupted_during_the_runs_writes_the_report(tmp_path, sig, k):
    out = tmp_path / "ev"
    proc = _run(tmp_path, sig, f"run:{k}", EVALUATE + ["--jobs", "1", "--no-figures", "--out", str(out)])
    _interrupted(proc, sig)
    runs = sorted(p.name for p in (out / "runs").glob("*.npz"))
    assert len(runs) == k
    assert sorted(r["run_file"] for r in read_csv(out / "results.csv")) == runs
    assert f"Incomplete: {k} of 2 runs finished" in (out / "results.md").read_text()
    assert not [p for p in out.rglob(".*") if p.is_file()]   # no temporary file left


def test_a_single_run_sweep_interrupted_by_sigterm_writes_the_report(tmp_path):
    out = tmp_path / "ev"   # one run: the in-process path whatever --jobs says
    proc = _run(tmp_path, "SIGTERM", "run:0", EVALUATE[:4] + ["nmpc"] + EVALUATE[5:] + ["--jobs", "2", "--no-figures",
                                                                                         "--out", str(out)])
    _interrupted(proc, "SIGTERM")
    assert "Incomplete: 0 of 1 runs finished" in (out / "results.md").read_text()
    assert read_csv(out / "results.csv") == []


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_signal_while_the_figures_are_drawn_still_writes_results_md(tmp_path, sig):
    out = tmp_path / "ev"
    proc = _run(tmp_path, sig, "figures", EVALUATE + ["--jobs", "1", "--out", str(out)])
    _interrupted(proc, sig)
    md = (out / "results.md").read_text()
    assert "Incomplete" not in md and "Figures: not all drawn" in md
    assert len(read_csv(out / "results.csv")) == 2
    assert not [p for p in out.rglob(".*") if p.is_file()]
    done = _run(tmp_path, sig, "none", EVALUATE + ["--jobs", "1", "--out", str(out)])   # resumes, draws them
    assert done.returncode == 0, done.stderr[-2000:]
    assert "(0 executed, 2 resumed)" in done.stdout and "Figures: not all drawn" not in (out / "results.md").read_text()


def test_campaign_jobs_1_sigterm_reports_k_of_n_incomplete(tmp_path):
    out = tmp_path / "c"
    proc = _run(tmp_path, "SIGTERM", "run:2", ["campaign", "--episodes", "3", "--controller", "nmpc", "--task",
                                                "surface", "--max-time", "0.3", "--max-offset", "0", "--jobs", "1",
                                                "--no-progress", "--no-figure", "--out", str(out)])
    _interrupted(proc, "SIGTERM")
    md = (out / "results.md").read_text()
    assert "2 of 3 episodes, incomplete" in md and "Incomplete: 2 of 3 episodes finished" in md
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["complete"] is False and doc["episodes_planned"] == 3 and len(doc["episodes"]) == 2
    assert len((out / "episodes.csv").read_text().strip().splitlines()) == 1 + 2


@pytest.mark.slow
def test_sigint_in_train_before_the_first_checkpoint_saves_one(tmp_path):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "t"
    proc = _run(tmp_path, "SIGINT", "train", ["train", "--algo", "ppo", "--task", "surface", "--timesteps", "100000",
                                               "--n-envs", "1", "--no-progress", "--out", str(out)])
    _interrupted(proc, "SIGINT")
    ckpts = sorted((out / "checkpoints").glob("ckpt_*.zip"))
    assert len(ckpts) == 1 and f"--resume {ckpts[0]}" in proc.stderr
    assert ckpts[0].with_suffix(".json").is_file()


def test_interrupts_deferred_holds_a_second_signal_until_the_report_is_written():
    from wt_inspect_env.util.interrupts import Terminated, interrupts_deferred, interrupts_raise
    # a suite started from a background job inherits an ignored SIGINT, which the helpers (rightly)
    # leave ignored; this test is about a live one
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    steps = []
    try:
        with interrupts_raise():
            with pytest.raises(Terminated):
                with interrupts_deferred():
                    os.kill(os.getpid(), signal.SIGTERM)
                    steps.append("written")   # not cut short
            with interrupts_deferred(raise_noted=False) as noted:
                os.kill(os.getpid(), signal.SIGINT)
            assert noted == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)
    assert steps == ["written"]


# --------------------------------------------------------------------------- run files with foreign metadata
def _rewrite_meta(path: Path, change) -> None:
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))
    meta = change(meta)
    np.savez_compressed(path, meta=np.array(json.dumps(meta)), **arrays)


def _spec_changed(key, value):
    def change(meta):
        meta["spec"][key] = value
        return meta
    return change


FOREIGN_META = {
    "an extra field": (lambda m: {**m, "colour": "red"}, "unknown metadata field 'colour'"),
    "a missing field": (lambda m: {k: v for k, v in m.items() if k != "steps"}, "metadata field 'steps' is missing"),
    "a list": (lambda m: [m], "its metadata is a list"),
    "no metrics": (lambda m: {k: v for k, v in m.items() if k != "metrics"}, "'metrics' is missing"),
    "metrics a list": (lambda m: {**m, "metrics": [1, 2]}, "metadata field 'metrics' is \\[1, 2\\]"),
    "an extra spec field": (_spec_changed("robot", 1), "unknown spec field 'robot'"),
    "a text wind": (_spec_changed("wind", "4"), "spec field 'wind' is '4'"),
}


@pytest.fixture(scope="module")
def run_file(tmp_path_factory) -> Path:
    from wt_inspect.evaluation.cli import main as evaluate_main
    out = tmp_path_factory.mktemp("ev")
    assert evaluate_main(["--scenario", "surface", "--controllers", "nmpc", "--winds", "0", "--max-time", "0.3",
                          "--no-progress", "--no-figures", "--jobs", "1", "--out", str(out)]) == 0
    (path,) = (out / "runs").glob("*.npz")
    return path


@pytest.mark.parametrize("case", sorted(FOREIGN_META))
def test_a_run_file_with_foreign_metadata_is_one_error_naming_the_file_and_field(run_file, tmp_path, case):
    from wt_inspect.evaluation.runner import load_run
    change, needle = FOREIGN_META[case]
    path = tmp_path / run_file.name
    path.write_bytes(run_file.read_bytes())
    _rewrite_meta(path, change)
    with pytest.raises(ValueError, match=needle) as err:
        load_run(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_evaluate_resumes_past_a_foreign_run_file_and_rescore_names_it(run_file, tmp_path, capsys):
    from wt_inspect.commands.rescore import main as rescore_main
    from wt_inspect.evaluation.cli import main as evaluate_main
    from wt_inspect.evaluation.runner import load_run
    out = tmp_path / "ev"
    (out / "runs").mkdir(parents=True)
    bad = out / "runs" / run_file.name
    bad.write_bytes(run_file.read_bytes())
    _rewrite_meta(bad, FOREIGN_META["an extra field"][0])
    assert rescore_main([str(bad), "--occlusion", "off"]) == 2   # rescore: the file the user named is refused
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and "'colour'" in err
    argv = ["--scenario", "surface", "--controllers", "nmpc", "--winds", "0", "--max-time", "0.3", "--no-progress",
            "--no-figures", "--jobs", "1", "--out", str(out)]
    assert evaluate_main(argv) == 0   # evaluate: reported, run again, replaced
    cap = capsys.readouterr()
    assert "(1 executed, 0 resumed)" in cap.out
    assert "warning:" in cap.err and str(bad) in cap.err and "'colour'" in cap.err and "Traceback" not in cap.err
    assert load_run(bad).spec.controller == "nmpc"
    assert "'colour'" in (out / "results.md").read_text()


# --------------------------------------------------------------------------- bounds and validation
@pytest.mark.parametrize("options,needle", [
    ({"start_offset": [1e308, 0, 0]}, r"start_offset must be at most 1000 m long.*1e\+308"),
    ({"start_noise": 1e300}, r"start_noise must be at most 100 m.*1e\+300"),
    ({"depth_far": 1e30}, r"depth_far must be at most 1000 m.*1e\+30"),
    ({"randomization": {"latency_steps": [10 ** 9, 10 ** 9]}}, r"latency_steps must be at most 1000 control steps"),
    ({"randomization": {"latency_steps": [0, 10 ** 20]}}, r"latency_steps must be at most 1000 control steps"),
    ({"turbine": {"blade": {"span": [0, 1], "chord": [1]}}}, r"blade twist_deg is missing"),
    ({"turbine": {"blade": {"span": [1, 2], "chord": [1], "twist_deg": [0, 0], "thickness": [1, 1]}}},
     r"blade chord must be a list of at least 2"),
    ({"turbine": {"blade": {"span": [1, 2, 3], "chord": [1, 1], "twist_deg": [0, 0, 0], "thickness": [1, 1, 1]}}},
     r"blade chord has 2 values but span has 3"),
])
def test_unbounded_or_malformed_options_are_refused_naming_the_field(options, needle):
    from wt_inspect_env.task.env_config import EnvConfig
    with pytest.raises(ValueError, match=needle):
        EnvConfig.from_kwargs(**options)


def test_the_start_bounds_hold_in_reset_options_and_the_vector_env():
    import gymnasium as gym

    from wt_inspect_env.vector import WindTurbineInspectionVectorEnv
    env = gym.make("WindTurbineInspection-v0", task="surface")
    try:
        for opts, needle in (({"start_offset": [1e308, 0, 0]}, "start_offset must be at most"),
                             ({"start_noise": 1e300}, "start_noise must be at most")):
            with pytest.raises(ValueError, match=needle):
                env.reset(seed=0, options=opts)
        obs, _ = env.reset(seed=0, options={"start_offset": [0.0, 0.0, 999.0]})   # at the bound: a finite start
        assert np.all(np.isfinite(obs["position"]))
    finally:
        env.close()
    for kw, needle in (({"start_offset": (1e308, 0, 0)}, "start_offset must be at most"),
                       ({"start_noise": 1e300}, "start_noise must be at most")):
        with pytest.raises(ValueError, match=needle):
            WindTurbineInspectionVectorEnv(num_envs=2, task="surface", **kw)


def test_depth_from_a_rounded_buffer_stays_inside_the_observation_space():
    from wt_inspect_env.scene.render import metric_depth
    buf = np.array([0.0, 0.5, 1.0 - 1e-7, 1.0, 1.0 + 1e-7, np.nextafter(np.float32(1), np.float32(2))], np.float32)
    for far in (50.0, 1000.0):
        d = metric_depth(buf, far)
        assert np.all(np.isfinite(d)) and np.all(d >= 0) and np.all(d <= far), d
        assert d[3] == pytest.approx(far) and d[-1] == pytest.approx(far)


def test_the_vector_env_refuses_text_in_an_object_array_as_the_single_env_does():
    import gymnasium as gym

    from wt_inspect_env.vector import WindTurbineInspectionVectorEnv
    single = gym.make("WindTurbineInspection-v0", task="surface")
    venv = WindTurbineInspectionVectorEnv(num_envs=2, task="surface")
    try:
        single.reset(seed=0)
        venv.reset(seed=0)
        row = np.array(["0", 0.0, 0.0, 0.0], dtype=object)
        with pytest.raises(ValueError, match=r"action must be a real numeric array.*'0'") as one:
            single.step(row)
        with pytest.raises(ValueError, match=r"actions must be a real numeric array.*'0'") as many:
            venv.step(np.stack([np.zeros(4, dtype=object), row]))
        assert "dtype object" in str(one.value) and "dtype object" in str(many.value)
        with pytest.raises(ValueError, match=r"actions must be a numeric array"):   # ragged: not numpy's message
            venv.step([[0.0, 0.0, 0.0, 0.0], [0.0]])
        venv.step(np.zeros((2, 4)))   # still usable
    finally:
        single.close()
        venv.close()


def test_campaign_episodes_are_bounded_before_any_work(tmp_path, capsys):
    from wt_inspect.commands.campaign import MAX_EPISODES
    from wt_inspect.commands.campaign import main as campaign_main
    out = tmp_path / "c"
    assert campaign_main(["--episodes", "1000000000000", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"episodes must be at most {MAX_EPISODES:,}" in err
    assert not out.exists()


# --------------------------------------------------------------------------- demos: validated before recording
@pytest.mark.parametrize("name,needle", [("../../../escape-v0", "no '/' or '..'"), ("noversion", "ending in a version"),
                                         ("a/b-v0", "no '/'"), ("", "--name")])
def test_demos_refuses_a_bad_dataset_name_before_recording(tmp_path, capsys, name, needle):
    pytest.importorskip("minari")
    from wt_inspect.demonstrations import main as demos_main
    out = tmp_path / "a" / "b" / "out"
    assert demos_main(["--out", str(out), "--name", name, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and "--name" in err
    assert not any(tmp_path.iterdir())   # nothing recorded, nothing created - inside --out or outside it


@pytest.mark.parametrize("kind", ["file", "unwritable"])
def test_demos_refuses_an_out_it_cannot_write_before_recording(tmp_path, capsys, kind):
    pytest.importorskip("minari")
    from wt_inspect.demonstrations import main as demos_main
    if kind == "file":
        out = tmp_path / "file.txt"
        out.write_text("x")
    else:
        if os.geteuid() == 0:
            pytest.skip("root writes into read-only directories")
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        out = ro / "out"
    try:
        assert demos_main(["--out", str(out), "--no-progress"]) == 2
    finally:
        if kind != "file":
            ro.chmod(0o700)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err and str(out) in err and "Traceback" not in err
    if kind == "file":
        assert out.read_text() == "x"
    else:
        assert not out.exists()


def test_demos_out_that_fails_to_be_created_is_one_line(tmp_path, capsys, monkeypatch):
    """What a read-only file system (or, for root, nothing else) does: mkdir raises PermissionError."""
    pytest.importorskip("minari")
    import pathlib

    from wt_inspect.demonstrations import main as demos_main

    def refuse(self, *a, **kw):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(pathlib.Path, "mkdir", refuse)
    out = tmp_path / "out"
    assert demos_main(["--out", str(out), "--no-progress", "--config", '{"episodes": 1, "full_missions": 0}']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err and "Permission denied" in err
    assert not out.exists()
