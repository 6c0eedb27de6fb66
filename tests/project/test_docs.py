"""The docs site's pages stay in step with the code they describe (the site itself is built with
``mkdocs build --strict`` in .ci/run; these checks need no MkDocs)."""
from __future__ import annotations

import dataclasses
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"


def _nav_pages() -> list[str]:
    return re.findall(r":\s*([\w/-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), flags=re.M)


def test_every_page_is_in_the_nav_and_exists():
    nav = _nav_pages()
    assert nav and all((DOCS / p).is_file() for p in nav), [p for p in nav if not (DOCS / p).is_file()]
    pages = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))
    assert sorted(nav) == pages


def test_api_reference_targets_exist():
    targets = [t for p in (DOCS / "api").glob("*.md") for t in re.findall(r"^::: ([\w.]+)", p.read_text(), re.M)]
    assert len(targets) >= 20
    for target in targets:
        parts = target.split(".")
        for i in range(len(parts), 0, -1):   # the longest importable prefix, then attributes
            try:
                obj = importlib.import_module(".".join(parts[:i]))
            except ModuleNotFoundError:
                continue
            for attr in parts[i:]:
                obj = getattr(obj, attr)
            break
        else:
            raise AssertionError(f"{target} does not exist")


def test_scenarios_page_names_every_scenario():
    from wt_inspect.evaluation.scenarios import SCENARIOS
    text = (DOCS / "scenarios.md").read_text()
    missing = [name for name in SCENARIOS if f"`{name}`" not in text]
    assert missing == []


def test_metrics_page_defines_every_reported_metric():
    from wt_inspect_env.task.metrics import InspectionMetrics
    text = (DOCS / "metrics.md").read_text()
    names = [f.name for f in dataclasses.fields(InspectionMetrics)
             if f.name not in {"n_samples", "n_inspecting", "n_triangles", "n_seen", "safety_margin_m", "coverage",
                               "safety_sm", "centering_cm", "centering_body_cm"}]
    assert [n for n in names if f"`{n}`" not in text] == []
    for heading in ("## Coverage", "## Safety metric SM", "## Centering metric CM"):
        assert heading in text


def test_cli_page_lists_every_config_key_and_the_reward_terms_are_documented():
    from wt_inspect.evaluation.config import KINDS
    from wt_inspect_env.task.step_terms import REWARD_TERMS
    cli = (DOCS / "cli.md").read_text()
    assert [k for k in KINDS if f"`{k}`" not in cli] == []
    env = (DOCS / "environment.md").read_text()
    assert [t for t in REWARD_TERMS if f"| `{t}` |" not in env] == []


# Names of files that are not in this repository (assembled, so this file does not contain them).
OUTSIDE = ("../" + "shared", "authors-code-" + "notes", "anchors" + ".md", "acados" + "_vt")


def _tracked_text_files() -> list[Path]:
    import subprocess
    res = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True)
    if res.returncode != 0:   # not a git checkout (an sdist): every file under the root
        return [p for p in ROOT.rglob("*") if p.is_file() and ".git" not in p.parts]
    return [ROOT / name for name in res.stdout.decode().split("\0") if name]


def test_no_file_cites_anything_outside_the_repository():
    bad = []
    for path in _tracked_text_files():
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):   # binary (figures, models) or gone
            continue
        bad += [f"{path.relative_to(ROOT)}: {name}" for name in OUTSIDE if name in text]
    assert bad == []


README = ROOT / "README.md"


def test_readme_is_a_short_door_and_its_test_command_is_ci_s():
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    ci = (ROOT / ".ci" / "run").read_text()
    marker = "# --- README test command (keep in sync with README \"Quick start\") ---\n"
    command = ci.split(marker, 1)[1].splitlines()[0]
    assert command.startswith("pip install torch==")
    assert f"```bash\n{command}\n```" in text


def test_readme_links_exist():
    missing = [t for t in re.findall(r"\]\(([^)#\s]+)", README.read_text())
               if "://" not in t and not (ROOT / t).exists()]
    assert missing == []


@pytest.mark.slow
def test_readme_python_example_runs_from_another_directory(tmp_path):
    import os
    import subprocess
    import sys
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks
    for code in blocks:
        res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                             timeout=300, env={**os.environ, "MPLBACKEND": "Agg"})
        assert res.returncode == 0, res.stderr[-2000:]
        coverage, sm, cm = (float(v) for v in res.stdout.split())
        assert 0.0 <= coverage <= 1.0 and sm > 0.9 and cm > 0.9
    assert list(tmp_path.iterdir()) == []
