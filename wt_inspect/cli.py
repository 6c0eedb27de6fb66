"""The ``wt-inspect`` command line: one entry point, subcommands implemented in their own modules.

This dispatcher sits above every package: it is the one place that names modules of
``wt_inspect_env``, ``controllers``/``agents``, ``wt_inspect`` and ``wt_inspect_px4`` together. The
environment package holds no commands (``plan`` and the environment benchmarks are in
``wt_inspect.commands`` with the commands that wire the layers together, and in
``wt_inspect.evaluation.cli``); ``agents`` keeps train and its benchmark, which need only it. Each
subcommand module exposes ``main(argv: list[str], prog: str) -> int``; it is imported only when its
subcommand runs, so ``wt-inspect plan`` never pays for importing torch.
"""
from __future__ import annotations

import importlib
import importlib.metadata
import sys

from .extras import missing_extra

DIST_NAME = "wt-inspect"   # the distribution (pyproject ``[project] name``) whose version --version prints

COMMANDS: dict[str, tuple[str, str]] = {
    "plan": ("wt_inspect.commands.plan", "plan the inspection path of a turbine"),
    "evaluate": ("wt_inspect.evaluation.cli", "run controllers on a scenario, write the table and figures"),
    "ablation": ("wt_inspect.ablation", "paper-faithful -> project default, one change at a time"),
    "train": ("agents.train_cli", "train a stable-baselines3 agent on an inspection task (or clone demonstrations)"),
    "demos": ("wt_inspect.demonstrations", "record expert (MPC) demonstrations as a Minari dataset"),
    "tune": ("wt_inspect.commands.tune",
             "tune an MPC's weights with Optuna; writes a weights file (NAME:weights=FILE)"),
    "campaign": ("wt_inspect.commands.campaign",
                 "robustness campaign: many randomised episodes, crashes/fallbacks/memory"),
    "rescore": ("wt_inspect.commands.rescore",
                "recorded runs' coverage under another camera / coverage rule, no flight"),
    "reproduce": ("wt_inspect.reproduce",
                  "rerun every committed result from results/reproduce.toml; --check: no flight"),
    "study": ("wt_inspect.studies", "the analyses behind some results/ folders (sm-vs-wind, wind-offset, ...)"),
    # the PX4 bridge: its own package above every other (named here by string, never imported below)
    "fly": ("wt_inspect_px4.offboard", "fly a policy on a PX4 vehicle over MAVLink (OFFBOARD), scored like evaluate"),
    "sitl": ("wt_inspect_px4.sitl", "serve our world to PX4 SITL (HIL sensors out, actuator controls in, lock-step)"),
}
BENCHES: dict[str, tuple[str, str]] = {
    "sim": ("wt_inspect.commands.bench_sim", "simulator real-time factor (hover, wind on)"),
    "coverage": ("wt_inspect.commands.bench_coverage", "camera coverage, reference and metrics cost per step"),
    "env": ("wt_inspect.commands.bench_env", "environment steps per second (full mission)"),
    "vecenv": ("wt_inspect.commands.bench_vecenv", "vector env aggregate steps per second vs the single env"),
    "planner": ("wt_inspect.commands.bench_planner", "planning time for the default turbine"),
    "solver": ("wt_inspect.commands.bench_solver", "MPC time per control step: compiled RTI, uncompiled, IPOPT"),
    "mission": ("wt_inspect.commands.bench_mission", "one whole mission's wall time: simulator, env, policy, harness"),
    "train": ("agents.bench", "training throughput: vector env vs subprocess envs"),
    "leak": ("wt_inspect.commands.bench_leak", "memory over repeated gym.make/reset/close cycles (RSS slope)"),
}


def version() -> str:
    """The installed distribution's version: read from the package metadata, so ``pyproject.toml``
    stays the one place the version is written (no ``__version__`` to keep in step)."""
    try:
        return importlib.metadata.version(DIST_NAME)
    except importlib.metadata.PackageNotFoundError:   # run from a checkout that was never installed
        return "unknown (not installed: pip install -e .)"


def _usage() -> str:
    lines = ["usage: wt-inspect [--version] <command> [options]", "", "commands:"]
    lines += [f"  {name:<10} {help_}" for name, (_, help_) in COMMANDS.items()]
    lines += ["  bench      benchmarks: " + ", ".join(BENCHES)]
    lines += ["", "Run 'wt-inspect <command> --help' for the options of one command."]
    return "\n".join(lines)


def _dispatch(table: dict[str, tuple[str, str]], name: str, argv: list[str], prog: str) -> int:
    module_name, _ = table[name]
    from wt_inspect_env.util.interrupts import EXIT_INTERRUPTED, interrupts_raise, signal_name
    try:   # the import and the run: a subcommand may import an optional dependency lazily
        with interrupts_raise():   # SIGTERM = Ctrl-C for every command, in every phase
            module = importlib.import_module(module_name)
            return int(module.main(argv, prog=prog) or 0)
    except KeyboardInterrupt as exc:   # a command that has no report to write (or was not yet running)
        print(f"\n{prog}: interrupted ({signal_name(exc)})", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ModuleNotFoundError as exc:
        msg = missing_extra(exc)
        if msg is None:
            raise
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    """The ``wt-inspect`` entry point: dispatch ``argv`` (default: the command line) to its subcommand."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(_usage())
        return 0 if argv else 2
    if argv[0] in {"-V", "--version"}:
        print(f"wt-inspect {version()}")
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd == "bench":
        if not rest or rest[0] not in BENCHES:
            print("usage: wt-inspect bench {" + ",".join(BENCHES) + "} [--json]", file=sys.stderr)
            for name, (_, help_) in BENCHES.items():
                print(f"  {name:<8} {help_}", file=sys.stderr)
            return 2
        return _dispatch(BENCHES, rest[0], rest[1:], prog=f"wt-inspect bench {rest[0]}")
    if cmd not in COMMANDS:
        print(f"wt-inspect: unknown command {cmd!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    return _dispatch(COMMANDS, cmd, rest, prog=f"wt-inspect {cmd}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
