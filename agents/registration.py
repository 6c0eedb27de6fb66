"""The saved stable-baselines3 agents as named policies: ``ppo:PATH``.

Entry points of the group ``wt_inspect.controllers`` (see ``pyproject.toml``) whose values are the
:class:`~wt_inspect_env.policy.PolicyEntry` objects below; the evaluation harness finds them
through ``importlib.metadata`` and never imports this package by name. Nothing heavy is imported
here: torch and stable-baselines3 load only when a model is (:func:`agents.policy.load_sb3_policy`).
Both entries take ``trust_model`` (``--trust-model``): without it a model file that would need
unpickling is refused (:mod:`agents.safe_load`), already by ``check`` before any run starts.
"""
from __future__ import annotations

import hashlib
from typing import Any

from wt_inspect_env.policy import PolicyEntry

from .safe_load import resolve_model_path, verify_shipped


def _check(algo: str):
    def check(path: str, trust_model: bool = False) -> None:
        """ValueError naming the path unless the model file (or shipped name) exists, a shipped
        model matches its digests and - unless ``trust_model`` - the file loads without unpickling
        (reads JSON and weights only; nothing of the model is built)."""
        model = resolve_model_path(path)
        verify_shipped(model)
        if trust_model:   # SB3's loader will run; still refuse, before any run, a zip that is no model
            from .safe_load import check_model_data
            check_model_data(model)
            return
        try:
            from .policy import algo_class, load_sidecar
            from .safe_load import check_safe
            check_safe(algo_class(algo), model, load_sidecar(model))
        except ImportError as exc:
            name = getattr(exc, "name", None) or ""
            if isinstance(exc, ModuleNotFoundError) and name.split(".")[0] in {"torch", "stable_baselines3"}:
                # refused here, before any run starts or any output directory is made
                raise ValueError(f"needs the optional dependency {name.split('.')[0]!r}; install it "
                                 "with: pip install 'wt-inspect[rl]'") from None
            # the loader module itself cannot be imported: the loader reports that in one line
            # (and runs the same safety checks before it loads anything)
            return
    return check


def model_fingerprint(path: str) -> str:
    """Content hash of a saved model and its sidecar (the sidecar holds the observation
    normalisation, so a retrained or re-normalised agent is a different controller)."""
    model = resolve_model_path(path)
    h = hashlib.sha256(model.read_bytes())
    sidecar = model.with_suffix(".json")
    if sidecar.is_file():
        h.update(sidecar.read_bytes())
    return "sha256=" + h.hexdigest()[:16]


def model_env_options(path: str) -> dict[str, Any]:
    """The env options a saved agent needs (:func:`agents.interface.needed_env_options` of its
    feature groups); none when its sidecar cannot be read (the entry's ``check`` reports that)."""
    from .interface import needed_env_options
    from .policy import load_sidecar
    try:
        doc = load_sidecar(resolve_model_path(path))
        groups = doc["spec"]["features"]["groups"]
    except (ValueError, KeyError, TypeError):
        return {}
    return needed_env_options(groups)


def _loader(algo: str):
    def load(env: Any, path: str, trust_model: bool = False) -> Any:
        """Load ``path`` for ``env``; a missing optional dependency is a one-line ValueError."""
        try:
            from .policy import load_sb3_policy  # torch and stable-baselines3 only now
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.split(".")[0] in {"torch", "stable_baselines3"}:
                raise ValueError(f"controller '{algo}:{path}' needs the optional dependency {exc.name!r}; "
                                 "install it with: pip install 'wt-inspect[rl]'") from None
            raise ValueError(f"controller '{algo}:{path}' needs agents.policy.load_sb3_policy, which cannot "
                             f"be imported: {exc}") from None
        trust = {"trust_model": True} if trust_model else {}   # the plain call unless the user consented
        return load_sb3_policy(algo, resolve_model_path(path), env, **trust)
    return load


ppo = PolicyEntry(_loader("ppo"), "a saved stable-baselines3 PPO model (ppo:PATH.zip or ppo:NAME of a shipped model)",
                  display_name="PPO",
                  takes_argument=True, check=_check("ppo"), fingerprint=model_fingerprint, trust_option=True,
                  env_options=model_env_options)
