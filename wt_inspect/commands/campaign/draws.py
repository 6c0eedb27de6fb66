"""What a campaign flies: its configuration and the episodes drawn from the master seed."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from wt_inspect_env.physics.wind import MAX_WIND_SPEED
from wt_inspect_env.task.turbine_draws import (  # noqa: F401 - the campaign's turbines, re-exported for its report
    NREL_SCALE_RANGE,
    NREL_SCALED_LENGTHS,
    SIZE_RANGES,
    TURBINE_KINDS,
    TurbineDistribution,
)

from ...evaluation import registry
from ...evaluation.runner import RunSpec, make_spec

SCENARIO = "campaign"


WIND_DIRECTION_RANGE_DEG = (-180.0, 180.0)   # any horizontal direction, from the rotor axis (+y)


# Domain randomisation of the airframe (the plant PyBullet integrates; the controllers keep the
# nominal model): the environment's default scale ranges, sensor noise and command latency off.
AIRFRAME_RANDOMIZATION: Mapping[str, Any] = {
    "mass": [0.9, 1.1], "inertia": [0.8, 1.2], "drag": [0.7, 1.3], "thrust": [0.95, 1.05],
    "torque_coeff": [0.8, 1.2], "motor_time_constant": [0.75, 1.25],
    "position_noise": [0.0, 0.0], "velocity_noise": [0.0, 0.0], "attitude_noise": [0.0, 0.0],
    "rate_noise": [0.0, 0.0], "latency_steps": [0, 0]}


# A drawn start nearer the turbine than this fraction of d_ref (the MPCs' default d_min, 3 m at 7 m)
# is a start inside or against the structure - a bad draw, not a test of the controller: its
# direction is redrawn (same distance) from a generator seeded by the episode's seed.
START_CLEARANCE_RATIO = 3.0 / 7.0


MAX_START_REDRAWS = 100


# Upper bound of --episodes: every episode's draw and run spec is made before the first flies
# (so a campaign resumes and its report knows what is missing), a few kB each. 10 000 episodes
# are weeks of flight on a workstation, far beyond the README's 200; a larger number is a typo
# (10**12 would grow memory for hours before the first episode).
MAX_EPISODES = 10_000


@dataclass(frozen=True)
class CampaignConfig:
    """What a campaign draws and flies (the command-line options). ``only``: fly just these
    episode numbers of the campaign (same draws: a re-fly of single episodes)."""

    episodes: int = 200
    controller: str = "vtnmpc-plus"
    seed: int = 0
    task: str = "full"
    max_wind: float = 10.0
    max_offset: float = 30.0
    max_time: float | None = None
    record_every: int = 10
    airframe_randomization: bool = True
    only: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        for name in ("episodes", "seed", "record_every"):
            v = getattr(self, name)
            lo = 0 if name == "seed" else 1
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if self.episodes > MAX_EPISODES:
            raise ValueError(f"episodes must be at most {MAX_EPISODES:,} (every draw is planned before the first "
                             f"episode flies; split a larger study into campaigns with other --seed), "
                             f"got {self.episodes!r}")
        for name, hi in (("max_wind", MAX_WIND_SPEED), ("max_offset", 1000.0)):
            v = getattr(self, name)
            if isinstance(v, (bool, str)) or not isinstance(v, (int, float)) or not 0 <= v <= hi:
                raise ValueError(f"{name} must be a number in [0, {hi:g}], got {v!r}")
        if self.max_time is not None and (isinstance(self.max_time, (bool, str))
                                          or not isinstance(self.max_time, (int, float)) or not self.max_time > 0):
            raise ValueError(f"max_time must be a positive number of simulated seconds, got {self.max_time!r}")
        if self.task not in ("full", "blade", "surface"):
            raise ValueError(f"unknown task {self.task!r}; valid: full, blade, surface")
        if not isinstance(self.airframe_randomization, bool):
            raise ValueError(f"airframe_randomization must be true or false, got {self.airframe_randomization!r}")
        if self.only is not None:
            bad = [k for k in self.only if isinstance(k, bool) or not isinstance(k, int)
                   or not 0 <= k < self.episodes]
            if bad or not self.only:
                raise ValueError(f"only must name episodes in [0, {self.episodes - 1}], got {list(self.only)!r}")
            object.__setattr__(self, "only", tuple(sorted(set(self.only))))


def draw_episodes(cfg: CampaignConfig) -> list[dict[str, Any]]:
    """The episodes' random draws (plain data), all from the master seed: the same seed gives
    the same campaign, episode k does not depend on how many episodes follow it, and nothing
    depends on the controller. Every episode takes the same number of variates (the sizes and the
    scale are drawn whichever turbine kind is used), which keeps the prefix property."""
    from gymnasium.utils.seeding import np_random
    rng, _ = np_random(cfg.seed)
    turbines = TurbineDistribution()
    out = []
    for k in range(cfg.episodes):
        t = turbines.draw(rng)
        wind = float(rng.uniform(0.0, cfg.max_wind))
        direction_deg = float(rng.uniform(*WIND_DIRECTION_RANGE_DEG))
        r = float(rng.uniform(0.0, cfg.max_offset))
        v = rng.normal(size=3)
        v[2] = abs(v[2])
        offset = (r * v / max(float(np.linalg.norm(v)), 1e-12)).tolist()
        seed = int(rng.integers(0, 2**31 - 1))
        out.append({"episode": k, "seed": seed, "turbine": t.kind, "turbine_scale": t.scale, "turbine_spec": t.spec,
                    "wind": wind, "wind_direction_deg": direction_deg, "rotor_azimuth_deg": t.rotor_azimuth_deg,
                    "start_offset": offset, "start_offset_m": r, **t.sizes})
    return out


def episode_options(draw: Mapping[str, Any], task: str, airframe_randomization: bool = True) -> dict[str, Any]:
    """The ``gym.make`` options of one drawn episode (the turbine faces +y: wind direction is
    measured from it)."""
    a = math.radians(draw["wind_direction_deg"])
    wind: Any = "none" if draw["wind"] <= 0.0 else {
        "type": "dryden", "mean_speed": draw["wind"], "direction": [math.sin(a), math.cos(a), 0.0]}
    opts = {"task": task, "wind": wind, "rotor_turn_deg": None, "start_offset": list(draw["start_offset"]),
            "turbine": {**draw["turbine_spec"], "rotor_azimuth_deg": draw["rotor_azimuth_deg"]}}
    if airframe_randomization:
        opts["randomization"] = dict(AIRFRAME_RANDOMIZATION)
    return opts


def campaign_specs(cfg: CampaignConfig) -> tuple[list[dict[str, Any]], list[RunSpec]]:
    """The draws and run specs of the episodes the campaign flies (all, or ``cfg.only``). The
    controller's runs get the env options it needs (an agent that observes the structure), as in
    ``evaluate``; the drawn options take precedence."""
    registry.check_controller(cfg.controller)
    needs = registry.env_options(cfg.controller)
    draws = draw_episodes(cfg)
    if cfg.only is not None:
        draws = [draws[k] for k in cfg.only]
    specs = [make_spec(SCENARIO, cfg.controller, d["wind"], d["seed"],
                       {**needs, **episode_options(d, cfg.task, cfg.airframe_randomization)},
                       cfg.max_time, cfg.record_every)
             for d in draws]
    return draws, specs


def clear_start(env: Any, spec: RunSpec) -> tuple[list[float], int]:
    """The episode's start offset with its start at least ``START_CLEARANCE_RATIO * d_ref`` from
    the turbine: the drawn one, or the first of up to ``MAX_START_REDRAWS`` directions redrawn
    (same length, no downward part) that is. Returns the offset and the number of redraws."""
    from wt_inspect_env.planner.proximity import MeshProximity
    u = env.unwrapped
    near = MeshProximity(u.mission.turbines[0].mesh.triangles)   # the start's rotor position only
    need = START_CLEARANCE_RATIO * float(u.config.standoff)
    offset = np.asarray(spec.env_options.get("start_offset", (0.0, 0.0, 0.0)), dtype=float)
    r = float(np.linalg.norm(offset))
    rng = np.random.default_rng(spec.seed)
    for k in range(MAX_START_REDRAWS + 1):
        u.reset(seed=spec.seed, options={"start_offset": offset.tolist()})
        if float(near.distance(u.sim.state[0:1, 0:3])[0]) >= need:
            return offset.tolist(), k
        v = rng.normal(size=3)
        v[2] = abs(v[2])
        offset = r * v / max(float(np.linalg.norm(v)), 1e-12)
    raise RuntimeError(f"no start {r:.1f} m off the first pose is {need:.1f} m clear of the turbine "
                       f"after {MAX_START_REDRAWS} directions")


def controller_dir(controller: str) -> str:
    """Sub-directory of one controller's campaign in a comparison (``ppo:x`` -> ``ppo-x``)."""
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in controller)
