"""What an RL agent sees and commands: relative body-frame features and residual-to-hover actions.

Why these wrappers exist
------------------------
The environment's Dict observation is in world coordinates (positions ~100 m, a quaternion) and
its action maps ``a = 0`` to 1.15 m g of thrust, not to hover. A network can in principle learn
the change of frame, but with a 2 M step budget every transform it has to learn costs samples. So
an agent here sees the quantities a flight-control engineer would feed a tracking controller, in
the body frame where the rate/thrust command acts, scaled to O(1):

======================  ====  =========================================================================
group                   size  feature
======================  ====  =========================================================================
``ideal_body``          3     ``R^T (q - x) / position_scale``: drone to the ideal stand-off pose
                              ``q = p + d_ref n_xy/|n_xy|`` (the env's definition) - zero at the pose
``point_body``          3     ``R^T (p - x) / d_ref``: drone to the inspection point (camera aim)
``velocity_body``       3     ``(v_body - R^T v_point) / velocity_scale``: velocity relative to the point
``pose_velocity_body``  3     ``(v_body - R^T v_q) / velocity_scale``: velocity relative to the ideal pose
                              ``q``, ``v_q = v_point + d_ref dn_xy/dt`` (the turn of the horizontal normal
                              by finite differences between control steps; 0 on an episode's first). Where
                              the normal turns - round a blade tip or the hub - the pose swings on a
                              ``d_ref`` lever while the point hardly moves, so ``velocity_body`` tells the
                              agent to stop where it has to move: the feed-forward a tracking controller
                              takes from its reference
``gravity_body``        3     ``R^T (0, 0, -1)``: attitude as the gravity direction (no quaternion sign
                              ambiguity, no yaw, which the task does not care about)
``heading``             2     ``(sin, cos)`` of the horizontal angle from the body x axis (camera) to the
                              point: (0, 1) when centred (the paper's h is its cosine)
``body_rates``          3     measured body rates / max command rate
``normal_body``         3     ``R^T n``: the surface normal in the body frame
``integral``            3     ``R^T I / (integral_time_s position_scale)`` with ``I`` a leaky integral
                              (time constant ``integral_time_s``) of the world-frame pose error: lets a
                              memoryless network learn integral action against the mean wind (the wind
                              is not observed, as on a real drone)
``last_action``         4     the policy's previous action (smoothness; the held command is part of the
                              state when actions are repeated)
``progress``            1     mission progress in [0, 1]
``coverage``            1     coverage so far in [0, 1]
``structure_body``      4     ``R^T (c - x) / d_ref`` and ``|c - x| / d_ref`` with ``c`` the nearest point
                              of the turbine (the env's ``structure`` entry: ``structure_observation=True``):
                              what the agent needs to keep d_min by itself
======================  ====  =========================================================================

Every feature is clipped to ``[-clip, clip]`` (large errors saturate instead of dominating).

Action (:class:`ResidualHoverAction`): the policy's ``u in [-1, 1]^4`` is a *residual around hover*.
Thrust is ``m g (1 + thrust_scale u[3])``, divided by the cosine of the tilt when
``tilt_compensation`` is on (so a tilted drone keeps its altitude at ``u = 0``; the factor is capped
at ``max_tilt_factor``). ``u[:3]`` depends on ``mode``:

* ``rates``: body rates ``rate_scale * max_rate * u[:3]`` - the env's own command, end to end;
* ``attitude``: ``u[0], u[1]`` are the desired roll and pitch (``max_tilt_deg`` at 1) in the
  heading frame, ``u[2]`` the yaw rate; a fixed proportional attitude loop,
  ``(p, q) = attitude_gain * (-z_b[1], z_b[0])`` with ``z_b`` the desired thrust axis in the body
  frame, turns the tilt set-point into the env's body-rate command at every control step. The
  network then works one integrator away from the position instead of two (the usual
  "attitude-thrust" action space of learned quadrotor controllers); the env, its rate loop and its
  bounds are unchanged.

So ``u = 0`` hovers (level, in ``attitude`` mode) from the first update on, and exploration noise
is centred on flying rather than on climbing. The command is converted to the env's normalised
action with :meth:`ActionScaling.to_action`, which saturates it at the airframe's bounds (rates
100 deg/s, thrust 0.3-2 m g) - physical limits, reachable only through the attitude loop or the
tilt compensation (policy actions outside [-1, 1] are an error, not clipped).

``action_repeat`` holds each policy action for that many 100 Hz control steps (the agent decides
at 25 Hz with 4): fewer, more consequential decisions make credit assignment easier, and the
network and inter-process costs per simulated step drop by the same factor. The held policy
action is decoded at every control step with the current attitude; the environment is stepped,
observed and scored at its own rate.

The same :class:`FeatureEncoder` / :class:`ResidualHoverAction` objects are used by the training
wrapper (:class:`InspectionAgentEnv`) and by the deployed policy (:mod:`agents.policy`), so the
features a saved model sees at evaluation are computed by the very code it was trained with.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from wt_inspect_env.task.spaces import ActionScaling
from wt_inspect_env.util.validation import check_array, check_choice, check_positive, check_unknown_options

from .interface import BatchedDecoder, BatchedFeatures, camera_heading, check_entries  # noqa: F401 - camera_heading re-exported

FEATURE_SIZES: dict[str, int] = {
    "ideal_body": 3, "point_body": 3, "velocity_body": 3, "gravity_body": 3, "heading": 2,
    "body_rates": 3, "normal_body": 3, "integral": 3, "last_action": 4, "progress": 1, "coverage": 1,
    "structure_body": 4, "pose_velocity_body": 3,
}

ACTION_MODES: tuple[str, ...] = ("rates", "attitude")
DEFAULT_GROUPS: tuple[str, ...] = (
    "ideal_body", "point_body", "velocity_body", "gravity_body", "heading", "body_rates",
    "normal_body", "integral", "last_action",
)


@dataclass(frozen=True)
class FeatureConfig:
    """Which feature groups (in this order) and how they are scaled (see the module docstring).

    position_scale [m], velocity_scale [m/s]: errors of this size map to 1. integral_time_s [s]:
    time constant of the leaky error integral (the feature saturates at ``clip``, which is also
    the integrator's anti-windup bound).
    """

    groups: tuple[str, ...] = DEFAULT_GROUPS
    position_scale: float = 2.0
    velocity_scale: float = 2.0
    integral_time_s: float = 5.0
    clip: float = 5.0

    def __post_init__(self) -> None:
        groups = tuple(self.groups)
        if not groups:
            raise ValueError("feature groups must not be empty")
        for g in groups:
            check_choice("feature group", g, FEATURE_SIZES)
        if len(set(groups)) != len(groups):
            raise ValueError(f"feature groups must not repeat, got {list(groups)}")
        object.__setattr__(self, "groups", groups)
        check_positive("feature position_scale", self.position_scale)
        check_positive("feature velocity_scale", self.velocity_scale)
        check_positive("feature integral_time_s", self.integral_time_s)
        check_positive("feature clip", self.clip)

    @property
    def size(self) -> int:
        """Number of feature entries (the length of the agent's observation)."""
        return sum(FEATURE_SIZES[g] for g in self.groups)

    def names(self) -> list[str]:
        """One name per feature entry, e.g. ``ideal_body[0]`` (for logs and tests)."""
        return [f"{g}[{i}]" for g in self.groups for i in range(FEATURE_SIZES[g])]


@dataclass(frozen=True)
class ActionConfig:
    """Residual-to-hover action mapping (see the module docstring)."""

    mode: str = "rates"
    rate_scale: float = 1.0
    thrust_scale: float = 0.5
    tilt_compensation: bool = True
    max_tilt_factor: float = 1.5
    max_tilt_deg: float = 30.0
    attitude_gain: float = 5.0

    def __post_init__(self) -> None:
        check_choice("action mode", self.mode, ACTION_MODES)
        if not 0.0 < float(self.max_tilt_deg) < 90.0:
            raise ValueError(f"action max_tilt_deg must lie in (0, 90), got {self.max_tilt_deg!r}")
        check_positive("action attitude_gain", self.attitude_gain)
        if not 0.0 < float(self.rate_scale) <= 1.0:
            raise ValueError(f"action rate_scale must lie in (0, 1], got {self.rate_scale!r}")
        if not 0.0 < float(self.thrust_scale) <= 0.7:
            # 1 - 0.7 = 0.3: the lowest residual thrust is the airframe's lower bound
            raise ValueError(f"action thrust_scale must lie in (0, 0.7], got {self.thrust_scale!r}")
        if not isinstance(self.tilt_compensation, bool):
            raise ValueError(f"action tilt_compensation must be a bool, got {self.tilt_compensation!r}")
        if not float(self.max_tilt_factor) >= 1.0:
            raise ValueError(f"action max_tilt_factor must be >= 1, got {self.max_tilt_factor!r}")


@dataclass(frozen=True)
class AgentSpec:
    """Everything besides the network that defines how an agent talks to the environment; saved
    next to every model so that :func:`agents.policy.load_sb3_policy` rebuilds the same interface."""

    features: FeatureConfig = field(default_factory=FeatureConfig)
    action: ActionConfig = field(default_factory=ActionConfig)
    action_repeat: int = 4

    def __post_init__(self) -> None:
        if isinstance(self.features, Mapping):
            check_unknown_options("features", self.features.keys(),
                                  [f.name for f in dataclasses.fields(FeatureConfig)])
            object.__setattr__(self, "features", FeatureConfig(**dict(self.features)))
        if isinstance(self.action, Mapping):
            check_unknown_options("action", self.action.keys(),
                                  [f.name for f in dataclasses.fields(ActionConfig)])
            object.__setattr__(self, "action", ActionConfig(**dict(self.action)))
        if not isinstance(self.features, FeatureConfig) or not isinstance(self.action, ActionConfig):
            raise ValueError("features / action must be FeatureConfig / ActionConfig or dicts of their fields")
        r = self.action_repeat
        if isinstance(r, bool) or not isinstance(r, int) or r < 1:
            raise ValueError(f"action_repeat must be a positive integer, got {r!r}")

    def to_dict(self) -> dict[str, Any]:
        """The spec as plain JSON-able data (for the model's sidecar)."""
        d = dataclasses.asdict(self)
        d["features"]["groups"] = list(self.features.groups)
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "AgentSpec":
        """The spec from :meth:`to_dict` data (unknown keys are an error)."""
        check_unknown_options("agent spec", data.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**dict(data))


@dataclass(frozen=True)
class ShapingConfig:
    """Training-only reward shaping added by :class:`InspectionAgentEnv` on top of the env's reward
    (evaluation always scores the env's own reward and metrics).

    ``distance_coarse_weight * dt / (1 + (e / distance_coarse_scale)^2)`` per control step, with
    ``e`` the 3-D distance to the ideal stand-off pose: a second, *heavy-tailed* kernel beside the
    env's narrow Gaussian (sigma 1 m). Why: the env's kernel is flat beyond ~3 m, so a young policy
    that has learnt to survive the gust but drifted 15 m downwind sees no gradient back to the
    pose (a wider Gaussian, sigma 4 m, was tried and was still flat there); this kernel pulls from
    tens of metres. It is positive and bounded like the env's term, so staying airborne always
    pays and a crash never looks attractive. 0 disables it.
    """

    distance_coarse_weight: float = 0.0
    distance_coarse_scale: float = 5.0
    centering_fine_weight: float = 0.0
    centering_fine_scale_deg: float = 5.0

    def __post_init__(self) -> None:
        check_positive("shaping distance_coarse_weight", self.distance_coarse_weight, allow_zero=True)
        check_positive("shaping distance_coarse_scale", self.distance_coarse_scale)
        check_positive("shaping centering_fine_weight", self.centering_fine_weight, allow_zero=True)
        check_positive("shaping centering_fine_scale_deg", self.centering_fine_scale_deg)
        if not self.centering_fine_scale_deg < 90.0:
            raise ValueError("shaping centering_fine_scale_deg must be below 90, got "
                             f"{self.centering_fine_scale_deg!r}")

    def centering_fine(self, dt: float, heading_cos: float) -> float:
        """The fine centering term of one control step: ``centering_fine_weight * dt *
        exp(-(1 - h) / (1 - cos s))`` with ``h`` the cosine of the camera's horizontal heading error
        (the env's centering function) and ``s = centering_fine_scale_deg``: 1 when the point is
        centred, 1/e at a heading error of ``s``. Why: the env's centering term is linear in ``h``,
        whose slope vanishes at the optimum (``h = cos 9 deg = 0.988`` earns 98.8 % of a perfect
        heading), so a policy that flies the path well has almost no gradient left toward the last
        degrees of centering; this kernel is steep exactly there."""
        return float(self.centering_fine_batch(dt, np.array([heading_cos], dtype=float))[0])

    def centering_fine_batch(self, dt: float, heading_cos: np.ndarray) -> np.ndarray:
        """:meth:`centering_fine` of each of the cosines ``heading_cos`` (n,)."""
        return self.centering_fine_weight * dt * np.exp(
            -(1.0 - heading_cos) / (1.0 - math.cos(math.radians(self.centering_fine_scale_deg))))


class FeatureEncoder:
    """Turns one drone's Dict observations into the feature vector (stateful: error integral, last
    action). Call :meth:`reset` at an episode start, :meth:`update` on *every* observation (each
    100 Hz step, also while an action is held) and :meth:`note_action` with each new policy action.
    A validated front over a :class:`~agents.interface.BatchedFeatures` of one drone.
    """

    def __init__(self, config: FeatureConfig, *, standoff: float, dt: float, max_rate: float) -> None:
        if not isinstance(config, FeatureConfig):
            raise ValueError(f"config must be a FeatureConfig, got {type(config).__name__}")
        self.config = config
        self.standoff = check_positive("standoff", standoff)
        self.dt = check_positive("dt", dt)
        self.max_rate = check_positive("max_rate", max_rate)
        self._batch = BatchedFeatures(config, 1, standoff=self.standoff, dt=self.dt, max_rate=self.max_rate)
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode (call at every env reset)."""
        self._batch.reset(0)
        self._features: np.ndarray | None = None

    def note_action(self, action: np.ndarray) -> None:
        """Remember the policy action now being applied (the ``last_action`` feature)."""
        self._batch.note_action(np.asarray(action, dtype=np.float64).reshape(1, 4))
        self._features = None

    def ideal_position(self, obs: Mapping[str, np.ndarray]) -> np.ndarray:
        """The stand-off pose for this observation (updates the remembered horizontal direction)."""
        normal = np.asarray(obs["normal"], dtype=np.float64).reshape(1, 3)
        point = np.asarray(obs["point"], dtype=np.float64).reshape(1, 3)
        return self._batch.ideal_positions(slice(0, 1), normal, point)[0]

    def update(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Consume one observation; returns the feature vector (float32)."""
        self._batch.update(slice(0, 1), {k: np.asarray(v, dtype=np.float64)[None] for k, v in obs.items()})
        self._features = None
        return self.features()

    def pose_error(self) -> np.ndarray:
        """World-frame ``ideal - position`` of the last :meth:`update` [m]."""
        return self._batch.err[0]

    def heading_cos(self) -> float:
        """Cosine of the camera's horizontal heading error at the last :meth:`update`."""
        return self._batch.heading_cos(0)

    def features(self) -> np.ndarray:
        """The feature vector of the last :meth:`update` (and last :meth:`note_action`)."""
        if self._features is None:
            self._features = self._batch.features()[0]
        return self._features


class ResidualHoverAction:
    """Policy action ``u in [-1, 1]^4`` -> the env's normalised action (see the module docstring);
    a validated front over a :class:`~agents.interface.BatchedDecoder`."""

    def __init__(self, config: ActionConfig, scaling: ActionScaling) -> None:
        if not isinstance(config, ActionConfig):
            raise ValueError(f"config must be an ActionConfig, got {type(config).__name__}")
        self.config = config
        self.scaling = scaling
        self.hover_thrust = scaling.hover_thrust
        self._batch = BatchedDecoder(config, scaling)

    def _checked(self, u: Any, quaternion: Any) -> tuple[np.ndarray, np.ndarray]:
        u = check_array("policy action", u, (4,))
        if np.any(np.abs(u) > 1.0 + 1e-6):
            raise ValueError(f"policy action must lie in [-1, 1]^4, got {np.array2string(u)}")
        return u[None], check_array("quaternion", quaternion, (4,))[None]

    def command(self, u: Any, quaternion: Any) -> np.ndarray:
        """The physical command ``[p, q, r, T]`` (before saturation at the airframe's bounds)."""
        return self._batch.command(*self._checked(u, quaternion))[0]

    def __call__(self, u: Any, quaternion: Any) -> np.ndarray:
        """The env's normalised action (float32) for policy action ``u`` at attitude ``quaternion``."""
        return self._batch.decode(*self._checked(u, quaternion))[0]


def encoder_for(env: gym.Env, spec: AgentSpec) -> FeatureEncoder:
    """A :class:`FeatureEncoder` with the env's stand-off, control period and rate bound."""
    u = env.unwrapped
    space = getattr(u, "single_observation_space", None) or u.observation_space
    check_entries(spec.features.groups, getattr(space, "spaces", {}) or {})
    return FeatureEncoder(spec.features, standoff=u.config.standoff, dt=u.dt, max_rate=u.scaling.max_rate)


class InspectionAgentEnv(gym.Wrapper):
    """Training view of an inspection env: Box features in, residual-hover actions out, each held
    for ``action_repeat`` control steps (rewards summed over them, plus the optional
    :class:`ShapingConfig` term; the episode ends on the first ``terminated``/``truncated`` step).
    ``info`` is the last control step's, plus ``env_steps`` (control steps this agent step took)
    and ``shaping_reward``."""

    def __init__(self, env: gym.Env, spec: AgentSpec | None = None, shaping: ShapingConfig | None = None) -> None:
        super().__init__(env)
        self.spec_ = spec = spec if spec is not None else AgentSpec()
        if not isinstance(spec, AgentSpec):
            raise ValueError(f"spec must be an AgentSpec, got {type(spec).__name__}")
        self.shaping = shaping if shaping is not None else ShapingConfig()
        if not isinstance(self.shaping, ShapingConfig):
            raise ValueError(f"shaping must be a ShapingConfig, got {type(self.shaping).__name__}")
        self._coarse_w = self.shaping.distance_coarse_weight * env.unwrapped.dt
        self._dt = env.unwrapped.dt
        self._coarse_k = 1.0 / self.shaping.distance_coarse_scale ** 2
        self.encoder = encoder_for(env, spec)
        self.decoder = ResidualHoverAction(spec.action, env.unwrapped.scaling)
        c = spec.features.clip
        self.observation_space = spaces.Box(-c, c, shape=(spec.features.size,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._raw: dict[str, np.ndarray] | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Reset the inspection env and return the agent's features of its first observation."""
        obs, info = self.env.reset(seed=seed, options=options)
        self.encoder.reset()
        self._raw = obs
        return self.encoder.update(obs), info

    def step(self, action):
        """Apply the policy action for ``action_repeat`` control steps; returns features and the summed reward."""
        if self._raw is None:
            raise RuntimeError("call reset() before step()")
        u = np.asarray(action, dtype=np.float64)
        self.decoder(u, self._raw["quaternion"])      # validates u before anything moves
        self.encoder.note_action(u)
        total = shaped = 0.0
        obs = self._raw
        n_steps = 0
        for _ in range(self.spec_.action_repeat):
            # the held *policy* action is decoded at every control step with the current attitude
            obs, reward, terminated, truncated, info = self.env.step(self.decoder(u, obs["quaternion"]))
            n_steps += 1
            self.encoder.update(obs)
            total += reward
            if self._coarse_w > 0.0 and not terminated:
                e2 = float(self.encoder.pose_error() @ self.encoder.pose_error())
                shaped += self._coarse_w / (1.0 + self._coarse_k * e2)
            if self.shaping.centering_fine_weight > 0.0 and not terminated:
                shaped += self.shaping.centering_fine(self._dt, self.encoder.heading_cos())
            if terminated or truncated:
                break
        self._raw = obs
        info["env_steps"] = n_steps
        info["shaping_reward"] = shaped
        total += shaped
        return self.encoder.features(), float(total), terminated, truncated, info


class EpisodeVariants(gym.Env):
    """Picks one of several environments (same spaces) at every reset: domain randomisation over
    conditions an env fixes at construction, such as the wind. ``weights`` (default equal) set how
    often each is drawn; the draw and each inner env's reset seed come from a Generator seeded by
    the first seeded reset, so a seeded run is reproducible. ``info["variant"]`` names the index."""

    def __init__(self, envs: list[gym.Env], weights: list[float] | None = None) -> None:
        super().__init__()
        if not envs:
            raise ValueError("EpisodeVariants needs at least one environment")
        first = envs[0]
        for i, e in enumerate(envs[1:], 1):
            if e.observation_space != first.observation_space or e.action_space != first.action_space:
                raise ValueError(f"environment variant {i} has other observation/action spaces than variant 0")
        w = np.ones(len(envs)) if weights is None else np.array(
            [check_positive(f"variant weight[{i}]", v) for i, v in enumerate(weights)])
        if len(w) != len(envs):
            raise ValueError(f"variant weights must have {len(envs)} entries, got {len(w)}")
        self.envs = list(envs)
        self.p = w / w.sum()
        self.observation_space = first.observation_space
        self.action_space = first.action_space
        self._rng: np.random.Generator | None = None
        self.active: int | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Draw the next episode's variant (seeded by ``seed``) and reset it."""
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        self.active = int(self._rng.choice(len(self.envs), p=self.p))
        obs, info = self.envs[self.active].reset(seed=int(self._rng.integers(2**31 - 1)), options=options)
        info["variant"] = self.active
        return obs, info

    def step(self, action):
        """Step the variant drawn at the last reset."""
        if self.active is None:
            raise RuntimeError("call reset() before step()")
        obs, reward, terminated, truncated, info = self.envs[self.active].step(action)
        info["variant"] = self.active
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Close every variant's env."""
        for e in self.envs:
            e.close()
        super().close()


class FeatureNormalization:
    """The observation normalisation a saved agent was trained behind: VecNormalize's running mean
    and variance frozen at the end of training, ``clip((x - mean) / sqrt(var + eps), -clip, clip)``.
    The network only ever saw normalised features, so every deployment path (the controller
    :class:`agents.policy.SB3Policy`, the :class:`AgentObservationEnv` for plain SB3 ``predict``)
    applies these same numbers, from the model's sidecar."""

    def __init__(self, mean: Any, var: Any, *, clip: float, epsilon: float, size: int) -> None:
        self.mean = check_array("obs_normalization mean", mean, (None,))
        v = check_array("obs_normalization var", var, (None,))
        if self.mean.shape != (size,) or v.shape != (size,):
            raise ValueError(f"obs_normalization must have {size} entries (the spec's feature size), "
                             f"got {self.mean.shape[0]}")
        self.std = np.sqrt(v + check_positive("obs_normalization epsilon", epsilon, allow_zero=True))
        self.clip = check_positive("obs_normalization clip_obs", clip)

    @classmethod
    def from_sidecar(cls, doc: Mapping[str, Any], size: int) -> "FeatureNormalization":
        """From a sidecar's ``obs_normalization`` entry (``mean``, ``var``, ``clip_obs``, ``epsilon``)."""
        return cls(doc["mean"], doc["var"], clip=doc["clip_obs"], epsilon=doc["epsilon"], size=size)

    def __call__(self, features: np.ndarray) -> np.ndarray:
        """The features normalised by the saved statistics and clipped to [-clip, clip] (float32)."""
        return np.clip((features - self.mean) / self.std, -self.clip, self.clip).astype(np.float32)


class AgentObservationEnv(gym.ObservationWrapper):
    """An inspection env exactly as a saved agent sees it, so the bare stable-baselines3 model works
    on it: ``model.predict(obs)`` takes this wrapper's observation and its action goes straight to
    ``step``. Why it is needed: the model's network maps the agent's normalised feature vector
    (27 numbers for the shipped agents) to a residual-to-hover action held for ``action_repeat``
    control steps, while the env speaks a Dict observation and a normalised body-rate command.

    It is :class:`InspectionAgentEnv` (features, action decoding and holding, the training rewards)
    followed by the model's :class:`FeatureNormalization`; build it with
    :func:`agents.policy.agent_env`, which reads both from the model's sidecar. The trajectory is
    the one :class:`agents.policy.SB3Policy` flies on the raw env (tested)."""

    def __init__(self, env: InspectionAgentEnv, normalization: FeatureNormalization | None) -> None:
        if not isinstance(env, InspectionAgentEnv):
            raise ValueError(f"env must be an InspectionAgentEnv, got {type(env).__name__}")
        super().__init__(env)
        self.normalization = normalization
        if normalization is not None:
            c = normalization.clip
            self.observation_space = spaces.Box(-c, c, shape=env.observation_space.shape, dtype=np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        """The observation as the model takes it: normalised if the agent was trained with normalisation."""
        if self.normalization is None:
            return np.asarray(observation, dtype=np.float32)
        return self.normalization(observation)
