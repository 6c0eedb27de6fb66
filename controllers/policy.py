"""The interface every controller and agent shares, so one harness can score MPCs and RL alike.

``reset(seed=None)``, ``act(obs) -> action`` (normalised, float32, shape (4,)) and
stable-baselines3's ``predict(obs, state=None, episode_start=None, deterministic=True)``.
``last_stats`` holds the statistics of the last call (for MPCs: solve time, QP iterations,
status, fallback flag).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.spaces import OBS_KEYS, OBS_SHAPES


def check_observation(obs: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The observation as float64 arrays of the documented shapes; ValueError naming the key
    otherwise (a missing key or a NaN must not reach a solver). A batch of one is unwrapped."""
    if not isinstance(obs, Mapping):
        raise ValueError(f"observation must be a dict with keys {OBS_KEYS}, got {type(obs).__name__}")
    out: dict[str, np.ndarray] = {}
    for key in OBS_KEYS:
        try:
            arr = np.asarray(obs[key], dtype=np.float64)
        except KeyError:
            raise ValueError(f"observation is missing key {key!r}") from None
        except (TypeError, ValueError):
            raise ValueError(f"observation[{key!r}] must be numeric, got {obs[key]!r}") from None
        shape = OBS_SHAPES[key]
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
