"""Saved stable-baselines3 agents as controllers with the shared ``reset / act / predict`` interface.

A model ``DIR/NAME.zip`` is saved with a sidecar ``DIR/NAME.json`` (:func:`save_agent`) holding
what the network alone does not know: the :class:`~agents.wrappers.AgentSpec` (features, residual
action, action repeat), the observation normalisation statistics of training (VecNormalize's
running mean / variance, clip, epsilon - plain numbers, no pickle needed to deploy) and the
environment interface it was trained on. ``DIR/NAME.vecnormalize.json`` (every VecNormalize
statistic, the reward's too, as JSON) is only needed to *resume* training.

Nothing is unpickled from a model file: :mod:`agents.safe_load` rebuilds what stable-baselines3
would unpickle from the sidecar and refuses a file that would still need it, unless the caller
trusts the file (``trust_model``).

:func:`load_sb3_policy` rebuilds the exact training-time pipeline around the network: Dict
observation -> :class:`~agents.wrappers.FeatureEncoder` -> normalisation -> network
(deterministic) -> :class:`~agents.wrappers.ResidualHoverAction` -> the env's normalised action;
the network's action is held for ``action_repeat`` control steps and decoded at each of them with
the current attitude (tilt compensation, attitude loop), exactly as in training. The evaluation
harness resolves ``ppo:PATH`` /
controller names through it. :func:`agent_env` is the same pipeline as an env wrapper,
for code that drives the bare SB3 model itself (``model.predict(obs)`` on the wrapped env).
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.policy import Policy, check_observation
from wt_inspect_env.task.spaces import ActionScaling
from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.validation import check_choice

from .safe_load import load_sb3_model, resolve_model_path, save_vecnormalize, vecnormalize_path, verify_shipped
from .wrappers import (
    AgentObservationEnv,
    AgentSpec,
    FeatureEncoder,
    FeatureNormalization,
    InspectionAgentEnv,
    ResidualHoverAction,
)

#: the reinforcement-learning algorithms that train and load agents here (SAC was dropped: CHANGELOG)
ALGOS: tuple[str, ...] = ("ppo",)
SIDECAR_FORMAT = 1


def algo_class(algo: str):
    """The stable-baselines3 class for an algorithm name (ValueError listing the valid ones)."""
    check_choice("algorithm", algo, ALGOS)
    from stable_baselines3 import PPO
    return {"ppo": PPO}[algo]


def sidecar_paths(model_path: str | Path) -> tuple[Path, Path, Path]:
    """``(NAME.zip, NAME.json, NAME.vecnormalize.json)`` for a model path given with or without
    its ``.zip`` suffix."""
    p = Path(model_path)
    stem = p.with_suffix("") if p.suffix == ".zip" else p
    return stem.with_suffix(".zip"), stem.with_suffix(".json"), vecnormalize_path(stem)


def env_interface(env) -> dict[str, float]:
    """The numbers of an environment the agent's interface depends on."""
    u = env.unwrapped
    return {"mass": float(u.scaling.mass), "max_rate": float(u.scaling.max_rate),
            "standoff": float(u.config.standoff), "dt": float(u.dt)}


def save_agent(model, path: str | Path, *, algo: str, spec: AgentSpec, vecnormalize=None,
               interface: Mapping[str, float], extra: Mapping[str, Any] | None = None) -> Path:
    """Save ``model`` as ``NAME.zip`` with its ``NAME.json`` sidecar (and ``NAME.vecnormalize.json``
    when a VecNormalize is given). Returns the ``.zip`` path."""
    zip_path, json_path, norm_path = sidecar_paths(path)
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    model.save(str(zip_path))
    norm = None
    if vecnormalize is not None:
        save_vecnormalize(vecnormalize, norm_path)
        if vecnormalize.norm_obs:
            norm = {"mean": vecnormalize.obs_rms.mean.tolist(), "var": vecnormalize.obs_rms.var.tolist(),
                    "clip_obs": float(vecnormalize.clip_obs), "epsilon": float(vecnormalize.epsilon)}
    doc = {"format": SIDECAR_FORMAT, "algo": algo, "spec": spec.to_dict(), "obs_normalization": norm,
           "env_interface": dict(interface), **(dict(extra) if extra else {})}
    write_text_atomic(json_path, json.dumps(doc, indent=1))
    return zip_path


def load_sidecar(path: str | Path) -> dict[str, Any]:
    """The sidecar document of a saved model (ValueError naming the file if missing or invalid;
    a shipped model's files are checked against their digests first)."""
    _, json_path, _ = sidecar_paths(path)
    verify_shipped(json_path)
    if not json_path.is_file():
        raise ValueError(f"model sidecar {str(json_path)!r} not found (saved by agents.policy.save_agent "
                         "next to the model: it holds the feature spec and normalisation)")
    try:
        doc = json.loads(json_path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"model sidecar {str(json_path)!r} is not valid JSON: {exc}") from None
    if doc.get("format") != SIDECAR_FORMAT:
        raise ValueError(f"model sidecar {str(json_path)!r} has format {doc.get('format')!r}, "
                         f"expected {SIDECAR_FORMAT}")
    return doc


