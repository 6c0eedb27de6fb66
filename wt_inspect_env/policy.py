"""The interface every controller and agent shares, so one harness can score MPCs and RL alike.

``reset(seed=None)``, ``act(obs) -> action`` (normalised, float32, shape (4,)) and
stable-baselines3's ``predict(obs, state=None, episode_start=None, deterministic=True)``.
``last_stats`` holds the statistics of the last call (for MPCs: solve time, QP iterations,
status, fallback flag).

It lives with the environment (not with the controllers) because it is the environment's contract
with whoever flies it: the MPCs (``controllers``) and the learned agents (``agents``) both
implement it without importing each other, as Gymnasium's ``Env`` lives in Gymnasium and not in
any agent library. :class:`PolicyEntry` is what a package registers under the entry-point group
:data:`ENTRY_POINT_GROUP` (``[project.entry-points."wt_inspect.controllers"]`` in its
``pyproject.toml``) so the evaluation harness and the command line find it by name without
importing it by name.
"""
from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from wt_inspect_env.task.spaces import OBS_KEYS, OBS_SHAPES, OPTIONAL_OBS_SHAPES

_OBS_SIZES = tuple(int(np.prod(OBS_SHAPES[k])) for k in OBS_KEYS)
_OBS_SLICES = tuple(zip(OBS_KEYS, np.cumsum((0,) + _OBS_SIZES[:-1]).tolist(), np.cumsum(_OBS_SIZES).tolist()))
_OBS_TOTAL = sum(_OBS_SIZES)


def _fast_observation(obs: Any) -> dict[str, np.ndarray] | None:
    """What :func:`check_observation` returns, for the common case of a dict of float32/float64
    NumPy arrays of the documented shapes with finite values (the environments' own observations):
    one conversion into one float64 buffer and one finiteness check, the arrays views of it (the
    same values: float32 to float64 is exact). None for anything else (the full check names it)."""
    if type(obs) is not dict:
        return None
    try:
        parts = [obs[k] for k in OBS_KEYS]
    except KeyError:
        return None
    for part, key in zip(parts, OBS_KEYS):
        if type(part) is not np.ndarray or part.dtype.kind != "f" or part.shape != OBS_SHAPES[key]:
            return None
    buf = np.concatenate(parts, dtype=np.float64)
    if buf.size != _OBS_TOTAL or not np.isfinite(buf.sum()):   # a sum that overflows: the full check
        return None
    return {key: buf[a:b] for key, a, b in _OBS_SLICES}


