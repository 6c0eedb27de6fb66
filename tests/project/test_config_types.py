"""Strings, bools and complex numbers are refused in every numeric field of every configuration
dataclass at construction (issue 17): ``time_limit_s="5"`` used to pass validation and fail in
arithmetic many steps later. The fields are enumerated from the dataclasses themselves, so a new
numeric field is covered without touching this test."""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the environment ids
from controllers.rti import RTIOptions
from controllers.vtnmpc import VTNMPCConfig
from wt_inspect_env.physics.quadrotor import get_preset
from wt_inspect_env.physics.rate_control import RateGains
from wt_inspect_env.physics.sim_config import SimConfig
from wt_inspect_env.planner.config import PlannerConfig
from wt_inspect_env.scene.camera import CameraConfig
from wt_inspect_env.task.env_config import EnvConfig, RewardConfig
from wt_inspect_env.task.metrics import MetricsConfig
from wt_inspect_env.task.reference import ReferenceConfig
from wt_inspect_env.task.spaces import ActionScaling
from wt_inspect_env.turbine.blade_geometry import BladeShape
from wt_inspect_env.turbine.loading import MeshLoadOptions
from wt_inspect_env.turbine.spec import TurbineSpec
from wt_inspect_env.util.validation import _field_kinds, check_array, check_finite


def _bases() -> list:
    params = get_preset("matrice100")
    return [EnvConfig(), RewardConfig(), CameraConfig(), TurbineSpec(), MeshLoadOptions(path="x.stl"),
            PlannerConfig(), params, RateGains(), SimConfig(), ReferenceConfig(),
            MetricsConfig(d_ref=7.0, safety_margin=1.0), ActionScaling(mass=params.mass),
            BladeShape(span=(1.0, 5.0, 10.0), chord=(1.0, 0.8, 0.5), twist_deg=(10.0, 5.0, 0.0),
                       thickness=(0.4, 0.3, 0.2)),
            VTNMPCConfig(params=params), VTNMPCConfig(params=params).weights, RTIOptions()]


def _cases() -> list:
    out = []
    for base in _bases():
        for name, kind in _field_kinds(type(base)):
            if kind == "bool":
                bad = [1, "true"]
            elif kind == "number":
                bad = ["5", True, 1 + 2j]
            else:
                good = getattr(base, name)
                n = len(good) if good is not None else 3
                bad = [("1",) * n, (True,) * n, "123"]
            out += [pytest.param(base, name, b, id=f"{type(base).__name__}.{name}={b!r}") for b in bad]
    return out


def test_the_enumeration_covers_the_reported_fields() -> None:
    kinds = dict(_field_kinds(EnvConfig))
    assert kinds["time_limit_s"] == "number" and kinds["standoff"] == "number"
    assert kinds["occlusion"] == "bool" and kinds["start_noise"] == "number"
    assert "task" not in kinds and "wind" not in kinds          # str / Any fields are not numbers
    assert dict(_field_kinds(CameraConfig))["mount_offset"] == "numbers"
    assert len(_cases()) > 150


@pytest.mark.parametrize("base,name,bad", _cases())
def test_wrong_kind_refused_naming_field_and_value(base, name, bad) -> None:
    with pytest.raises(ValueError) as exc:
        dataclasses.replace(base, **{name: bad})
    msg = str(exc.value)
    assert name in msg and repr(bad) in msg and "\n" not in msg


@pytest.mark.parametrize("value", ["5", True, np.bool_(True), 2 + 0j, b"1"])
def test_check_finite_refuses_non_numbers(value) -> None:
    with pytest.raises(ValueError, match="must be a finite number"):
        check_finite("x", value)
    assert check_finite("x", np.float32(2.5)) == 2.5 and check_finite("x", 3) == 3.0


@pytest.mark.parametrize("value", [np.array([1, 2j, 0]), ["1", "2", "3"], np.zeros(3, bool)])
def test_check_array_refuses_complex_text_bool(value) -> None:
    with pytest.raises(ValueError, match="real numeric array"):
        check_array("v", value, (3,))
    assert check_array("v", [1, 2.5, np.float32(3)], (3,)).tolist() == [1.0, 2.5, 3.0]


@pytest.mark.parametrize("kw", [{"time_limit_s": "5"}, {"standoff": "7"}, {"start_noise": True},
                                {"turbine": {"blade_length": "40"}}, {"camera": {"focal_length_mm": "20"}},
                                {"reward": {"crash": "1"}}, {"planner": {"clearance": "0.2"}}])
def test_gym_make_refuses_strings_for_numbers(kw) -> None:
    key, value = next(iter(kw.items()))
    if isinstance(value, dict):
        key, value = next(iter(value.items()))
    with pytest.raises(ValueError, match=f"{key} must be a number, got {value!r}"):
        gym.make("WindTurbineInspection-Surface-v0", **kw)


@pytest.mark.slow
def test_evaluate_cli_refuses_string_option_in_one_line(tmp_path) -> None:
    out = tmp_path / "ev"
    proc = subprocess.run([sys.executable, "-m", "wt_inspect.cli", "evaluate", "--scenario", "surface",
                           "--controllers", "vtnmpc", "--winds", "0", "--out", str(out),
                           "--env", json.dumps({"time_limit_s": "5"})], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["wt-inspect evaluate: error: time_limit_s must be a number, got '5'"]
    assert not out.exists()
