"""``wt-inspect campaign``: a robustness campaign - many randomised whole missions of one or several controllers.

Example (the README's robustness goal; hours on 2 cores)::

    wt-inspect campaign --episodes 200 --controllers vtnmpc-plus,ppo:ppo_full_vec128 --out results/campaign

Each episode is flown to the mission's end or its time limit (the environment's, 1.5 x the
nominal mission time + 30 s); ``--max-time S`` caps it at S simulated seconds for quick runs.

Each episode draws, from one master seed (``--seed``, through ``gymnasium.utils.seeding.np_random``;
episode k's draw does not depend on the controller or on how many episodes follow it):

* a turbine (:data:`TURBINE_KINDS`): a generated one (tower height, blade length and width
  within :data:`SIZE_RANGES`, the paper's cuboid blade), the ``nrel-5mw`` preset as published, or
  the ``nrel-5mw`` scaled geometrically by a factor in :data:`NREL_SCALE_RANGE` (every length of
  the preset: tower, blade, hub, overhang, nacelle);
* a rotor azimuth in [0, 120) deg with the planner choosing the rotor turns (``rotor_turn_deg=None``);
* a mean wind in [0, ``--max-wind``] m/s with Dryden turbulence, from any horizontal direction
  (measured from the rotor axis, +y);
* a start up to ``--max-offset`` m off the ideal stand-off pose (a random direction with no
  downward part, so a start is not under ground; a start nearer the turbine than 3/7 d_ref -
  inside or against the structure - gets a new direction, ``START_CLEARANCE_RATIO``);
* the episode's reset seed, from which the environment draws the airframe's domain randomisation
  (:data:`AIRFRAME_RANDOMIZATION`: mass, inertia, drag, thrust, torque coefficient and motor lag
  of the plant; no sensor noise, no latency; ``--no-airframe-randomization`` switches it off).

Every episode runs through the evaluation harness's backends (the local process pool or Ray, as
``evaluate``) and is recorded: a row of ``episodes.csv`` and its trajectory in
``runs/<name>.npz`` (the evaluation's run-file format). An exception in an episode - building
the turbine, planning, the controller, the simulator - is caught in that episode and recorded
with its message; the campaign goes on.

Reported per episode (``episodes.csv``, ``campaign.json``): coverage, SM, CM, the minimum
clearance to the structure and the time below d_min (:mod:`~wt_inspect.evaluation.harness_metrics`),
the minimum distance to the inspection point, collisions, crashes, completion, QP fallbacks
(``last_stats.fallback`` of the MPC), the worker's resident set size after the episode, energy
and path length. ``results.md`` and ``campaign.png`` give the distribution of each metric and the
worst episodes, each with the exact command that flies that one episode again (``--only K``: the
same draw and run spec, so the same numbers). With several controllers (``--controllers a,b``)
each flies the same episodes into ``DIR/<controller>/`` and ``DIR/comparison.md`` (``.csv``,
``.json``, ``.png``) compares them. Wall time is summed over the invocations of a resumed
campaign (``wall_time_s``; each invocation's in ``wall_time_invocations_s``).

Exit code 0 when the campaign ran (whatever it found), 2 for bad arguments or an unwritable
``--out``, 130 when interrupted.

The package: :mod:`.draws` (configuration and the episodes' draws), :mod:`.running` (flying the
episodes, resumed), :mod:`.summary` (rows and distributions), :mod:`.report` (the files, the
comparison of controllers) and :mod:`.cli` (the command line).
"""
from __future__ import annotations

from .cli import build_parser, configs_from_args, main
from .draws import (
                    AIRFRAME_RANDOMIZATION,
                    MAX_EPISODES,
                    NREL_SCALE_RANGE,
                    SCENARIO,
                    SIZE_RANGES,
                    START_CLEARANCE_RATIO,
                    TURBINE_KINDS,
                    CampaignConfig,
                    campaign_specs,
                    clear_start,
                    controller_dir,
                    draw_episodes,
                    episode_options,
)
from .report import config_json, write_comparison
from .running import earlier_invocations, run_campaign, run_comparison, run_episode
from .summary import episode_row, summarise

__all__ = ["AIRFRAME_RANDOMIZATION", "MAX_EPISODES", "NREL_SCALE_RANGE", "SCENARIO", "SIZE_RANGES",
           "START_CLEARANCE_RATIO", "TURBINE_KINDS", "CampaignConfig", "build_parser", "campaign_specs", "clear_start",
           "config_json", "configs_from_args", "controller_dir", "draw_episodes", "earlier_invocations",
           "episode_options", "episode_row", "main", "run_campaign", "run_comparison", "run_episode", "summarise",
           "write_comparison"]
