"""The optional dependencies and the extra that installs each: one table for every place that
turns a missing one into a one-line error (the ``wt-inspect`` dispatcher, the controller
registry), so ``ppo:`` models or ``train`` without the ``rl`` extra say what to install instead
of printing a ModuleNotFoundError traceback."""
from __future__ import annotations

# top-level module -> extra of pyproject.toml [project.optional-dependencies]
OPTIONAL_MODULES: dict[str, str] = {"torch": "rl", "stable_baselines3": "rl", "tensorboard": "rl",
                                    "ray": "ray", "minari": "demos", "h5py": "demos",
                                    "optuna": "tune", "pymavlink": "px4"}


def missing_extra(exc: BaseException) -> str | None:
    """For a ModuleNotFoundError of an optional dependency, the sentence naming the module and
    the install command; None for anything else (a genuine bug stays a traceback)."""
    if not isinstance(exc, ModuleNotFoundError):
        return None
    top = (exc.name or "").split(".")[0]
    extra = OPTIONAL_MODULES.get(top)
    if extra is None:
        return None
    return f"needs the optional dependency '{top}'; install it with: pip install 'wt-inspect[{extra}]'"
