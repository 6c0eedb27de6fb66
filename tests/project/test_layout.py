"""The package layering: wt_inspect_env <- controllers, agents <- wt_inspect <- wt_inspect_px4, nothing upward;
inside wt_inspect_env, the subpackages' layering (:data:`ENV_LAYERS`) and no import cycle between modules.

Read from the sources (every ``import``/``from`` statement, at any depth, including the lazy ones
inside functions and those under ``TYPE_CHECKING``), so an upward import cannot hide behind a
function body.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
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
# What each part of wt_inspect_env may import from the package (besides itself): a subpackage, or a
# module at the top of the package (its stem). Bottom to top; a module outside this table fails
# test_every_env_module_has_a_layer, so a new module is placed deliberately.
_BELOW_TASK = {"util", "native", "turbine", "planner", "physics", "scene"}
ENV_LAYERS = {
    "util": set(),                                 # validation, atomic I/O, native cache, signals, Ray
    "native": {"util"},                            # the world's compiled per-step arithmetic
    "turbine": {"util"},                           # spec, mesh, blades, presets
    "planner": {"util", "turbine"},                # inspection path, clearance, proximity
    "physics": {"util", "native"},                 # airframe, model, rate loop, wind, flight core
    "scene": {"util"},                             # camera, texture, visuals, rendering
    "task": _BELOW_TASK,                           # options, spaces, mission, reference, metrics, hooks
    "world": _BELOW_TASK | {"task"},               # simulators and the inspection world
    "policy": _BELOW_TASK | {"task"},              # the controllers' interface
    "env": _BELOW_TASK | {"task", "world"},        # the Gymnasium environment
    "vector": _BELOW_TASK | {"task", "world", "env"},
    "__init__": set(),                             # names env/vector as entry-point strings only
}


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
        allowed = ALLOWED[package] | {package}
        for name in sorted((_imports(f) & project) - allowed):
            bad.append(f"{rel} imports {name}")
    assert not bad, "upward or sideways imports:\n" + "\n".join(bad)


def _env_modules() -> dict[str, tuple[Path, bool]]:
    """Dotted name -> (file, is a package) for every module of wt_inspect_env."""
    out = {}
    for f in sorted((ROOT / "wt_inspect_env").rglob("*.py")):
        parts = list(f.relative_to(ROOT).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    return out


def _env_imports(name: str, path: Path, is_pkg: bool, modules) -> set[str]:
    """The wt_inspect_env modules ``name`` imports (relative imports resolved; ``from pkg import
    mod`` counts as importing ``pkg.mod``), at any depth of the file."""
    def deepest(dotted: str) -> str | None:
        while dotted and dotted not in modules:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        else:
            continue
        out.update(t for t in map(deepest, (t for t in targets if t.startswith("wt_inspect_env"))) if t)
    out.discard(name)
    return out


def _layer(dotted: str) -> str:
    parts = dotted.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_env_module_has_a_layer():
    modules = _env_modules()
    missing = sorted(m for m in modules if _layer(m) not in ENV_LAYERS)
    assert not missing, f"modules outside ENV_LAYERS (place them in a subpackage or declare them): {missing}"


def test_env_subpackages_import_only_the_layers_below():
    modules = _env_modules()
    bad = []
    for name, (path, is_pkg) in modules.items():
        layer = _layer(name)
        allowed = ENV_LAYERS.get(layer, set()) | {layer}
        for target in sorted(_env_imports(name, path, is_pkg, modules)):
            if _layer(target) not in allowed:
                bad.append(f"{path.relative_to(ROOT)} ({layer}) imports {target} ({_layer(target)})")
    assert not bad, "imports against ENV_LAYERS:\n" + "\n".join(bad)


def test_env_layers_are_acyclic():
    """The declared table itself is a one-way order (a cycle in it would let modules cycle)."""
    seen: dict[str, int] = {}

    def visit(layer: str, stack: tuple[str, ...]) -> None:
        assert layer not in stack, f"ENV_LAYERS cycle: {' -> '.join(stack + (layer,))}"
        if seen.get(layer):
            return
        for below in ENV_LAYERS[layer]:
            visit(below, stack + (layer,))
        seen[layer] = 1

    for layer in ENV_LAYERS:
        visit(layer, ())


def test_no_import_cycle_between_env_modules():
    """No two modules of wt_inspect_env import each other, directly or through others - lazy and
    TYPE_CHECKING imports included (a cycle hidden in a function body still ties the modules)."""
    modules = _env_modules()
    graph = {name: _env_imports(name, path, is_pkg, modules) for name, (path, is_pkg) in modules.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def strongconnect(v: str) -> None:   # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                strongconnect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    assert not cycles, f"import cycles between modules: {cycles}"


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
    assert {"vtnmpc", "vtnmpc-plus", "vtnmpc-dob", "vtnmpc-later", "nmpc", "pampc", "ppo"} <= set(entries)
    assert all(isinstance(e, PolicyEntry) for e in entries.values())
    assert entries["ppo"].takes_argument and not entries["vtnmpc"].takes_argument
    roots = {p.name for p in registry.source_roots()}
    assert {"controllers", "agents"} <= roots


def test_code_fingerprint_covers_every_result_changing_source():
    from wt_inspect.evaluation.runner import code_sources
    names = {f.relative_to(ROOT).as_posix() for f in code_sources()}
    for must in ("wt_inspect_env/env.py", "controllers/rti/solver.py", "agents/policy.py", "agents/wrappers.py",
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


def _hover_entry():
    from stub_policies import Hover

    from wt_inspect_env.policy import PolicyEntry
    return PolicyEntry(Hover, "hover in place (a third-party registration in a test)", display_name="Hover")


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
