"""The tutorials in examples/ run as a user would run them (from another directory, in a fresh
interpreter) and print what their docstrings promise; the docs include them verbatim."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from wt_inspect.evaluation.config import load_config

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
EXPECTED = {   # script -> lines its output must contain
    "01_make_env_and_step.py": ["observation keys: position(3,)", "reward terms of the last step:", "metrics so far:"],
    "02_run_vtnmpc.py": ["VT-NMPC (the paper's form)", "VT-NMPC+", "SM 1.000"],
    "03_evaluate_shipped_agent.py": ["shipped agents: ", "harness, 3 s", "model input: (27,)", "bare model, 3.0 s"],
}


def test_every_example_is_tested_and_in_the_docs():
    scripts = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert scripts == sorted(EXPECTED)
    tutorials = (ROOT / "docs" / "tutorials.md").read_text()
    for name in scripts:
        assert f'--8<-- "examples/{name}"' in tutorials, name
    load_config(EXAMPLES / "paper.toml")      # the example sweep file parses


@pytest.mark.slow
@pytest.mark.parametrize("script", sorted(EXPECTED))
def test_example_runs_from_another_directory(script, tmp_path):
    if script.startswith("03"):
        pytest.importorskip("stable_baselines3")
    env = {**os.environ, "MPLBACKEND": "Agg"}
    res = subprocess.run([sys.executable, str(EXAMPLES / script)], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    for line in EXPECTED[script]:
        assert line in res.stdout, (line, res.stdout)
    assert list(tmp_path.iterdir()) == []      # a tutorial writes nothing where it is run
