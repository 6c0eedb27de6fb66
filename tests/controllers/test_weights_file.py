"""Weights files: every MPC's LSQWeights as plain JSON, on the command line as ``NAME:weights=FILE``."""
from __future__ import annotations

import dataclasses
import json

import pytest

from controllers.authors_baselines import AuthorsNMPCWeights
from controllers.nmpc import NMPCWeights
from controllers.pampc import PAMPCWeights
from controllers.registration import load_entry_weights
from controllers.vtnmpc import VTNMPCConfig, VTNMPCWeights
from wt_inspect import cli
from wt_inspect.evaluation import registry


def _write(tmp_path, data, name="w.json"):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


@pytest.mark.parametrize("weights", [VTNMPCWeights.later_tuning(), NMPCWeights(position=(1.0, 2.0, 3.0)),
                                     PAMPCWeights(), AuthorsNMPCWeights(heading=12.5)])
def test_round_trip_through_a_file_gives_the_same_weights(tmp_path, weights):
    path = _write(tmp_path, weights.to_dict())
    assert type(weights).load(path) == weights
    # the file is plain JSON data: every value a number or a list of numbers
    assert all(isinstance(v, (float, list)) for v in json.loads(path.read_text()).values())


def test_missing_fields_keep_the_base_set(tmp_path):
    path = _write(tmp_path, {"heading": 99.0})
    w = load_entry_weights("vtnmpc-later", str(path))
    assert w == dataclasses.replace(VTNMPCWeights.later_tuning(), heading=99.0)
    assert load_entry_weights("vtnmpc", str(path)).distance == VTNMPCWeights().distance
    # the config accepts a path too (missing fields: the class's default set, the paper's)
    assert VTNMPCConfig(weights=str(path)).weights == VTNMPCWeights(heading=99.0)


BAD = [
    ({"foo": 1.0}, "unknown field 'foo'"),
    ({"x_star": [1.0, 2.0]}, "x_star must be a list of 5 numbers, got [1.0, 2.0]"),
    ({"x_star": 5.0}, "x_star must be a list of 5 numbers, got 5.0"),
    ({"heading": [1.0]}, "heading must be a number, got [1.0]"),
    ({"heading": -1.0}, "heading must be non-negative, got -1.0"),
    ('{"distance": NaN}', "distance must be finite, got nan"),
    ('{"roi": Infinity}', "roi must be finite, got inf"),
    ({"x_star": [1.0, 1.0, -2.0, 1.0, 1.0]}, "x_star[2] must be non-negative, got -2.0"),
    ({"heading": "80"}, "heading must be a number, got '80'"),
    ({"inputs": [1.0, "1", 1.0, 1.0]}, "inputs[1] must be a number, got '1'"),
    ({"terminal_factor": True}, "terminal_factor must be a number, got True"),
    ({"inputs": [0.0, 1.0, 1.0, 1.0]}, "inputs[0] must be positive"),
    ([1.0, 2.0], "must be a JSON object of weight fields, got list"),
    ("{not json", "not valid JSON"),
]


@pytest.mark.parametrize("data,message", BAD)
def test_bad_weights_file_is_one_line_naming_field_and_value(tmp_path, data, message):
    path = _write(tmp_path, data)
    with pytest.raises(ValueError) as exc:
        VTNMPCWeights.load(path)
    text = str(exc.value)
    assert message in text and str(path) in text and "\n" not in text


def test_missing_file_names_the_file(tmp_path):
    with pytest.raises(ValueError, match="cannot read"):
        VTNMPCWeights.load(tmp_path / "absent.json")


def test_registry_accepts_weights_argument_and_fingerprints_the_values(tmp_path):
    a = _write(tmp_path, {"heading": 100.0}, "a.json")
    b = _write(tmp_path, '{\n  "heading": 100\n}', "b.json")      # same values, other layout and name
    c = _write(tmp_path, {"heading": 101.0}, "c.json")
    roi = _write(tmp_path, {"roi": 1.0}, "roi.json")             # a VT-NMPC field the PAMPC does not have
    registry.check_controller(f"vtnmpc:weights={a}")
    assert "vtnmpc[:weights=FILE|damping=X|backoff=M[:...]]" in registry.valid_names()
    fp = registry.fingerprint
    assert fp(f"vtnmpc:weights={a}") == fp(f"vtnmpc:weights={b}") != fp(f"vtnmpc:weights={c}")
    assert fp(f"vtnmpc:weights={a}") != fp(f"nmpc:weights={a}") and fp("vtnmpc") == "vtnmpc"
    for name, msg in [(f"vtnmpc:heading={a}", "unknown MPC option 'heading'"),
                      ("vtnmpc:", "needs an argument"), (f"pampc:weights={roi}", "unknown field 'roi'")]:
        with pytest.raises(ValueError, match=msg):
            registry.check_controller(name)


