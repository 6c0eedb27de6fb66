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

The VT-NMPC keeps its 0.01 s shooting interval at any control rate (``control_dt`` is the
environment's period), as the paper's 200 Hz loop ran a 30 x 0.01 s horizon.
"""
from __future__ import annotations

from typing import Any

from wt_inspect_env.policy import PolicyEntry


def _turbine(env: Any) -> Any:
    """The turbine the MPCs keep ``d_min`` from: the mission's collision mesh of every rotor
    position (the geometry the simulator collides the drone with)."""
    from wt_inspect_env.proximity import TurbineProximity
    return TurbineProximity.from_mission(env.mission)


def _vtnmpc_policy(env: Any, **options: Any) -> Any:
    from .vtnmpc import VTNMPCPolicy
    return VTNMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, obstacles=_turbine(env),
                        **options)


def _vtnmpc_plus_policy(env: Any) -> Any:
    from .vtnmpc import VTNMPC_PLUS
    return _vtnmpc_policy(env, **VTNMPC_PLUS)


def _nmpc_policy(env: Any) -> Any:
    from .nmpc import NMPCPolicy
    return NMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt, obstacles=_turbine(env))


def _pampc_policy(env: Any) -> Any:
    from .pampc import PAMPCConfig, PAMPCPolicy
    guard = PAMPCConfig.image_plane_guard * env.config.standoff / 7.0
    return PAMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt,
                       camera=env.config.camera, image_plane_guard=guard, obstacles=_turbine(env))


vtnmpc = PolicyEntry(_vtnmpc_policy, "the paper's VT-NMPC, paper weights", display_name="VT-NMPC")
vtnmpc_later = PolicyEntry(lambda env: _vtnmpc_policy(env, weights="later_tuning"),
                           "VT-NMPC with the authors' later tuning file", display_name="VT-NMPC (later tuning)")
vtnmpc_dob = PolicyEntry(lambda env: _vtnmpc_policy(env, disturbance_observer=True),
                         "VT-NMPC, paper weights + disturbance observer (not in the paper)",
                         display_name="VT-NMPC + observer")
vtnmpc_dob_gimbal = PolicyEntry(lambda env: _vtnmpc_policy(env, disturbance_observer=True, heading_model="camera"),
                                "VT-NMPC, paper weights + observer + gimbal-camera heading (VT-NMPC+ without the "
                                "chord residual; an ablation step)", display_name="VT-NMPC + observer + gimbal")
vtnmpc_plus = PolicyEntry(_vtnmpc_plus_policy,
                          "VT-NMPC+: observer + gimbal-camera heading + chord heading residual (not in the paper)",
                          display_name="VT-NMPC+")
nmpc = PolicyEntry(_nmpc_policy, "conventional NMPC baseline (stand-off position + yaw tracking)",
                   display_name="NMPC")
pampc = PolicyEntry(_pampc_policy, "perception-aware MPC baseline (Falanga et al. 2018)", display_name="PAMPC")


def _nmpc_authors_policy(env: Any) -> Any:
    from .authors_baselines import AuthorsNMPCPolicy
    return AuthorsNMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt)


def _pampc_authors_policy(env: Any) -> Any:
    from .authors_baselines import AuthorsPAMPCPolicy
    from .pampc import PAMPCConfig
    guard = PAMPCConfig.image_plane_guard * env.config.standoff / 7.0
    return AuthorsPAMPCPolicy(params=env.params, d_ref=env.config.standoff, control_dt=env.dt,
                              camera=env.config.camera, image_plane_guard=guard)


nmpc_authors = PolicyEntry(_nmpc_authors_policy,
                           "NMPC as the authors ran it: quaternion yaw reference that flips sign at 360 deg wraps",
                           display_name="NMPC (authors' yaw bug)")
pampc_authors = PolicyEntry(_pampc_authors_policy, "PAMPC as the authors ran it: camera axis body up",
                            display_name="PAMPC (authors' camera axis)")
