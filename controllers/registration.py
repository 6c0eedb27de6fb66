"""The controllers this package registers with the evaluation harness and the command line.

Each name below is an entry point of the group ``wt_inspect.controllers`` (see ``pyproject.toml``),
whose value is a :class:`~wt_inspect_env.policy.PolicyEntry`; the harness loads them through
``importlib.metadata`` and so never imports this package by name. A factory builds its policy
*from the environment* so the MPC's model parameters, stand-off, control period and camera are the
simulated ones whatever the scenario (the 1.09 kg lab drone with d_ref = 0.5 m gets a matching
MPC without any option). The policy modules are imported inside the factories, so listing the
registry (``wt-inspect evaluate --help``) does not build CasADi functions.

* ``vtnmpc`` - the paper's VT-NMPC with the paper's weights (no disturbance observer, as in the
  paper); ``vtnmpc-later`` - the authors' later tuning file; ``vtnmpc-dob`` - the paper's weights
  plus the disturbance observer of :class:`~controllers.vtnmpc.VTNMPCConfig`; ``vtnmpc-plus`` -
  VT-NMPC+ (:data:`~controllers.vtnmpc.VTNMPC_PLUS`: the observer, the gimbal camera's heading and
  the chord heading residual; not in the paper, the wind-robust variant).
* ``nmpc`` - the conventional NMPC baseline; ``pampc`` - the perception-aware MPC baseline (its
  projection guard ``image_plane_guard`` is scaled with d_ref, 0.5 m at the paper's 7 m, so the
  guard distorts the projection by the same relative amount in the lab scenario).
* ``nmpc-authors`` / ``pampc-authors`` - the two baselines as the authors ran them, with their
  quaternion yaw reference and their camera axis (:mod:`controllers.authors_baselines`), for the
  ``paper-faithful`` scenario.

The MPC factories of ``vtnmpc*``, ``nmpc`` and ``pampc`` also hand the policy the mission's turbine
(``env.mission``: the collision mesh of each rotor position), so every one of them keeps the clearance
d_min (:mod:`controllers.rti_policy`); the ``*-authors`` variants reproduce the authors' runs and
do not.

Every MPC entry also takes an optional argument ``weights=FILE.json`` (``vtnmpc:weights=best.json``):
a weights file of the controller's :class:`~controllers.rti_policy.LSQWeights` class (plain JSON,
:meth:`~controllers.rti_policy.LSQWeights.load`; the fields it leaves out keep the entry's own set,
the later tuning for ``vtnmpc-later``), checked before any run and fingerprinted by its content, so
a changed file is a different run when an evaluation resumes. ``wt-inspect tune`` writes such files.

The VT-NMPC keeps its 0.01 s shooting interval at any control rate (``control_dt`` is the
environment's period), as the paper's 200 Hz loop ran a 30 x 0.01 s horizon.
"""
from __future__ import annotations

import hashlib
import json
from typing import Any, Callable

from wt_inspect_env.policy import PolicyEntry

WEIGHTS_ARGUMENT = "weights=FILE"


def _weights_class(kind: str) -> tuple[type, Any]:
    """(weights class, the entry's own set) of an MPC entry kind (imported lazily: listing the
    registry builds no CasADi function)."""
    if kind in {"vtnmpc", "vtnmpc-later"}:
        from .vtnmpc import WEIGHT_SETS, VTNMPCWeights
        return VTNMPCWeights, WEIGHT_SETS["later_tuning" if kind == "vtnmpc-later" else "paper"]
    if kind == "nmpc":
        from .nmpc import NMPCWeights
        return NMPCWeights, NMPCWeights.authors()
    if kind == "pampc":
        from .pampc import PAMPCWeights
        return PAMPCWeights, PAMPCWeights.authors()
    if kind == "nmpc-authors":
        from .authors_baselines import AUTHORS_NMPC_WEIGHTS, AuthorsNMPCWeights
        return AuthorsNMPCWeights, AUTHORS_NMPC_WEIGHTS["authors"]
    raise ValueError(f"no weights class for {kind!r}")   # pragma: no cover - a registration bug


def weights_path(arg: str) -> str:
    """The file of an MPC entry's argument ``weights=FILE``; one-line ValueError otherwise."""
    key, sep, path = arg.partition("=")
    if key.strip() != "weights" or not sep or not path:
        raise ValueError(f"argument must be {WEIGHTS_ARGUMENT}, got {arg!r}")
    return path


def load_entry_weights(kind: str, arg: str) -> Any:
    """The weights of ``weights=FILE`` for an MPC entry kind (missing fields: the entry's set)."""
    cls, base = _weights_class(kind)
    return cls.load(weights_path(arg), base=base)