def check_observation(obs: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The observation as float64 arrays of the documented shapes; ValueError naming the key
    otherwise (a missing key or a NaN must not reach a solver). A batch of one is unwrapped. The
    optional entries (:data:`~wt_inspect_env.task.spaces.OPTIONAL_OBS_SHAPES`, e.g. ``structure``)
    are kept, checked alike, when present: an agent trained on them needs them at evaluation."""
    fast = _fast_observation(obs)
    if fast is not None and not any(k in obs for k in OPTIONAL_OBS_SHAPES):
        return fast
    if not isinstance(obs, Mapping):
        raise ValueError(f"observation must be a dict with keys {OBS_KEYS}, got {type(obs).__name__}")
    out: dict[str, np.ndarray] = {}
    for key in OBS_KEYS + tuple(k for k in OPTIONAL_OBS_SHAPES if k in obs):
        try:
            arr = np.asarray(obs[key], dtype=np.float64)
        except KeyError:
            raise ValueError(f"observation is missing key {key!r}") from None
        except (TypeError, ValueError):
            raise ValueError(f"observation[{key!r}] must be numeric, got {obs[key]!r}") from None
        shape = OBS_SHAPES.get(key) or OPTIONAL_OBS_SHAPES[key]
        if arr.shape != shape:
            if arr.shape == (1,) + shape:   # a vectorised env with a single copy
                arr = arr[0]
            else:
                raise ValueError(f"observation[{key!r}] must have shape {shape}, got {arr.shape}")
        out[key] = arr
    if not np.isfinite(sum(float(v.sum()) for v in out.values())):
        bad = [k for k, v in out.items() if not np.all(np.isfinite(v))]
        if bad:   # (an overflowing sum of finite values is not an error)
            raise ValueError(f"observation[{bad[0]!r}] must be finite, got {out[bad[0]]}")
    return out


def state_from_observation(obs: Mapping[str, np.ndarray]) -> np.ndarray:
    """The model state [p, v_B, q] (:mod:`wt_inspect_env.physics.dynamics` layout) of a checked
    observation, quaternion renormalised (float32 observations are not exactly unit)."""
    q = obs["quaternion"]
    nq = np.linalg.norm(q)
    if nq < 1e-9:
        raise ValueError(f"observation['quaternion'] must be a unit quaternion, got {q}")
    return np.concatenate([obs["position"], obs["velocity_body"], q / nq])


class Policy(ABC):
    """Base class: subclasses implement :meth:`act` and :meth:`reset`; :meth:`predict` adapts
    them to stable-baselines3's signature (a batch of one environment, no recurrent state)."""

    last_stats: Any = None

    @abstractmethod
    def reset(self, seed: int | None = None) -> None:
        """Forget everything about the previous episode (warm starts, filters)."""

    @abstractmethod
    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Normalised action in [-1, 1]^4 (p, q, r, T) for one observation."""

    def predict(self, obs: Mapping[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """stable-baselines3 style. With a batched observation (leading axis of 1, as from a
        ``VecEnv`` with one environment) the action is returned batched as well. A controller
        keeps one warm start, so batches of several environments are refused."""
        batched = np.asarray(obs["position"]).ndim == 2 if isinstance(obs, Mapping) and \
            "position" in obs else False
        if batched and np.asarray(obs["position"]).shape[0] != 1:
            raise ValueError("predict accepts one environment at a time (a controller keeps one "
                             f"warm start); got a batch of {np.asarray(obs['position']).shape[0]}")
        if episode_start is not None and bool(np.any(episode_start)):
            self.reset()
        action = self.act(obs)
        return (action[None, :] if batched else action), state


ENTRY_POINT_GROUP = "wt_inspect.controllers"
#: entry-point group of safety filters: ``wrap(env, policy) -> policy`` (``filter`` is the one a
#: controller name's :data:`FILTER_SUFFIX` selects)
FILTER_ENTRY_POINT_GROUP = "wt_inspect.safety_filters"
#: a controller name ending in this flies that controller through the safety filter
FILTER_SUFFIX = "+filter"


@dataclass(frozen=True)
class PolicyEntry:
    """A named policy as a package registers it (the value of one entry point).

    ``factory(env)`` builds the policy from the *unwrapped* environment (its ``params``,
    ``config.standoff``, ``dt``, ``config.camera``, and ``mission`` - the planned path and the
    turbine of each rotor position, which the MPCs keep their clearance from), so the policy's
    model always matches the simulated drone and world. An entry with ``takes_argument`` is
    addressed as ``NAME:ARG`` (e.g.
    ``ppo:models/agent.zip``) and its factory is ``factory(env, arg)``; ``check(arg)`` raises a
    one-line ValueError for a bad argument before any run starts, and ``fingerprint(arg)`` names
    what makes the argument's behaviour unique (a model file's content hash), so a changed model
    is a different run. An entry with ``optional_argument`` (the argument's form for help, e.g.
    ``"weights=FILE"``) works both plain (``factory(env)``) and as ``NAME:ARG`` (``factory(env, arg)``,
    with ``check`` and ``fingerprint`` as above); ``label(arg)``, if given, is how a results table names
    the argument (default: the stem of a file path); ``env_options(arg)``, if given, the env options
    the policy needs for that argument (an agent that observes the structure needs
    ``structure_observation=True``), which the evaluation harness adds to the runs' env unless the
    user set them. An entry with ``trust_option`` loads files
    that might carry code: its
    ``factory`` and ``check`` take the keyword ``trust_model`` and run code from such a file only
    when it is True (the user's explicit ``--trust-model``); otherwise they refuse it.
    """

    factory: Callable[..., Any]
    description: str
    display_name: str | None = None
    takes_argument: bool = False
    check: Callable[..., None] | None = None
    fingerprint: Callable[[str], str] | None = None
    trust_option: bool = False
    optional_argument: str | None = None
    label: Callable[[str], str] | None = None
    env_options: Callable[[str], Mapping[str, Any]] | None = None

    def with_argument(self, arg: str, **trust: bool) -> Callable[[Any], Any]:
        """The factory ``env -> policy`` of ``NAME:arg`` (``trust``: the ``trust_model`` keyword of an
        entry with ``trust_option``); a partial of a module function, so it pickles to worker processes."""
        return functools.partial(_build_with_argument, self.factory, arg, dict(trust))

    def __post_init__(self) -> None:
        if not callable(self.factory):
            raise ValueError(f"PolicyEntry.factory must be callable, got {self.factory!r}")
        if not isinstance(self.description, str) or not self.description:
            raise ValueError(f"PolicyEntry.description must be a non-empty string, got {self.description!r}")


def _build_with_argument(factory: Callable[..., Any], arg: str, trust: Mapping[str, bool], env: Any) -> Any:
    return factory(env, arg, **trust)
