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
The argument may instead (or also, joined by ``:``) set ``damping=X``, a Levenberg-Marquardt damping
of the real-time iteration (:func:`damped_solver`): ``vtnmpc:damping=1``,
``pampc:weights=best.json:damping=1``; and, for the entries that keep d_min, ``backoff=M``: the OCP
keeps d_min + M [m] instead of d_min + d_ref / 70 (``clearance_backoff``) - a tightened expert whose
imitator, tracking it with decimetres of error, still keeps d_min (``vtnmpc-plus:backoff=0.5``).

The VT-NMPC keeps its 0.01 s shooting interval at any control rate (``control_dt`` is the
environment's period), as the paper's 200 Hz loop ran a 30 x 0.01 s horizon.
"""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any, Callable

from wt_inspect_env.policy import PolicyEntry

MPC_ARGUMENT = "weights=FILE|damping=X|backoff=M[:...]"
#: the options an MPC entry's argument may set (``OPTION=VALUE`` parts joined by ``:``)
MPC_OPTIONS = ("weights", "damping", "backoff")
#: the options whose value is a number >= 0
_NUMERIC_OPTIONS = ("damping", "backoff")


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


def parse_mpc_argument(arg: str) -> dict[str, str]:
    """``{"weights": FILE, "damping": X, "backoff": M}`` (any of them) from an MPC entry's argument
    ``weights=FILE``, ``damping=X``, ``backoff=M`` or several joined by ``:``; one-line ValueError
    naming the bad part otherwise (unknown option, repeated option, missing value, a damping or
    back-off that is not a finite number >= 0)."""
    out: dict[str, str] = {}
    for part in arg.split(":"):
        key, sep, value = part.partition("=")
        key = key.strip()
        if not sep or not value:
            raise ValueError(f"argument must be OPTION=VALUE parts joined by ':' ({MPC_ARGUMENT}), got {arg!r} "
                             f"(part {part!r} is not OPTION=VALUE)")
        if key not in MPC_OPTIONS:
            raise ValueError(f"unknown MPC option {key!r} in argument {arg!r}; valid: {', '.join(MPC_OPTIONS)}")
        if key in out:
            raise ValueError(f"MPC option {key!r} given twice in argument {arg!r}")
        if key in _NUMERIC_OPTIONS:
            try:
                x = float(value)
            except ValueError:
                x = float("nan")
            if not math.isfinite(x) or x < 0:
                raise ValueError(f"{key} must be a finite number >= 0, got {value!r}")
        out[key] = value
    return out


def load_entry_weights(kind: str, path: str) -> Any:
    """The weights of the file ``path`` for an MPC entry kind (missing fields: the entry's set)."""
    cls, base = _weights_class(kind)
    return cls.load(path, base=base)


def damped_solver(damping: float) -> Any:
    """The MPCs' default solver options with the real-time iteration damped by ``damping``
    (:attr:`~controllers.rti.RTIOptions.regularization`, a Levenberg-Marquardt term on the
    Gauss-Newton Hessian in the solver's units). Why an option: a full Gauss-Newton step per
    control period does not settle on every problem - on the lab scenario's scaled OCP the rate
    commands alternate between their bounds from one step to the next (``results/lab``) - and
    damping the step is the standard remedy; on the paper-scale problems it slows the tracking,
    so the default stays undamped."""
    from .rti_policy import default_solver
    return default_solver(regularization=float(damping))


def mpc_options(kind: str, arg: str, clearance: bool = True) -> dict[str, Any]:
    """The policy options of an MPC entry's argument (see :func:`parse_mpc_argument`);
    ``clearance``: whether the entry keeps d_min (``backoff`` is refused by one that does not)."""
    parts = parse_mpc_argument(arg)
    options: dict[str, Any] = {}
    if "backoff" in parts:
        if not clearance:
            raise ValueError(f"backoff={parts['backoff']} needs the clearance constraint, which this "
                             f"{kind!r} entry (the authors' variant) does not have")
        options["clearance_backoff"] = float(parts["backoff"])
    if "weights" in parts:
        options["weights"] = load_entry_weights(kind, parts["weights"])
    if "damping" in parts:
        options["solver"] = damped_solver(float(parts["damping"]))
    return options


def mpc_label(arg: str) -> str:
    """How a table names an MPC entry's argument: the weights file's stem and/or ``damping X``."""
    parts = parse_mpc_argument(arg)
    shown = [Path(parts["weights"]).stem] if "weights" in parts else []
    if "damping" in parts:
        shown.append(f"damping {parts['damping']}")
    if "backoff" in parts:
        shown.append(f"backoff {parts['backoff']} m")
    return ", ".join(shown)


def _weights_entry(kind: str, build: Callable[..., Any], description: str, display_name: str,
                   clearance: bool = True) -> PolicyEntry:
    """An MPC entry that works plain (its own weights, undamped) or with the argument
    ``weights=FILE``, ``damping=X``, ``backoff=M`` (with ``clearance``: it keeps d_min) or several
    (:func:`parse_mpc_argument`)."""
    def factory(env: Any, arg: str | None = None) -> Any:
        return build(env) if arg is None else build(env, **mpc_options(kind, arg, clearance))

    def check(arg: str) -> None:
        mpc_options(kind, arg, clearance)

    def fingerprint(arg: str) -> str:   # the weights' values, not the file's name or layout
        parts = parse_mpc_argument(arg)
        out = []
        if "weights" in parts:
            w = load_entry_weights(kind, parts["weights"])
            data = json.dumps(w.to_dict(), sort_keys=True)
            out.append("weights=" + hashlib.sha256(data.encode()).hexdigest()[:16])
        if "damping" in parts:
            out.append(f"damping={float(parts['damping'])!r}")
        if "backoff" in parts:
            out.append(f"backoff={float(parts['backoff'])!r}")
        return ":".join(out)

    return PolicyEntry(factory, description, display_name=display_name,
                       check=check, fingerprint=fingerprint, optional_argument=MPC_ARGUMENT, label=mpc_label)


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
                              "NMPC (authors' yaw bug)", clearance=False)
pampc_authors = _weights_entry("pampc", _pampc_authors_policy, "PAMPC as the authors ran it: camera axis body up",
                               "PAMPC (authors' camera axis)", clearance=False)


def safety_filter(env: Any, policy: Any) -> Any:
    """The safety filter a ``NAME+filter`` controller flies through (:mod:`controllers.safety_filter`)."""
    from .safety_filter import SafetyFilter
    return SafetyFilter(policy, env)
