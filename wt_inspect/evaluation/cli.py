"""``wt-inspect evaluate``: run controllers on a scenario, write the table, run files and figures.

Example (the paper's table; ~10 min on 2 cores)::

    wt-inspect evaluate --scenario paper --controllers vtnmpc,nmpc,pampc --winds 0,4,7 --out results/paper

The same sweep from a file (``--config examples/paper.toml``; see :mod:`.config`), flags given on
the command line overriding the file's keys::

    wt-inspect evaluate --config examples/paper.toml --winds 4 --out out/paper_w4

Exit codes: 0 done, 2 bad arguments or an unwritable output directory (nothing is written), 130
interrupted by SIGINT or SIGTERM, with any --jobs and in any phase (finished runs are kept,
results.md / results.csv list them marked "Incomplete: k of n"; rerun the same command to resume).
"""
from __future__ import annotations

import argparse
import sys
from typing import Any

from wt_inspect.commands.args import json_object as _json
from wt_inspect_env.util.figure_io import DEFAULT_FIGURE_FORMAT, FIGURE_FORMATS
from wt_inspect_env.util.interrupts import EXIT_INTERRUPTED, interrupted_message, interrupts_raise, signal_name

from . import OutputDirError, command_line, run_evaluation
from .backends import BACKENDS
from .config import EvaluateConfig, load_config
from .registry import argument_form, entries, valid_names
from .scenarios import SCENARIOS, WIND_TYPES


def _list(kind: type, name: str):
    def parse(text: str) -> list:
        out = []
        for part in text.split(","):
            part = part.strip()
            if not part:
                continue
            try:
                out.append(kind(part))
            except ValueError:
                raise argparse.ArgumentTypeError(f"{name} must be a comma-separated list of "
                                                 f"{'integers' if kind is int else 'numbers'}, got {part!r}") from None
        if not out:
            raise argparse.ArgumentTypeError(f"{name} must not be empty")
        return out
    return parse


def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect evaluate`` (its epilog lists the scenarios)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="scenarios:\n" + "\n".join(f"  {k:<8} {s.description} (winds "
                                                                  f"{', '.join(f'{w:g}' for w in s.winds)})"
                                                                  for k, s in SCENARIOS.items())
                                 + "\ncontrollers (registered entry points):\n"
                                 + "\n".join(f"  {argument_form(k):<13} {e.description}"
                                             for k, e in entries().items()))
    # Every default is None here: the defaults live in EvaluateConfig, so a flag that was not
    # given cannot override a key of --config.
    ap.add_argument("--config", metavar="FILE", help="TOML file with any of the options below (keys: the option "
                    "names with _ for -; figures/progress = false for --no-figures/--no-progress); flags override it")
    ap.add_argument("--scenario", help=f"one of {', '.join(SCENARIOS)} (default paper)")
    ap.add_argument("--controllers", help="comma-separated (default vtnmpc,nmpc,pampc)")
    ap.add_argument("--winds", type=_list(float, "--winds"), metavar="W,...",
                    help="mean wind speeds [m/s] (default: the scenario's)")
    ap.add_argument("--seeds", type=_list(int, "--seeds"), metavar="S,...", help="(default 0)")
    ap.add_argument("--out", metavar="DIR", help="output directory (created if missing; required here or in --config)")
    ap.add_argument("--backend", choices=BACKENDS, help="local process pool or Ray (default local)")
    ap.add_argument("--address", help="Ray cluster address ('auto', 'ray://host:10001'); default: start a local one")
    ap.add_argument("--jobs", type=int, metavar="N", help="parallel runs (default: the number of cores)")
    ap.add_argument("--max-time", type=float, metavar="S", help="cap each run at S simulated seconds (quick runs)")
    w = ap.add_argument_group("overrides")
    w.add_argument("--wind-type", choices=WIND_TYPES, help="(default gust, the paper's)")
    w.add_argument("--wind-options", type=_json("--wind-options"), metavar="JSON",
                   help="extra wind options, e.g. '{\"direction\": [1, 0, 0]}'")
    w.add_argument("--turbine", type=_json("--turbine"), metavar="JSON",
                   help="TurbineSpec fields, e.g. '{\"blade_length\": 40}'")
    w.add_argument("--drone", metavar="PRESET", help="drone preset (matrice100, lab250)")
    w.add_argument("--env", type=_json("--env"), metavar="JSON",
                   help="other environment options, e.g. '{\"start_noise\": 0.5, \"reference_mode\": \"open_loop\"}'")
    o = ap.add_argument_group("output")
    o.add_argument("--record-every", type=int, metavar="K",
                   help="keep every K-th step in the run files (default 1: all)")
    o.add_argument("--no-figures", action="store_true", default=None, help="skip the figures")
    o.add_argument("--figure-format", choices=FIGURE_FORMATS,
                   help=f"format of the figures (default {DEFAULT_FIGURE_FORMAT}; pdf and svg are vector)")
    o.add_argument("--no-progress", action="store_true", default=None, help="no progress bars")
    o.add_argument("--rerun", action="store_true", default=None,
                   help="ignore finished runs in DIR/runs and run everything again")
    ap.add_argument("--trust-model", action="store_true", default=None,
                    help="load ppo: model files even if that runs code stored in them (refused otherwise); "
                         "only for files you made yourself or fully trust")
    return ap


