"""Controller names -> policy factories, so runs are described by plain strings.

A factory takes the (unwrapped) environment and returns a policy with the common interface
(``reset(seed=None)``, ``act(obs)``; see :mod:`controllers.policy`). Building the policy *from
the environment* keeps the MPC's model parameters, stand-off, action scaling, control period and
camera identical to the simulated ones whatever the scenario (a 1.09 kg lab drone with
d_ref = 0.5 m gets a matching MPC without any extra option).

Names:

* ``vtnmpc`` - the paper's VT-NMPC with the paper's weights (no disturbance observer, as in the
  paper); ``vtnmpc-later`` - the authors' later tuning file; ``vtnmpc-dob`` - the paper's weights
  plus the optional disturbance observer of :class:`~controllers.vtnmpc.VTNMPCConfig`;
  ``vtnmpc-plus`` - VT-NMPC+ (:data:`~controllers.vtnmpc.VTNMPC_PLUS`): the observer, the gimbal
  camera's heading and the chord heading residual (not in the paper; the wind-robust variant).
* ``nmpc`` - the conventional NMPC baseline; ``pampc`` - the perception-aware MPC baseline (its
  projection guard ``image_plane_guard`` is scaled with d_ref, 0.5 m at the paper's 7 m, so the
  guard distorts the projection by the same relative amount in the lab scenario).
* ``ppo:PATH`` / ``sac:PATH`` (any ``algo:PATH``) - a saved stable-baselines3 model, loaded through
  ``agents.policy.load_sb3_policy(algo, path, env)`` (imported only when used).
"""
from __future__ import annotations

import hashlib
import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

PolicyFactory = Callable[[Any], Any]
SB3_ALGOS = ("ppo", "sac", "td3", "a2c", "ddpg")

# Names as the paper's tables print them (keys without an entry print as they are).
DISPLAY_NAMES = {"vtnmpc": "VT-NMPC", "vtnmpc-later": "VT-NMPC (later tuning)",
                 "vtnmpc-dob": "VT-NMPC + observer",
                 "vtnmpc-plus": "VT-NMPC+", "nmpc": "NMPC", "pampc": "PAMPC"}


def _vtnmpc(env: Any, **extra: Any) -> Any:
    from controllers.vtnmpc import VTNMPCPolicy
    return VTNMPCPolicy(params=env.params, d_ref=env.config.standoff, dt=env.dt, **extra)


def _vtnmpc_plus(env: Any) -> Any:
    from controllers.vtnmpc import VTNMPC_PLUS
    return _vtnmpc(env, **VTNMPC_PLUS)


def _nmpc(env: Any) -> Any:
    from controllers.nmpc import NMPCPolicy
    return NMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt)


def _pampc(env: Any) -> Any:
    from controllers.pampc import PAMPCConfig, PAMPCPolicy
    guard = PAMPCConfig.image_plane_guard * env.config.standoff / 7.0
    return PAMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt,
                       camera=env.config.camera, image_plane_guard=guard)


@dataclass(frozen=True)
class ControllerEntry:
    """One registered controller."""

    name: str
    factory: PolicyFactory
    description: str


CONTROLLERS: dict[str, ControllerEntry] = {e.name: e for e in (
    ControllerEntry("vtnmpc", _vtnmpc, "the paper's VT-NMPC, paper weights"),
    ControllerEntry("vtnmpc-later", lambda env: _vtnmpc(env, weights="later"),
                    "VT-NMPC with the authors' later tuning file"),
    ControllerEntry("vtnmpc-dob", lambda env: _vtnmpc(env, disturbance_observer=True),
                    "VT-NMPC, paper weights + disturbance observer (not in the paper)"),
    ControllerEntry("vtnmpc-plus", _vtnmpc_plus,
                    "VT-NMPC+: observer + gimbal-camera heading + chord heading residual (not in the paper)"),
    ControllerEntry("nmpc", _nmpc, "conventional NMPC baseline (stand-off position + yaw tracking)"),
    ControllerEntry("pampc", _pampc, "perception-aware MPC baseline (Falanga et al. 2018)"),
)}


def valid_names() -> str:
    """The names accepted by :func:`resolve`, for error messages and ``--help``."""
    return ", ".join(CONTROLLERS) + ", or a saved stable-baselines3 model as " + \
        ", ".join(f"{a}:PATH.zip" for a in ("ppo", "sac"))


def parse_sb3(name: str) -> tuple[str, str] | None:
    """``("ppo", "path.zip")`` for ``"ppo:path.zip"``; None for a registry name."""
    algo, sep, path = name.partition(":")
    if not sep:
        return None
    if algo.lower() not in SB3_ALGOS:
        raise ValueError(f"unknown controller {name!r}: {algo!r} is not a stable-baselines3 algorithm "
                         f"({', '.join(SB3_ALGOS)}); valid: {valid_names()}")
    if not path:
        raise ValueError(f"controller {name!r} needs a model path after '{algo}:'")
    return algo.lower(), path


def check_controller(name: str) -> None:
    """``ValueError`` listing the valid names unless ``name`` resolves (cheap: nothing is built;
    a model file must exist)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"controller must be a non-empty name; valid: {valid_names()}")
    sb3 = parse_sb3(name)
    if sb3 is None:
        if name not in CONTROLLERS:
            raise ValueError(f"unknown controller {name!r}; valid: {valid_names()}")
        return
    if not Path(sb3[1]).is_file():
        raise ValueError(f"controller {name!r}: model file {sb3[1]!r} does not exist")


def fingerprint(name: str) -> str:
    """What identifies the controller's behaviour for resuming: the name, plus the content hash
    of a model file (a retrained ``ppo:model.zip`` must not reuse the old results)."""
    sb3 = parse_sb3(name)
    if sb3 is None:
        return name
    model = Path(sb3[1])
    h = hashlib.sha256(model.read_bytes())
    sidecar = model.with_suffix(".json")   # agents' normalisation statistics live beside the model
    if sidecar.is_file():
        h.update(sidecar.read_bytes())
    digest = h.hexdigest()[:16]
    return f"{sb3[0]}:sha256={digest}"


def load_sb3(algo: str, path: str, env: Any) -> Any:
    """Load a saved stable-baselines3 model as a policy via the agents package (lazy import)."""
    try:
        module = importlib.import_module("agents.policy")
    except ModuleNotFoundError as exc:
        if exc.name in ("agents", "agents.policy"):
            raise ValueError(f"controller '{algo}:{path}' needs agents.policy.load_sb3_policy(algo, path, env), "
                             "which is not available in this installation (agents/policy.py is missing)") from None
        raise ValueError(f"controller '{algo}:{path}' needs the optional dependency {exc.name!r}; "
                         "install it with: pip install 'wt-inspect[rl]'") from None
    loader = getattr(module, "load_sb3_policy", None)
    if loader is None:
        raise ValueError("agents.policy has no load_sb3_policy(algo, path, env); cannot load "
                         f"'{algo}:{path}'")
    return loader(algo, path, env)


def resolve(name: str) -> PolicyFactory:
    """The factory ``env -> policy`` of a controller name (see the module docstring)."""
    check_controller(name)
    sb3 = parse_sb3(name)
    if sb3 is None:
        return CONTROLLERS[name].factory
    algo, path = sb3
    return lambda env: load_sb3(algo, path, env)


def display_name(name: str) -> str:
    """Table name: the paper's spelling for built-ins, ``PPO (model stem)`` for a saved model."""
    sb3 = parse_sb3(name)
    if sb3 is not None:
        return f"{sb3[0].upper()} ({Path(sb3[1]).stem})"
    return DISPLAY_NAMES.get(name, name)
