"""The package layering: wt_inspect_env <- controllers, agents <- wt_inspect <- wt_inspect_px4, nothing upward.

Read from the sources (every ``import``/``from`` statement, at any depth, including the lazy ones
inside functions), so an upward import cannot hide behind a function body.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# what each package may import from this project (besides itself)
ALLOWED = {
    "wt_inspect_env": set(),
    "controllers": {"wt_inspect_env"},
    "agents": {"wt_inspect_env"},
    "wt_inspect": {"wt_inspect_env", "controllers", "agents"},
    # the PX4 / MAVLink bridge sits above everything; the dispatcher (wt_inspect/cli.py) names
    # its modules only as strings, so no package below imports it
    "wt_inspect_px4": {"wt_inspect_env", "controllers", "agents", "wt_inspect"},
}
# Transitional, documented in the module itself: the old dispatcher path, kept while work started
# against it is re-pointed to wt_inspect.cli. Delete the shim and this entry together.
SHIMS = {"wt_inspect_env/cli.py": {"wt_inspect"}}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_no_package_imports_upward(package):
    project = set(ALLOWED)
    bad = []
    for f in sorted((ROOT / package).rglob("*.py")):
        rel = f.relative_to(ROOT).as_posix()
        allowed = ALLOWED[package] | SHIMS.get(rel, set()) | {package}
        for name in sorted((_imports(f) & project) - allowed):
            bad.append(f"{rel} imports {name}")
    assert not bad, "upward or sideways imports:\n" + "\n".join(bad)


def test_nothing_imports_the_px4_bridge_and_it_is_packaged():
    """No module below the bridge imports it (the check above, spelled out for the new top), and
    pyproject packages it with its optional dependency in the ``px4`` extra."""
    import tomllib
    below = [p for p in ALLOWED if p != "wt_inspect_px4"]
    bad = [f"{f.relative_to(ROOT)}" for pkg in below for f in sorted((ROOT / pkg).rglob("*.py"))
           if "wt_inspect_px4" in _imports(f)]
    assert not bad, bad
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "wt_inspect_px4*" in meta["tool"]["setuptools"]["packages"]["find"]["include"]
    assert any(d.startswith("pymavlink") for d in meta["project"]["optional-dependencies"]["px4"])
    assert "pymavlink" not in " ".join(meta["project"]["dependencies"])


def test_registry_finds_every_policy_through_entry_points():
    from wt_inspect.evaluation import registry
    from wt_inspect_env.policy import PolicyEntry
    entries = registry.entries()
    assert {"vtnmpc", "vtnmpc-plus", "vtnmpc-dob", "vtnmpc-later", "nmpc", "pampc", "ppo", "sac"} <= set(entries)
    assert all(isinstance(e, PolicyEntry) for e in entries.values())
    assert entries["ppo"].takes_argument and not entries["vtnmpc"].takes_argument
    roots = {p.name for p in registry.source_roots()}
    assert {"controllers", "agents"} <= roots


def test_code_fingerprint_covers_every_result_changing_source():
    from wt_inspect.evaluation.runner import code_sources
    names = {f.relative_to(ROOT).as_posix() for f in code_sources()}
    for must in ("wt_inspect_env/env.py", "controllers/rti.py", "agents/policy.py", "agents/wrappers.py",
                 "wt_inspect/evaluation/runner.py", "wt_inspect/evaluation/scenarios.py"):
        assert must in names
    assert "wt_inspect/evaluation/report.py" not in names   # presentation only


def test_policy_entry_rejects_bad_input():
    from wt_inspect_env.policy import PolicyEntry
    with pytest.raises(ValueError, match="factory"):
        PolicyEntry(factory=None, description="x")
    with pytest.raises(ValueError, match="description"):
        PolicyEntry(factory=lambda env: None, description="")


def test_every_registered_controller_builds_and_flies_a_step():
    """Each plain name builds its policy from the environment and returns a valid action (the
    ``vtnmpc-later`` entry once named a weight set that did not exist)."""
    import gymnasium as gym
    import numpy as np

    import wt_inspect_env  # noqa: F401 - registers the env ids
    from wt_inspect.evaluation import registry
    env = gym.make("WindTurbineInspection-Surface-v0")
    try:
        obs, _ = env.reset(seed=0)
        for name, entry in registry.entries().items():
            if entry.takes_argument:
                continue
            policy = registry.resolve(name)(env.unwrapped)
            policy.reset(seed=0)
            action = policy.act(obs)
            assert action.shape == (4,) and np.all(np.abs(action) <= 1.0), name
            assert not policy.last_stats.fallback, name
    finally:
        env.close()


class _Hover:
    """A third-party policy: hover thrust, zero rates (the interface, nothing else)."""

    def __init__(self, env) -> None:
        self.action = env.scaling.hover_action()

    def reset(self, seed=None) -> None:
        pass

    def act(self, obs):
        return self.action


def _hover_entry():
    from wt_inspect_env.policy import PolicyEntry
    return PolicyEntry(_Hover, "hover in place (a third-party registration in a test)", display_name="Hover")


HOVER_ENTRY = _hover_entry()


@pytest.fixture
def patched_registry(monkeypatch):
    """The registry with extra entry points (as another installed package would add them)."""
    from wt_inspect.evaluation import registry
    real = registry.entry_points
    extra: list = []
    monkeypatch.setattr(registry, "entry_points", lambda group: list(real(group=group)) + extra)
    registry._entry_points.cache_clear()
    registry._load.cache_clear()
    yield registry, extra
    registry._entry_points.cache_clear()
    registry._load.cache_clear()


def test_a_third_party_controller_plugs_in_through_an_entry_point(patched_registry):
    from importlib.metadata import EntryPoint

    from wt_inspect.evaluation import evaluate_policy
    from wt_inspect_env.policy import ENTRY_POINT_GROUP
    registry, extra = patched_registry
    extra.append(EntryPoint("hover-test", "test_layout:HOVER_ENTRY", ENTRY_POINT_GROUP))
    res = evaluate_policy("hover-test", scenario="surface", wind=0.0, max_time=0.2)
    assert res.steps == 20 and res.spec.controller_id == "hover-test"
    assert registry.display_name("hover-test") == "Hover" and "hover-test" in registry.valid_names()
    # a name claimed by two packages with different targets is refused, naming both
    extra.append(EntryPoint("vtnmpc", "test_layout:HOVER_ENTRY", ENTRY_POINT_GROUP))
    registry._entry_points.cache_clear()
    with pytest.raises(ValueError, match="registered twice"):
        registry.check_controller("vtnmpc")