def _flags(args: argparse.Namespace) -> dict[str, Any]:
    """The options given on the command line, under their config keys (None: not given)."""
    controllers = None
    if args.controllers is not None:
        controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
        if not controllers:
            raise ValueError(f"--controllers is empty; valid: {valid_names()}")
    return {"scenario": args.scenario, "controllers": controllers, "winds": args.winds, "seeds": args.seeds,
            "out": args.out, "backend": args.backend, "address": args.address, "jobs": args.jobs,
            "max_time": args.max_time, "wind_type": args.wind_type, "wind_options": args.wind_options,
            "turbine": args.turbine, "drone": args.drone, "env": args.env, "record_every": args.record_every,
            "figures": False if args.no_figures else None, "figure_format": args.figure_format,
            "progress": False if args.no_progress else None, "rerun": True if args.rerun else None,
            "trust_model": True if args.trust_model else None}


def resolve(args: argparse.Namespace) -> EvaluateConfig:
    """The sweep the parsed arguments ask for: the defaults, then the ``--config`` file, then the
    flags given (ValueError naming the file and key, or the flag, on bad input)."""
    base = load_config(args.config) if args.config is not None else EvaluateConfig()
    return base.merged(_flags(args))


def main(argv: list[str], prog: str = "wt-inspect evaluate") -> int:
    """``wt-inspect evaluate``: run the evaluation given by ``argv``; returns the exit code."""
    with interrupts_raise():   # SIGTERM = Ctrl-C from here on, whatever --jobs
        try:
            return _main(argv, prog)
        except KeyboardInterrupt as exc:   # before the sweep started: nothing was written
            print(f"\n{prog}: interrupted ({signal_name(exc)}) before any run started; nothing written",
                  file=sys.stderr)
            return EXIT_INTERRUPTED


def _main(argv: list[str], prog: str) -> int:
    args = build_parser(prog).parse_args(argv)
    try:
        cfg = resolve(args)
        kwargs = cfg.run_kwargs()
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    # a results file made from a config file says how to rerun it without the file
    command = cfg.command(prog) if args.config is not None else command_line(argv, prog)
    try:
        ev = run_evaluation(**kwargs, command=command)
    except OutputDirError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"\n{prog}: {interrupted_message(exc, cfg.out, 'runs')}", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"{len(ev.results)} runs ({ev.n_ran} executed, {ev.n_resumed} resumed) in {ev.wall_time_s:.1f} s; wrote "
          f"{ev.files['csv']}, {ev.files['md']}" + (f" and {len(ev.files.get('figures', []))} figures"
                                                    if ev.files.get("figures") else ""))
    return 0
