"""One-line errors, exit 2 and nothing half-written (issue 17): ``plan --out`` that cannot be
created or written (and never the mesh without the path), ``train --out`` an existing file,
``ppo:`` models and ``train`` without the ``rl`` extra, the output going read-only in the middle
of an evaluation, huge turbines; and a reused evaluation ``--out`` flags the stale files."""
from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest

from wt_inspect.commands import plan as plan_cmd
from wt_inspect.evaluation import OutputDirError, run_evaluation
from wt_inspect_env.planner.plan import InspectionPlan

SMALL = ["--blade-length", "20", "--blade-width", "2", "--tower-height", "40", "--mesh-step", "1.5", "--no-plot"]


def _cli(*args: str, no_sb3: bool = False) -> subprocess.CompletedProcess:
    """``wt-inspect ARGS`` in a subprocess; ``no_sb3``: as if the rl extra were not installed
    (``import stable_baselines3`` fails)."""
    pre = "import sys; sys.modules['stable_baselines3'] = None; " if no_sb3 else ""
    code = pre + "from wt_inspect.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", "import sys; " + code, *args], capture_output=True, text=True,
                          timeout=300)


def _one_line(proc: subprocess.CompletedProcess, *needles: str) -> str:
    lines = [ln for ln in proc.stderr.splitlines() if not ln.startswith("pybullet build time")]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def _main_one_line(main, argv: list[str], capsys, *needles: str) -> str:
    """``main(argv)`` in this process: exit 2 and one line on stderr containing ``needles``."""
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def test_plan_out_that_cannot_be_created(tmp_path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    _main_one_line(plan_cmd.main, ["--out", str(blocker / "sub"), *SMALL], capsys, "--out", "is not a directory")
    _main_one_line(plan_cmd.main, ["--out", str(blocker), *SMALL], capsys, "exists and is not a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_plan_out_read_only_dir(tmp_path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        _one_line(_cli("plan", "--out", str(ro / "plan"), *SMALL), "not writable")
        _one_line(_cli("plan", "--out", str(ro), *SMALL), "not writable")
    finally:
        ro.chmod(0o755)
    assert list(ro.iterdir()) == []


def test_plan_write_failure_leaves_no_file_of_the_set(tmp_path, monkeypatch, capsys) -> None:
    """The disk fills (or goes read-only) after the mesh was written: neither file is left,
    no temporary either, and the error is one line."""
    def full(self, path):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(InspectionPlan, "to_csv", full)
    out = tmp_path / "plan"
    assert plan_cmd.main(["--out", str(out), *SMALL]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"wt-inspect plan: error: cannot write --out {str(out)!r}: No space left on device"]
    assert list(out.iterdir()) == []


def test_plan_huge_turbine_is_a_size_error(tmp_path, capsys) -> None:
    out = tmp_path / "plan"
    _main_one_line(plan_cmd.main, ["--out", str(out), "--blade-length", "600", "--tower-height", "290"], capsys,
                   "blade_length must be at most 200 m", "600")
    assert not out.exists()


def test_train_out_existing_file(tmp_path, capsys) -> None:
    from agents.train_cli import main as train_main
    f = tmp_path / "model"
    f.write_text("x")
    _main_one_line(train_main, ["--algo", "ppo", "--task", "surface", "--timesteps", "10", "--out", str(f)], capsys,
                   "--out", "exists and is not a directory")
    assert f.read_text() == "x"


@pytest.mark.slow
def test_without_the_rl_extra(tmp_path) -> None:
    out = tmp_path / "ev"
    _one_line(_cli("evaluate", "--scenario", "surface", "--controllers", "ppo:ppo_surface", "--winds", "0",
                   "--out", str(out), no_sb3=True), "ppo:ppo_surface", "stable_baselines3", "wt-inspect[rl]")
    _one_line(_cli("train", "--algo", "ppo", "--task", "surface", "--timesteps", "10", "--out", str(tmp_path / "tr"),
                   no_sb3=True), "stable_baselines3", "wt-inspect[rl]")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_output_read_only_mid_evaluation(tmp_path, monkeypatch) -> None:
    """The first run file is written, then the disk refuses: one OutputDirError naming the file,
    the finished run kept (a rerun resumes it), no temporary left."""
    import wt_inspect.evaluation as ev
    real, calls = ev.save_run, []

    def flaky(result, path):
        calls.append(path)
        if len(calls) > 1:
            raise OSError(errno.EROFS, "Read-only file system")
        return real(result, path)
    monkeypatch.setattr(ev, "save_run", flaky)
    out = tmp_path / "ev"
    with pytest.raises(OutputDirError, match=r"cannot write run file .*Read-only file system; the 1 run\(s\)"):
        run_evaluation("surface", ["vtnmpc"], winds=[0.0], seeds=[0, 1], out=out, jobs=1, max_time=0.05,
                       figures=False, progress=False)
    assert len(list((out / "runs").glob("*.npz"))) == 1
    assert not list((out / "runs").glob(".*"))
    monkeypatch.setattr(ev, "save_run", real)
    again = run_evaluation("surface", ["vtnmpc"], winds=[0.0], seeds=[0, 1], out=out, jobs=1, max_time=0.05,
                           figures=False, progress=False)
    assert (again.n_resumed, again.n_ran) == (1, 1)


@pytest.mark.slow
def test_reused_out_flags_stale_files(tmp_path) -> None:
    out = tmp_path / "ev"
    first = run_evaluation("surface", ["vtnmpc"], winds=[0.0], out=out, jobs=1, max_time=0.05, figures=False,
                           progress=False)
    assert first.files["stale"] == []
    (out / "coverage_w9.png").write_bytes(b"old figure")
    second = run_evaluation("surface", ["nmpc"], winds=[0.0], out=out, jobs=1, max_time=0.05, figures=False,
                            progress=False)
    old_run = f"runs/{first.results[0].path.name}"
    assert second.files["stale"] == [old_run]          # figures are not judged when none were drawn
    md = (out / "results.md").read_text()
    assert "1 file(s)" in md and old_run in md and "not from this sweep" in md
    third = run_evaluation("surface", ["vtnmpc", "nmpc"], winds=[0.0], out=out, jobs=1, max_time=0.05,
                           figures=False, progress=False)
    assert third.files["stale"] == [] and "not from this sweep" not in (out / "results.md").read_text()


@pytest.mark.parametrize("argv", [
    ["evaluate", "--scenario", "surface", "--controllers", "vtnmpc", "--winds", "0", "--backend", "ray"],
    ["train", "--algo", "ppo", "--task", "surface", "--timesteps", "100", "--seeds", "0,1", "--ray"],
])
@pytest.mark.slow
def test_a_ray_address_nothing_answers_on_is_one_line_and_nothing_written(tmp_path, argv) -> None:
    pytest.importorskip("ray")
    out = tmp_path / "out"
    proc = _cli(*argv, "--address", "127.0.0.1:1", "--out", str(out))
    _one_line(proc, "address '127.0.0.1:1'", "nothing answers there")
    assert not out.exists()


def test_ray_backend_without_ray_is_one_error_and_nothing_written(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)     # `import ray` now fails as when it is not installed
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"needs Ray.*wt-inspect\[ray\]"):
        run_evaluation("surface", ["nmpc"], winds=[0.0], out=out, backend="ray", jobs=1, max_time=0.05,
                       figures=False, progress=False)
    assert not out.exists()