def test_damping_argument_is_checked_named_and_fingerprinted(tmp_path):
    """``damping=X`` alone or after ``weights=FILE``: its value is part of the fingerprint (a
    resumed evaluation does not reuse an undamped run), the table names it, and a bad value or a
    repeated option is a one-line error naming it."""
    a = _write(tmp_path, {"heading": 100.0}, "a.json")
    fp = registry.fingerprint
    assert fp("vtnmpc:damping=1") == fp("vtnmpc:damping=1.0") != fp("vtnmpc:damping=0.5") != fp("vtnmpc")
    both = f"vtnmpc:weights={a}:damping=1"
    registry.check_controller(both)
    assert fp(both).startswith(fp(f"vtnmpc:weights={a}") + ":")
    assert registry.display_name(both) == "VT-NMPC (a, damping 1)"
    assert registry.display_name("nmpc:damping=1+filter") == "NMPC (damping 1) + filter"
    for name, msg in [("vtnmpc:damping=-1", "damping must be a finite number >= 0, got '-1'"),
                      ("vtnmpc:damping=nan", "damping must be a finite number >= 0"),
                      ("vtnmpc:damping=1:damping=2", "'damping' given twice"),
                      ("vtnmpc:damping", "part 'damping' is not OPTION=VALUE")]:
        with pytest.raises(ValueError, match=msg):
            registry.check_controller(name)


def test_damping_builds_the_controller_with_only_the_regularization_changed():
    import dataclasses

    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    env = gym.make("WindTurbineInspection-Surface-v0")
    try:
        plain = registry.resolve("nmpc")(env.unwrapped).config.solver
        damped = registry.resolve("nmpc:damping=0.25")(env.unwrapped).config.solver
        assert plain.regularization == 0.0 and damped.regularization == 0.25
        assert dataclasses.replace(damped, regularization=0.0) == plain
    finally:
        env.close()


def test_backoff_tightens_the_clearance_the_mpc_keeps_and_only_that():
    """``backoff=M`` sets ``clearance_backoff`` (the OCP keeps d_min + M: a tightened expert to
    imitate), is fingerprinted and named, and is refused by the authors' variants, which keep no
    clearance at all."""
    import dataclasses

    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    fp = registry.fingerprint
    assert fp("vtnmpc-plus:backoff=0.5") == fp("vtnmpc-plus:backoff=0.50") != fp("vtnmpc-plus:backoff=0.4")
    assert registry.display_name("vtnmpc-plus:backoff=0.5") == "VT-NMPC+ (backoff 0.5 m)"
    for name, msg in [("nmpc-authors:backoff=0.5", "needs the clearance constraint"),
                      ("pampc-authors:backoff=0.5", "needs the clearance constraint"),
                      ("vtnmpc:backoff=-0.1", "backoff must be a finite number >= 0, got '-0.1'")]:
        with pytest.raises(ValueError, match=msg):
            registry.check_controller(name)
    env = gym.make("WindTurbineInspection-v0", task="full")
    try:
        plain = registry.resolve("vtnmpc-plus")(env.unwrapped)
        tight = registry.resolve("vtnmpc-plus:backoff=0.5")(env.unwrapped)
        assert plain.clearance_active and tight.clearance_active
        assert plain.config.clearance_backoff == pytest.approx(7.0 / 70.0) and tight.config.clearance_backoff == 0.5
        assert dataclasses.replace(tight.config, clearance_backoff=plain.config.clearance_backoff) == plain.config
        with pytest.raises(ValueError, match="d_min \\+ clearance_backoff must be below d_ref"):
            registry.resolve("vtnmpc-plus:backoff=4")(env.unwrapped)
    finally:
        env.close()


def test_weights_file_builds_the_controller(tmp_path):
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the env ids
    path = _write(tmp_path, VTNMPCWeights(distance=55.0, inputs=(2.0, 2.0, 0.5, 0.05)).to_dict())
    env = gym.make("WindTurbineInspection-Surface-v0")
    try:
        policy = registry.resolve(f"vtnmpc:weights={path}")(env.unwrapped)
        assert policy.config.weights == VTNMPCWeights(distance=55.0, inputs=(2.0, 2.0, 0.5, 0.05))
        assert registry.resolve("vtnmpc")(env.unwrapped).config.weights == VTNMPCWeights()
    finally:
        env.close()


def test_evaluate_cli_refuses_a_bad_weights_file_before_writing(tmp_path, capsys):
    bad = _write(tmp_path, {"heading": "80"})
    out = tmp_path / "out"
    rc = cli.main(["evaluate", "--scenario", "surface", "--controllers", f"vtnmpc:weights={bad}",
                   "--winds", "4", "--max-time", "0.05", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "heading must be a number, got '80'" in err and len(err.splitlines()) == 1
    assert not out.exists()