class SB3Policy(Policy):
    """A stable-baselines3 model behind the shared controller interface (see the module docstring).

    ``act`` must see every control step's observation of an episode in order (the encoder
    integrates the pose error and the action is held between network calls); call :meth:`reset`
    at each episode start (``predict`` does so on ``episode_start``). ``last_stats["solve_ms"]``
    is the network's inference time on decision steps and None on the held steps between them.
    """

    def __init__(self, model, spec: AgentSpec, scaling: ActionScaling, *, standoff: float, dt: float,
                 obs_normalization: Mapping[str, Any] | None = None, algo: str = "ppo") -> None:
        self.model = model
        self.algo = algo
        self.spec = spec
        self.encoder = FeatureEncoder(spec.features, standoff=standoff, dt=dt, max_rate=scaling.max_rate)
        self.decoder = ResidualHoverAction(spec.action, scaling)
        n = spec.features.size
        self.normalization = (None if obs_normalization is None
                              else FeatureNormalization.from_sidecar(obs_normalization, n))
        expected = getattr(model, "observation_space", None)
        if expected is not None and tuple(expected.shape) != (n,):
            raise ValueError(f"model expects observations of shape {tuple(expected.shape)}, "
                             f"the spec gives {n} features")
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode (the network is deterministic; ``seed`` is accepted for the interface)."""
        self.encoder.reset()
        self._count = 0
        self._held: np.ndarray | None = None
        self.last_stats = None

    def normalize(self, features: np.ndarray) -> np.ndarray:
        """The features as the network takes them: normalised if the agent was trained with normalisation."""
        if self.normalization is None:
            return features.astype(np.float32)
        return self.normalization(features)

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """The env action for ``obs``: the network is asked every ``action_repeat`` steps, its action held between."""
        o = check_observation(obs)
        self.encoder.update(o)
        if self._count % self.spec.action_repeat == 0 or self._held is None:
            t0 = time.perf_counter()
            x = self.normalize(self.encoder.features())
            u, _ = self.model.predict(x, deterministic=True)
            self._held = np.asarray(u, dtype=np.float64).reshape(4)
            self.encoder.note_action(self._held)
            self.last_stats = {"solve_ms": (time.perf_counter() - t0) * 1e3, "policy_action": self._held,
                               "new_decision": True}
        else:   # holding the last decision: no network call, no solve time to report
            self.last_stats = {"solve_ms": None, "policy_action": self._held, "new_decision": False}
        self._count += 1
        # the held policy action is decoded with the current attitude, as in training
        return self.decoder(self._held, o["quaternion"])


def load_sb3_policy(algo: str, path: str | Path, env=None, *, trust_model: bool = False) -> SB3Policy:
    """Load ``path`` (``NAME.zip`` with its ``NAME.json`` sidecar) as a controller for ``env``.

    The returned object takes the env's raw Dict observation and returns a normalised env action
    (``reset / act / predict``). The stand-off, control period and airframe come from ``env`` when
    given (features are relative to *its* ideal pose; hover thrust from *its* mass), else from the
    sidecar. ValueError if ``algo`` is not ``ppo``, the file is missing, the sidecar
    says another algorithm, or the file would need unpickling (:mod:`agents.safe_load`) and
    ``trust_model`` is False.
    """
    cls = algo_class(algo)
    zip_path, _, _ = sidecar_paths(path)
    if not zip_path.is_file():
        raise ValueError(f"model file {str(zip_path)!r} not found")
    doc = load_sidecar(zip_path)
    if doc.get("algo") != algo:
        raise ValueError(f"model {str(zip_path)!r} was trained with {doc.get('algo')!r}, not {algo!r}")
    spec = AgentSpec.from_dict(doc["spec"])
    if env is not None:
        iface = env_interface(env)
        scaling = env.unwrapped.scaling
    else:
        iface = doc["env_interface"]
        scaling = ActionScaling(mass=iface["mass"], max_rate=iface["max_rate"])
    model = load_sb3_model(cls, zip_path, doc, trust_model=trust_model, device="cpu")
    return SB3Policy(model, spec, scaling, standoff=iface["standoff"], dt=iface["dt"],
                     obs_normalization=doc.get("obs_normalization"), algo=algo)


def agent_env(env, path: str | Path) -> AgentObservationEnv:
    """``env`` as the saved agent ``path`` (a ``NAME.zip`` with its sidecar, or a shipped model's
    name such as ``"ppo_surface"``) sees it: observations are the normalised feature vectors its
    network takes, actions are its network's outputs. So a plain stable-baselines3 model flies the
    env with ``model.predict(obs)`` and ``env.step(action)`` - the same flight as
    :func:`load_sb3_policy` on the unwrapped env. Each step holds the action for the agent's
    ``action_repeat`` control steps (rewards summed). The model itself can be loaded with
    ``load_sb3_policy(algo, path).model`` (no code from the file runs) or with SB3's
    ``PPO.load(path)`` (which unpickles)."""
    zip_path = resolve_model_path(str(path))
    doc = load_sidecar(zip_path)
    spec = AgentSpec.from_dict(doc["spec"])
    norm = doc.get("obs_normalization")
    return AgentObservationEnv(InspectionAgentEnv(env, spec),
                               None if norm is None else FeatureNormalization.from_sidecar(norm, spec.features.size))


__all__ = ["ALGOS", "SB3Policy", "load_sb3_policy", "agent_env", "save_agent", "load_sidecar", "sidecar_paths",
           "algo_class", "env_interface"]
