"""The ``wt-inspect campaign`` command line."""
from __future__ import annotations

import argparse
import sys
from typing import Any, Mapping

from wt_inspect_env.util.interrupts import EXIT_INTERRUPTED, interrupted_message, interrupts_raise

from ...evaluation.backends import BACKENDS
from .draws import CampaignConfig
from .running import run_campaign, run_comparison
from .summary import fmt


def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect campaign`` (defaults from :class:`CampaignConfig`)."""
    d = CampaignConfig()
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=d.episodes, help=f"(default {d.episodes})")
    ap.add_argument("--controller", help=f"a registered controller (default {d.controller})")
    ap.add_argument("--controllers", metavar="A,B,...",
                    help="comma-separated registered controllers (e.g. vtnmpc-plus,ppo:ppo_full_vec128): the same "
                         "episodes for each, into DIR/<controller>/, and DIR/comparison.md comparing them")
    ap.add_argument("--out", required=True, metavar="DIR")
    ap.add_argument("--seed", type=int, default=d.seed, help="master seed of every draw (default 0)")
    ap.add_argument("--task", default=d.task, choices=["full", "blade", "surface"], help="(default full)")
    ap.add_argument("--max-wind", type=float, default=d.max_wind, metavar="M/S", help="(default 10)")
    ap.add_argument("--max-offset", type=float, default=d.max_offset, metavar="M", help="start offset (default 30)")
    ap.add_argument("--max-time", type=float, metavar="S",
                    help="cap each episode at S simulated seconds (quick runs; default: no cap, every episode flies "
                         "to the mission's end or its time limit)")
    ap.add_argument("--no-airframe-randomization", action="store_true",
                    help="fly the nominal airframe (default: per-episode mass, inertia, drag, thrust, torque and "
                         "motor-lag draws)")
    ap.add_argument("--only", metavar="K,...",
                    help="fly only these episode numbers of the campaign (the re-fly commands in results.md)")
    ap.add_argument("--record-every", type=int, default=d.record_every, metavar="K",
                    help=f"keep every K-th step in the trajectory files (default {d.record_every})")
    ap.add_argument("--backend", default="local", choices=BACKENDS)
    ap.add_argument("--ray", action="store_true", help="same as --backend ray")
    ap.add_argument("--address", help="Ray cluster address (default: a local instance)")
    ap.add_argument("--jobs", type=int, metavar="N", help="parallel episodes (default: the number of cores)")
    ap.add_argument("--no-figure", action="store_true")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def main(argv: list[str], prog: str = "wt-inspect campaign") -> int:
    """``wt-inspect campaign``: run (or resume) the campaign given by ``argv``; returns the exit code."""
    with interrupts_raise():   # SIGTERM = Ctrl-C from the start, whatever --jobs
        return _main(argv, prog)


def _int_list(text: str, what: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ValueError(f"{what} must be comma-separated episode numbers, got {text!r}") from None


def configs_from_args(args: argparse.Namespace) -> list[CampaignConfig]:
    """One campaign configuration per controller the parsed command line names, in its order
    (ValueError for a bad combination)."""
    if args.controller and args.controllers:
        raise ValueError("give --controller or --controllers, not both")
    controllers = ([c.strip() for c in args.controllers.split(",") if c.strip()] if args.controllers
                   else [args.controller or CampaignConfig().controller])
    if not controllers:
        raise ValueError(f"--controllers names no controller: {args.controllers!r}")
    only = _int_list(args.only, "--only") if args.only is not None else None
    return [CampaignConfig(episodes=args.episodes, controller=c, seed=args.seed, task=args.task,
                           max_wind=args.max_wind, max_offset=args.max_offset, max_time=args.max_time,
                           record_every=args.record_every, airframe_randomization=not args.no_airframe_randomization,
                           only=only) for c in controllers]


def _main(argv: list[str], prog: str) -> int:
    args = build_parser(prog).parse_args(argv)
    from ...evaluation import command_line
    backend = "ray" if args.ray else args.backend
    try:
        configs = configs_from_args(args)
        cfg = configs[0]
        controllers = [c.controller for c in configs]
        kw = {"backend": backend, "jobs": args.jobs, "address": args.address, "progress": not args.no_progress,
              "figure": not args.no_figure, "command": command_line(argv, prog)}
        if len(set(controllers)) > 1:
            cmp = run_comparison(cfg, controllers, args.out, **kw)
        else:
            doc = run_campaign(cfg, args.out, **kw)
    except ValueError as exc:   # OutputDirError included
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"\n{prog}: "
              f"{interrupted_message(exc, args.out, 'episodes', 'results.md, episodes.csv and campaign.json')}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    if len(set(controllers)) > 1:
        for c in cmp["controllers"]:
            print(f"{c}: {_summary_line(cmp['summary'][c])}")
        print(f"wrote {args.out}/comparison.md, comparison.csv, comparison.json and one directory per controller")
        return 0
    s = doc["summary"]
    print(f"{_summary_line(s)}; wall time {doc['wall_time_this_invocation_s']:.0f} s in this invocation, "
          f"{doc['wall_time_s']:.0f} s over {len(doc['wall_time_invocations_s'])}; wrote {args.out}/results.md, "
          "campaign.json, episodes.csv")
    return 0


def _summary_line(s: Mapping[str, Any]) -> str:
    cov = s["distribution"]["coverage"]
    return (f"{s['episodes']} episodes: {s['mission_complete']} completed, {s['exceptions']} exceptions, "
            f"{s['non_finite_states']} non-finite states, {s['crashes']} crashes, {s['episodes_with_collisions']} "
            f"with collisions, {s['clearance_below_d_min']} below d_min, median coverage "
            f"{fmt(cov['median'], 100, 1)} %, QP fallbacks {100 * s['fallback_fraction']:.4f} % of {s['steps']} "
            f"steps, RSS {s['rss_first_mb']:.0f} -> {s['rss_last_mb']:.0f} MB")
