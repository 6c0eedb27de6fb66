"""The ``wt-inspect`` command line beyond single commands: --version, evaluate --config (TOML) and
--figure-format, and the plan figure's readability."""
from __future__ import annotations

import importlib.metadata
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from wt_inspect.cli import main
from wt_inspect.evaluation.cli import build_parser, resolve
from wt_inspect.evaluation.config import KINDS, EvaluateConfig, load_config

ROOT = Path(__file__).resolve().parents[2]
PAPER_TOML = ROOT / "examples" / "paper.toml"


def _pyproject_version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_version_is_the_installed_metadata_which_is_the_pyproject_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"wt-inspect {importlib.metadata.version('wt-inspect')}"
    assert out == f"wt-inspect {_pyproject_version()}"


def test_version_through_the_console_script():
    exe = Path(sys.executable).with_name("wt-inspect")
    res = subprocess.run([str(exe), "--version"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"wt-inspect {_pyproject_version()}"


def _resolve(argv: list[str]) -> EvaluateConfig:
    return resolve(build_parser("wt-inspect evaluate").parse_args(argv))


def test_example_config_is_the_paper_sweep_of_results_paper():
    """examples/paper.toml asks for exactly the sweep whose results are committed in results/paper
    (the command recorded in its results.md), apart from where it writes, how it reports and how many
    runs it flies at once."""
    line = next(ln for ln in (ROOT / "results" / "paper" / "results.md").read_text().splitlines()
                if ln.startswith("- Command: `"))
    argv = shlex.split(line.split("`")[1])[2:]
    from_flags = _resolve(argv)
    from_file = _resolve(["--config", str(PAPER_TOML)])
    ignore = {"out", "rerun", "progress", "jobs"}   # how many runs in parallel changes no result
    for key in KINDS:
        if key not in ignore:
            assert getattr(from_file, key) == getattr(from_flags, key), key
    assert from_file.out == "out/paper"
    # the file names every option (commented-out ones have no fixed default)
    text = PAPER_TOML.read_text()
    for key in KINDS:
        assert f"{key} =" in text or f"[{key}]" in text, key


def test_flags_override_the_config_file_and_the_rest_is_kept():
    cfg = _resolve(["--config", str(PAPER_TOML), "--winds", "4", "--out", "elsewhere", "--no-figures",
                    "--figure-format", "svg"])
    assert cfg.winds == (4.0,) and cfg.out == "elsewhere" and cfg.figures is False and cfg.figure_format == "svg"
    assert cfg.controllers == ("vtnmpc", "nmpc", "pampc", "vtnmpc-dob", "vtnmpc-plus")
    assert cfg.scenario == "paper" and cfg.seeds == (0,)
    assert _resolve(["--config", str(PAPER_TOML)]).winds == (0.0, 4.0, 7.0)
    assert _resolve(["--out", "x"]) == EvaluateConfig(out="x")     # no file: the defaults


def test_equivalent_command_reproduces_the_config():
    cfg = load_config(PAPER_TOML).merged({"turbine": {"blade_length": 40.0}, "max_time": 5.0, "progress": False})
    argv = shlex.split(cfg.command())[2:]
    assert _resolve(argv) == cfg


@pytest.mark.parametrize("body, key", [
    ('scenario = "paper"\nwind = 4\n', "'wind'"),                 # unknown key (misspelt)
    ('winds = "0,4,7"\n', "'winds'"),                             # a string, not an array
    ('winds = [0, "4"]\n', "'winds'"),
    ('seeds = [0.5]\n', "'seeds'"),
    ('jobs = true\n', "'jobs'"),
    ('controllers = "vtnmpc"\n', "'controllers'"),
    ('figures = "no"\n', "'figures'"),
    ('turbine = 40\n', "'turbine'"),
    ('controllers = []\n', "'controllers'"),
    ('winds = [0, 4\n', "not valid TOML"),
])
def test_bad_config_is_one_line_naming_the_key_exit_2_and_nothing_written(tmp_path, capsys, body, key):
    cfg = tmp_path / "sweep.toml"
    cfg.write_text(body + f'out = "{tmp_path / "out"}"\n' if "TOML" not in key else body)
    assert main(["evaluate", "--config", str(cfg), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and key in err and "sweep.toml" in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_bad_values_in_the_config_are_named_too(tmp_path, capsys):
    cfg = tmp_path / "sweep.toml"
    cfg.write_text('figure_format = "jpg"\nscenario = "surface"\n')
    assert main(["evaluate", "--config", str(cfg), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "figure_format" in err and "'jpg'" in err
    assert main(["evaluate", "--config", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "out")]) == 2
    assert "missing.toml" in capsys.readouterr().err
    cfg.write_text('scenario = "surface"\n')
    assert main(["evaluate", "--config", str(cfg)]) == 2          # out neither in the file nor given
    assert "out is required" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_figure_format_flag_refuses_unknown_formats(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--out", str(tmp_path / "o"), "--figure-format", "jpg"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["plan", "--out", str(tmp_path / "p"), "--figure-format", "gif"])
    assert exc.value.code == 2
    assert not (tmp_path / "o").exists() and not (tmp_path / "p").exists()


@pytest.mark.slow
def test_evaluate_from_a_config_writes_svg_figures_and_the_equivalent_command(tmp_path, capsys):
    cfg = tmp_path / "quick.toml"
    cfg.write_text('scenario = "surface"\ncontrollers = ["vtnmpc-plus"]\nwinds = [4]\nmax_time = 0.5\n'
                   'figure_format = "svg"\nprogress = false\njobs = 1\n'
                   f'out = "{tmp_path / "from_file"}"\n')
    out = tmp_path / "from_flag"     # the flag wins over the file's out
    assert main(["evaluate", "--config", str(cfg), "--out", str(out)]) == 0
    assert not (tmp_path / "from_file").exists()
    figures = sorted(p.name for p in out.iterdir() if p.suffix in {".png", ".pdf", ".svg"})
    assert figures == ["centering_w4.svg", "coverage_w4.svg", "distance_w4.svg", "energy_w4.svg",
                       "trajectories_w4.svg"]
    assert (out / "trajectories_w4.svg").read_text().lstrip().startswith("<?xml")
    md = (out / "results.md").read_text()
    assert (f"`wt-inspect evaluate --scenario surface --controllers vtnmpc-plus --winds 4 --out {out} --jobs 1 "
            "--max-time 0.5 --figure-format svg --no-progress`") in md


def _overlaps(boxes) -> list[tuple[int, int]]:
    return [(i, j) for i in range(len(boxes)) for j in range(i + 1, len(boxes)) if boxes[i].overlaps(boxes[j])]


@pytest.mark.slow
def test_plan_figure_labels_do_not_overlap_and_it_has_a_legend_of_every_surface(tmp_path):
    from wt_inspect_env.planner import plan_inspection
    from wt_inspect_env.planner.plot import plan_figure, save_plan_figure
    from wt_inspect_env.turbine.mesh import build_turbine
    from wt_inspect_env.turbine.spec import TurbineSpec

    plan = plan_inspection(build_turbine(TurbineSpec()))
    fig = plan_figure(plan)
    renderer = fig.canvas.get_renderer()
    fig.canvas.draw()
    for ax in fig.axes:
        boxes = [t.get_bbox_patch().get_window_extent(renderer) for t in ax.texts]
        assert len(boxes) == sum(1 for t in plan.tour if t.phase == fig.axes.index(ax) + 1)
        assert _overlaps(boxes) == [], [ax.texts[i].get_text() for pair in _overlaps(boxes) for i in pair]
    (legend,) = fig.legends
    labels = [t.get_text() for t in legend.get_texts()]
    assert len(labels) == plan.n_surfaces + 3
    assert {int(s.split("surface ")[1].split()[0]) for s in labels[:plan.n_surfaces]} == set(range(plan.n_surfaces))
    pdf = save_plan_figure(plan, tmp_path / "plan.png", "pdf")
    assert pdf == tmp_path / "plan.pdf" and pdf.read_bytes().startswith(b"%PDF")
    assert not (tmp_path / "plan.png").exists()


def test_train_figures_in_every_format(tmp_path, capsys):
    """The training figures (learning curve, curves over seeds) honour --figure-format too."""
    import json

    from agents.curves import plot_learning_curve
    from agents.seeds import plot_seed_curves

    evals = [{"env_steps": s, "wall_time_s": s / 1000, "mean": {"coverage": c, "safety_sm": c, "centering_cm": 0.99},
              "score": c} for s, c in ((1000, 0.2), (2000, 0.6), (3000, 0.95))]
    for seed in (0, 1):
        run = tmp_path / f"seed_{seed}"
        run.mkdir()
        (run / "evaluations.json").write_text(json.dumps(evals))
        (run / "episodes.csv").write_text("env_steps,return,safety_sm\n500,1.0,0.5\n1500,2.0,0.7\n2500,3.0,0.9\n")
    svg = plot_learning_curve(tmp_path / "seed_0", tmp_path / "seed_0" / "learning_curve.png", fmt="svg")
    assert svg.name == "learning_curve.svg" and svg.read_text().lstrip().startswith("<?xml")
    pdf = plot_seed_curves(tmp_path, [0, 1], tmp_path / "learning_curves_seeds.png", "pdf")
    assert pdf.name == "learning_curves_seeds.pdf" and pdf.read_bytes().startswith(b"%PDF")
    assert not list(tmp_path.glob("*.png"))
    with pytest.raises(SystemExit) as exc:
        main(["train", "--algo", "ppo", "--timesteps", "10", "--out", str(tmp_path / "t"), "--figure-format", "gif"])
    assert exc.value.code == 2 and not (tmp_path / "t").exists()


def test_ablation_figure_in_every_format_and_the_flag_is_checked(tmp_path, capsys):
    from wt_inspect import ablation

    cell = {"coverage": 0.9, "safety": 0.8, "centering": 0.99, "min_distance": 6.0}
    doc = {"scenario": "paper-faithful", "task": "surface", "winds": [4.0],
           "rows": [{"key": k, "cells": {f"{c}@4": dict(cell) for c in ablation.COLUMNS}} for k in ("a", "b")]}
    svg = ablation.figure(doc, tmp_path / "ablation.png", "svg")
    assert svg == tmp_path / "ablation.svg" and svg.read_text().lstrip().startswith("<?xml")
    with pytest.raises(SystemExit) as exc:
        main(["ablation", "--out", str(tmp_path / "o"), "--figure-format", "tiff"])
    assert exc.value.code == 2 and not (tmp_path / "o").exists()


def test_the_package_version_is_the_clis():
    """One version, written once (pyproject.toml), read from the metadata by both."""
    import wt_inspect_env
    from wt_inspect.cli import version
    assert wt_inspect_env.__version__ == version() != "unknown"
