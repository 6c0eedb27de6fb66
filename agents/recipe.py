"""Training recipes: every hyperparameter of a run in one JSON file (``agents/recipes/*.json``).

A recipe names the algorithm, the environment options used for training and for evaluation
(``gym.make`` keyword options, so reward weights, wind, start noise and episode length are set
there), the agent interface (:class:`~agents.wrappers.AgentSpec`), observation / reward
normalisation, the algorithm's keyword arguments and the network. Unknown keys are a ValueError
listing the valid ones, so a misspelt hyperparameter never silently falls back to a default.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from wt_inspect_env.physics.wind import make_wind
from wt_inspect_env.task.env_config import EnvConfig
from wt_inspect_env.util.validation import check_choice, check_positive, check_unknown_options

from .policy import ALGOS
from .safe_load import ACTIVATIONS
from .wrappers import AgentSpec, ShapingConfig

RECIPE_DIR = Path(__file__).resolve().parent / "recipes"
NORMALIZE_KEYS: tuple[str, ...] = ("obs", "reward", "clip_obs", "clip_reward")


def _check_env_options(options: Mapping[str, Any]) -> None:
    """Validate ``gym.make`` options without building an env (the wind spec is checked by building
    the wind field: EnvConfig keeps it as given)."""
    cfg = EnvConfig.from_kwargs(**dict(options))
    make_wind(cfg.wind)


TARGET_METRICS: tuple[str, ...] = ("coverage", "safety_sm", "centering_cm")
#: distances a target may also ask for [m]: the least clearance to the structure over the
#: evaluation (recorded when the env observes the structure) - an agent meant to keep d_min by
#: itself is not done when it only covers the blade
TARGET_DISTANCES: tuple[str, ...] = ("clearance_min_m",)


def check_target(target: Any, name: str = "recipe target") -> dict[str, float]:
    """``{metric: threshold}`` over :data:`TARGET_METRICS` (fractions in (0, 1]) and
    :data:`TARGET_DISTANCES` (positive finite metres)."""
    if not isinstance(target, Mapping) or not target:
        raise ValueError(f"{name} must be a non-empty dict of metric thresholds, got {target!r}")
    check_unknown_options(name, target.keys(), TARGET_METRICS + TARGET_DISTANCES)
    out = {}
    for k, v in target.items():
        number = not isinstance(v, (bool, str)) and isinstance(v, (int, float))
        if k in TARGET_DISTANCES:
            if not number or not math.isfinite(v) or v <= 0.0:
                raise ValueError(f"{name} {k} must be a positive distance in metres, got {v!r}")
        elif not number or not 0.0 < v <= 1.0:
            raise ValueError(f"{name} {k} must be a fraction in (0, 1], got {v!r}")
        out[k] = float(v)
    return out


def _positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return value


@dataclass(frozen=True)
class Recipe:
    """One training recipe (see the module docstring).

    env: ``gym.make`` options for the training envs (``task`` comes from the command line).
    eval_env: options overriding ``env`` for the periodic evaluation (e.g. no start noise, the full
        mission length). eval_variants: option dicts merged over the evaluation's options, each flown
        by every evaluation (``eval_episodes`` each) and the evaluation scored by the worst of them -
        so the kept model is one that does the task in every listed condition (e.g. calm air and the
        7 m/s gust), not the best in one; empty (default): the evaluation options alone.
    env_variants: option dicts merged over ``env``, one drawn per training episode (weights
        ``env_variant_weights``, default equal) - e.g. several wind speeds.
        agent: :class:`AgentSpec` fields. shaping: training-only reward shaping
        (:class:`~agents.wrappers.ShapingConfig`). normalize: VecNormalize switches.
    algo_kwargs: keyword arguments of the stable-baselines3 algorithm; ``learning_rate_final``
        (optional) makes the learning rate decay linearly to it. policy_kwargs: ``net_arch``,
        ``activation_fn`` (a name from ``ACTIVATIONS``) and the algorithm's other policy options.
    eval_every_env_steps / eval_episodes / checkpoint_every_env_steps: in simulator control steps.
    torch_threads: intra-op threads of the learner (1 leaves the other core to the env workers).
    target: the recipe's own acceptance thresholds on the periodic evaluation's means (keys of
        ``TARGET_METRICS``, fractions in (0, 1], or ``TARGET_DISTANCES`` in metres) - a stage of a
        curriculum is judged by what it is for (a surface stage by coverage and SM); the seeds
        report shows it beside the full-mission target of :data:`agents.seeds.TARGET`. None: that
        target only.
    turbines: many turbines in one training run (vector backend): ``{"n_turbines": G,
        "redraw_every": K | "redraw_after_s": T, "distribution": {...}}``
        (:func:`~wt_inspect_env.vector.turbines.many_turbine_kwargs`); the drones fly G worlds on drawn
        turbines, each redrawn every K episodes of its drones or every T simulated seconds.
        None (default): every drone on the turbine of ``env``. The periodic evaluation keeps ``eval_env``'s.
    """

    algo: str = "ppo"
    description: str = ""
    env: dict = field(default_factory=dict)
    eval_env: dict = field(default_factory=dict)
    eval_variants: list = field(default_factory=list)
    env_variants: list = field(default_factory=list)
    env_variant_weights: Any = None
    agent: Any = field(default_factory=AgentSpec)
    shaping: Any = field(default_factory=ShapingConfig)
    normalize: dict = field(default_factory=lambda: {"obs": True, "reward": True})
    algo_kwargs: dict = field(default_factory=dict)
    policy_kwargs: dict = field(default_factory=dict)
    eval_every_env_steps: int = 100_000
    eval_episodes: int = 2
    checkpoint_every_env_steps: int = 200_000
    torch_threads: int = 1
    target: Any = None
    turbines: Any = None

    def __post_init__(self) -> None:
        check_choice("algorithm", self.algo, ALGOS)
        for name in ("env", "eval_env", "normalize", "algo_kwargs", "policy_kwargs"):
            if not isinstance(getattr(self, name), Mapping):
                raise ValueError(f"recipe {name} must be a dict, got {getattr(self, name)!r}")
        for name in ("env", "eval_env"):
            opts = dict(getattr(self, name))
            if "task" in opts:
                raise ValueError(f"recipe {name} must not set 'task' (it comes from --task)")
            _check_env_options({**dict(self.env), **opts})
        self._set_variants("env_variants", dict(self.env))
        self._set_variants("eval_variants", self.eval_env_options())
        w = self.env_variant_weights
        if w is not None:
            if not isinstance(w, (list, tuple)) or len(w) != len(self.env_variants):
                raise ValueError(f"recipe env_variant_weights must be a list of {len(self.env_variants)} "
                                 f"numbers (one per variant), got {w!r}")
            for i, x in enumerate(w):
                check_positive(f"recipe env_variant_weights[{i}]", x)
            object.__setattr__(self, "env_variant_weights", [float(x) for x in w])
        agent = self.agent
        if isinstance(agent, Mapping):
            agent = AgentSpec.from_dict(agent)
        if not isinstance(agent, AgentSpec):
            raise ValueError(f"recipe agent must be an AgentSpec or a dict of its fields, got {agent!r}")
        object.__setattr__(self, "agent", agent)
        shaping = self.shaping
        if isinstance(shaping, Mapping):
            check_unknown_options("recipe shaping", shaping.keys(),
                                  [f.name for f in dataclasses.fields(ShapingConfig)])
            shaping = ShapingConfig(**dict(shaping))
        if not isinstance(shaping, ShapingConfig):
            raise ValueError(f"recipe shaping must be a ShapingConfig or a dict of its fields, got {shaping!r}")
        object.__setattr__(self, "shaping", shaping)
        check_unknown_options("recipe normalize", self.normalize.keys(), NORMALIZE_KEYS)
        for key in ("clip_obs", "clip_reward"):
            if key in self.normalize:
                check_positive(f"recipe normalize {key}", self.normalize[key])
        act = self.policy_kwargs.get("activation_fn")
        if act is not None:
            check_choice("recipe policy_kwargs activation_fn", act, ACTIVATIONS)
        if "learning_rate_final" in self.algo_kwargs:
            check_positive("recipe algo_kwargs learning_rate_final", self.algo_kwargs["learning_rate_final"])
        for name in ("eval_every_env_steps", "eval_episodes", "checkpoint_every_env_steps", "torch_threads"):
            _positive_int(f"recipe {name}", getattr(self, name))
        if self.target is not None:
            object.__setattr__(self, "target", check_target(self.target))
        if self.turbines is not None:
            from wt_inspect_env.vector.turbines import many_turbine_kwargs
            many_turbine_kwargs(self.turbines)
            if "turbine" in self.env or "turbine_mesh" in self.env:
                raise ValueError("recipe turbines (drawn per world) and env turbine / turbine_mesh exclude each other")
            try:
                object.__setattr__(self, "turbines", json.loads(json.dumps(dict(self.turbines))))
            except TypeError:
                raise ValueError(f"recipe turbines must be plain JSON data, got {self.turbines!r}") from None

    def _set_variants(self, name: str, base: dict) -> None:
        """Check the list of option dicts ``name`` (each merged over ``base`` must be valid env
        options, none sets the task) and store it as plain dicts."""
        variants = getattr(self, name)
        if not isinstance(variants, (list, tuple)) or not all(isinstance(v, Mapping) for v in variants):
            raise ValueError(f"recipe {name} must be a list of dicts, got {variants!r}")
        for i, v in enumerate(variants):
            if "task" in v:
                raise ValueError(f"recipe {name}[{i}] must not set 'task'")
            _check_env_options({**base, **dict(v)})
        object.__setattr__(self, name, [dict(v) for v in variants])

    @property
    def spec(self) -> AgentSpec:
        """The agent spec the recipe trains (its ``agent`` field)."""
        return self.agent

    def eval_env_options(self) -> dict:
        """The env options of the periodic evaluation: ``env`` with ``eval_env`` over it."""
        return {**dict(self.env), **dict(self.eval_env)}

    def eval_options_list(self) -> list[dict]:
        """The env options of every env an evaluation flies: :meth:`eval_env_options` with each of
        ``eval_variants`` over it, or those options alone when there are none."""
        base = self.eval_env_options()
        return [{**base, **v} for v in self.eval_variants] or [base]

    def to_dict(self) -> dict[str, Any]:
        """The recipe as plain JSON data (for the model's sidecar and the run's files)."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        d["agent"] = self.agent.to_dict()
        d["shaping"] = dataclasses.asdict(self.shaping)
        if d["turbines"] is None:      # absent as before the option: older runs' recipes and digests stay equal
            del d["turbines"]
        if not d["eval_variants"]:     # likewise
            del d["eval_variants"]
        return json.loads(json.dumps(d))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Recipe":
        """The recipe from its JSON object (unknown keys are an error)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"a recipe must be a JSON object, got {type(data).__name__}")
        check_unknown_options("recipe", data.keys(), [f.name for f in dataclasses.fields(cls)])
        return cls(**dict(data))


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``over`` on top of ``base``: objects merge key by key (recursively), anything else - a list,
    a number, null - replaces the base's value whole."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _read_recipe_data(p: Path, chain: tuple[Path, ...]) -> dict[str, Any]:
    """The JSON object of recipe file ``p`` with its ``base`` (if any) resolved."""
    if not p.is_file():
        where = f" (the base of {str(chain[-1])!r})" if chain else ""
        raise ValueError(f"recipe file {str(p)!r}{where} not found")
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"recipe file {str(p)!r} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"recipe file {str(p)!r} must hold a JSON object, got {type(data).__name__}")
    if "base" not in data:
        return data
    base = data.pop("base")
    if not isinstance(base, str) or not base:
        raise ValueError(f"recipe file {str(p)!r}: base must be the file name of another recipe, got {base!r}")
    base_path = (p.parent / base).resolve()
    if base_path in chain or base_path == p.resolve():
        raise ValueError(f"recipe file {str(p)!r}: base {base!r} leads back to itself "
                         f"({' -> '.join(c.name for c in (*chain, p, base_path))})")
    return _merge(_read_recipe_data(base_path, (*chain, p.resolve())), data)


def load_recipe(path: str | Path) -> Recipe:
    """Read a recipe file (ValueError naming the file if it is missing or not valid JSON).

    A recipe may name another as its ``base`` (a path relative to its own folder): its keys then
    override the base's - objects key by key, lists and values whole - so a training stage states
    only what it changes. The result is the complete recipe, as if written out in full (models,
    sidecars and digests record that, never the ``base`` key).
    """
    return Recipe.from_dict(_read_recipe_data(Path(path), ()))


def default_recipe_path(algo: str) -> Path:
    """``agents/recipes/<algo>_surface.json``: the shipped recipe of an algorithm."""
    check_choice("algorithm", algo, ALGOS)
    return RECIPE_DIR / f"{algo}_surface.json"
