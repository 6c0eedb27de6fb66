"""wt_inspect_env: the world of the wind-turbine inspection testbed.

Turbine model and inspection planner, quadrotor parameters and model, wind, PyBullet simulation,
camera coverage, inspection reference, metrics, and the Gymnasium environments registered below.
Importing this package registers the environment ids with Gymnasium.
"""
from __future__ import annotations

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _dist_version

from gymnasium.envs.registration import register, registry

try:   # one version, written once in pyproject.toml; the CLI reads the same metadata
    __version__ = _dist_version("wt-inspect")
except PackageNotFoundError:   # a checkout that was never installed
    __version__ = "unknown"

ENV_IDS = {
    "WindTurbineInspection-v0": "full",
    "WindTurbineInspection-Blade-v0": "blade",
    "WindTurbineInspection-Surface-v0": "surface",
}

for _env_id, _task in ENV_IDS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point="wt_inspect_env.env:WindTurbineInspectionEnv",
                 vector_entry_point="wt_inspect_env.vector:WindTurbineInspectionVectorEnv",
                 kwargs={"task": _task})