def _weights_entry(kind: str, build: Callable[..., Any], description: str, display_name: str) -> PolicyEntry:
    """An MPC entry that works plain (its own weights) or with ``weights=FILE``."""
    def factory(env: Any, arg: str | None = None) -> Any:
        return build(env) if arg is None else build(env, weights=load_entry_weights(kind, arg))

    def check(arg: str) -> None:
        load_entry_weights(kind, arg)

    def fingerprint(arg: str) -> str:   # the weights' values, not the file's name or layout
        data = json.dumps(load_entry_weights(kind, arg).to_dict(), sort_keys=True)
        return "weights=" + hashlib.sha256(data.encode()).hexdigest()[:16]

    return PolicyEntry(factory, description, display_name=display_name,
                       check=check, fingerprint=fingerprint, optional_argument=WEIGHTS_ARGUMENT)


def _turbine(env: Any) -> Any:
    """The turbine the MPCs keep ``d_min`` from: the mission's collision mesh of every rotor
    position (the geometry the simulator collides the drone with)."""
    from wt_inspect_env.planner.proximity import TurbineProximity
    return TurbineProximity.from_env(env)


def _vtnmpc_policy(env: Any, **options: Any) -> Any:
    from .vtnmpc import VTNMPCPolicy
    return VTNMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, obstacles=_turbine(env),
                        **options)


def _vtnmpc_plus_policy(env: Any, **options: Any) -> Any:
    from .vtnmpc import VTNMPC_PLUS
    return _vtnmpc_policy(env, **VTNMPC_PLUS, **options)


def _nmpc_policy(env: Any, **options: Any) -> Any:
    from .nmpc import NMPCPolicy
    return NMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, obstacles=_turbine(env),
                      **options)


def _pampc_policy(env: Any, **options: Any) -> Any:
    from .pampc import PAMPCConfig, PAMPCPolicy
    guard = PAMPCConfig.image_plane_guard * env.config.standoff / 7.0
    return PAMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt,
                       camera=env.config.camera, image_plane_guard=guard, obstacles=_turbine(env), **options)


vtnmpc = _weights_entry("vtnmpc", _vtnmpc_policy, "the paper's VT-NMPC, paper weights", "VT-NMPC")
vtnmpc_later = _weights_entry("vtnmpc-later", lambda env, **o: _vtnmpc_policy(env, **({"weights": "later_tuning"} | o)),
                              "VT-NMPC with the authors' later tuning file", "VT-NMPC (later tuning)")
vtnmpc_dob = _weights_entry("vtnmpc", lambda env, **o: _vtnmpc_policy(env, disturbance_observer=True, **o),
                            "VT-NMPC, paper weights + disturbance observer (not in the paper)", "VT-NMPC + observer")
vtnmpc_dob_gimbal = _weights_entry(
    "vtnmpc", lambda env, **o: _vtnmpc_policy(env, disturbance_observer=True, heading_model="camera", **o),
    "VT-NMPC, paper weights + observer + gimbal-camera heading (VT-NMPC+ without the chord residual; an "
    "ablation step)", "VT-NMPC + observer + gimbal")
vtnmpc_plus = _weights_entry("vtnmpc", _vtnmpc_plus_policy,
                             "VT-NMPC+: observer + gimbal-camera heading + chord heading residual (not in the paper)",
                             "VT-NMPC+")
nmpc = _weights_entry("nmpc", _nmpc_policy, "conventional NMPC baseline (stand-off position + yaw tracking)", "NMPC")
pampc = _weights_entry("pampc", _pampc_policy, "perception-aware MPC baseline (Falanga et al. 2018)", "PAMPC")


def _nmpc_authors_policy(env: Any, **options: Any) -> Any:
    from .authors_baselines import AuthorsNMPCPolicy
    return AuthorsNMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, **options)


def _pampc_authors_policy(env: Any, **options: Any) -> Any:
    from .authors_baselines import AuthorsPAMPCPolicy
    from .pampc import PAMPCConfig
    guard = PAMPCConfig.image_plane_guard * env.config.standoff / 7.0
    return AuthorsPAMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt,
                              camera=env.config.camera, image_plane_guard=guard, **options)


nmpc_authors = _weights_entry("nmpc-authors", _nmpc_authors_policy,
                              "NMPC as the authors ran it: quaternion yaw reference that flips sign at 360 deg wraps",
                              "NMPC (authors' yaw bug)")
pampc_authors = _weights_entry("pampc", _pampc_authors_policy, "PAMPC as the authors ran it: camera axis body up",
                               "PAMPC (authors' camera axis)")


def safety_filter(env: Any, policy: Any) -> Any:
    """The safety filter a ``NAME+filter`` controller flies through (:mod:`controllers.safety_filter`)."""
    from .safety_filter import SafetyFilter
    return SafetyFilter(policy, env)
