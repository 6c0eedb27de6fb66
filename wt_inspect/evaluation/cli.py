"""``wt-inspect evaluate``: run controllers on a scenario, write the table, run files and figures.

Example (the paper's table; ~10 min on 2 cores)::

    wt-inspect evaluate --scenario paper --controllers vtnmpc,nmpc,pampc --winds 0,4,7 --out results/paper

Exit codes: 0 done, 2 bad arguments or an unwritable output directory (nothing is written), 130
interrupted (finished runs are kept; rerun the same command to resume).
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from . import OutputDirError, command_line, run_evaluation
from .backends import BACKENDS
from .registry import entries, valid_names
from .scenarios import SCENARIOS, WIND_TYPES


def _json(name: str):
    def parse(text: str) -> Any:
        try:
            value = json.loads(text)
        except json.JSONDecodeError as exc:
            raise argparse.ArgumentTypeError(f"{name} must be JSON, e.g. '{{\"key\": 1}}': {exc}") from None
        if not isinstance(value, dict):
            raise argparse.ArgumentTypeError(f"{name} must be a JSON object, got {text!r}")
        return value
    return parse


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
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="scenarios:\n" + "\n".join(f"  {k:<8} {s.description} (winds "
                                                                  f"{', '.join(f'{w:g}' for w in s.winds)})"
                                                                  for k, s in SCENARIOS.items())
                                 + "\ncontrollers (registered entry points):\n"
                                 + "\n".join(f"  {k + (':PATH' if e.takes_argument else ''):<13} {e.description}"
                                             for k, e in entries().items()))
    ap.add_argument("--scenario", default="paper", help=f"one of {', '.join(SCENARIOS)} (default paper)")
    ap.add_argument("--controllers", default="vtnmpc,nmpc,pampc", help="comma-separated (default vtnmpc,nmpc,pampc)")
    ap.add_argument("--winds", type=_list(float, "--winds"), metavar="W,...",
                    help="mean wind speeds [m/s] (default: the scenario's)")
    ap.add_argument("--seeds", type=_list(int, "--seeds"), default=[0], metavar="S,...", help="(default 0)")
    ap.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    ap.add_argument("--backend", default="local", choices=BACKENDS, help="local process pool or Ray (default local)")
    ap.add_argument("--address", help="Ray cluster address ('auto', 'ray://host:10001'); default: start a local one")
    ap.add_argument("--jobs", type=int, metavar="N", help="parallel runs (default: the number of cores)")
    ap.add_argument("--max-time", type=float, metavar="S", help="cap each run at S simulated seconds (quick runs)")
    w = ap.add_argument_group("overrides")
    w.add_argument("--wind-type", default="gust", choices=WIND_TYPES, help="(default gust, the paper's)")
    w.add_argument("--wind-options", type=_json("--wind-options"), default={}, metavar="JSON",
                   help="extra wind options, e.g. '{\"direction\": [1, 0, 0]}'")
    w.add_argument("--turbine", type=_json("--turbine"), default={}, metavar="JSON",
                   help="TurbineSpec fields, e.g. '{\"blade_length\": 40}'")
    w.add_argument("--drone", metavar="PRESET", help="drone preset (matrice100, lab250)")
    w.add_argument("--env", type=_json("--env"), default={}, metavar="JSON",
                   help="other environment options, e.g. '{\"start_noise\": 0.5, \"reference_mode\": \"open_loop\"}'")
    o = ap.add_argument_group("output")
    o.add_argument("--record-every", type=int, default=1, metavar="K",
                   help="keep every K-th step in the run files (default 1: all)")
    o.add_argument("--no-figures", action="store_true", help="skip the figures")
    o.add_argument("--no-progress", action="store_true", help="no progress bars")
    o.add_argument("--rerun", action="store_true", help="ignore finished runs in DIR/runs and run everything again")
    return ap


def main(argv: list[str], prog: str = "wt-inspect evaluate") -> int:
    args = build_parser(prog).parse_args(argv)
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    if not controllers:
        print(f"{prog}: error: --controllers is empty; valid: {valid_names()}", file=sys.stderr)
        return 2
    try:
        ev = run_evaluation(
            args.scenario, controllers, args.winds, args.seeds, out=args.out, backend=args.backend, jobs=args.jobs,
            address=args.address, max_time=args.max_time, wind_type=args.wind_type, wind_options=args.wind_options,
            turbine=args.turbine, drone=args.drone, env_overrides=args.env, record_every=args.record_every,
            figures=not args.no_figures, progress=not args.no_progress, rerun=args.rerun,
            command=command_line(argv, prog))
    except OutputDirError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted; finished runs are kept in {args.out}/runs - rerun the same command to resume",
              file=sys.stderr)
        return 130
    print(f"{len(ev.results)} runs ({ev.n_ran} executed, {ev.n_resumed} resumed) in {ev.wall_time_s:.1f} s; wrote "
          f"{ev.files['csv']}, {ev.files['md']}" + (f" and {len(ev.files.get('figures', []))} figures"
                                                    if ev.files.get("figures") else ""))
    return 0
