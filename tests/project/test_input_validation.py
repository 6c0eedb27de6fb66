"""Validation before work, one validation for every entry point: run files with foreign metadata are
one error naming the file and field, options a user can make unbounded or malformed are refused
naming the field (the env, reset options and the vector env alike), and campaign and demos inputs are
checked before anything flies or records."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest


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
