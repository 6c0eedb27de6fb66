"""``wt-inspect train``: train (or resume) a stable-baselines3 agent on an inspection task."""
from __future__ import annotations

import argparse
import json
import sys

from wt_inspect_env.task.env_config import TASKS
from wt_inspect_env.util.atomic_io import check_out_dir
from wt_inspect_env.util.figure_io import DEFAULT_FIGURE_FORMAT, FIGURE_FORMATS
from wt_inspect_env.util.interrupts import EXIT_INTERRUPTED, interrupts_raise, signal_name

from .policy import ALGOS


def build_parser(prog: str) -> argparse.ArgumentParser:
    """The argument parser of ``wt-inspect train`` (``prog``: the name shown in its usage)."""
    p = argparse.ArgumentParser(
        prog=prog, description="Train a stable-baselines3 agent on a wind-turbine inspection task. Steps are "
        "simulator control steps (100 Hz); outputs (model, checkpoints, evaluations, TensorBoard logs, "
        "learning curve, summary.json) go to --out.")
    p.add_argument("--algo", required=True, help=f"algorithm: {', '.join(ALGOS)}, bc (behaviour cloning of "
                   "a demonstration dataset into a PPO policy; needs --dataset), or dagger (bc, then DAgger rounds "
                   "labelled by the expert flying in shadow; needs --dataset)")
    p.add_argument("--dataset", default=None, help="bc, dagger: a dataset folder written by wt-inspect demos")
    p.add_argument("--dagger-options", default=None,
                   help="dagger: JSON object (or FILE.json) of agents.dagger.DAggerConfig fields, e.g. "
                        "'{\"rounds\": 8, \"episodes_per_round\": 4}' (recipe default agents/recipes/dagger_full.json)")
    p.add_argument("--bc-epochs", type=int, default=30, help="bc: passes over the dataset (default 30)")
    p.add_argument("--task", default=None, help=f"task: {', '.join(TASKS)} (default surface; full for bc)")
    p.add_argument("--timesteps", type=int, default=None, help="simulator steps to train in this run (RL)")
    p.add_argument("--n-envs", type=int, default=16,
                   help="parallel environments (drones of the vector env; default 16)")
    p.add_argument("--backend", default="vector", choices=["vector", "subprocess", "dummy"],
                   help="vector: all drones in one batched env in this process (default); subprocess: one env per "
                        "process (SB3 SubprocVecEnv); dummy: single envs in turn in this process")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--recipe", default=None,
                   help="recipe JSON (default agents/recipes/<algo>_surface.json, or the checkpoint's when resuming); "
                        "with --seeds, several comma-separated: one run per recipe and seed into "
                        "OUT/<recipe>/seed_<s>/")
    p.add_argument("--resume", default=None, help="checkpoint .zip of an earlier run to continue from; with --seeds, "
                   "'{seed}' in the path is replaced by each seed (OUT_BLADE/seed_{seed}/model.zip: "
                   "every seed fine-tunes "
                   "its own model of the curriculum's stage before)")
    p.add_argument("--trust-model", action="store_true",
                   help="WARNING: with --resume (or --seeds resuming unfinished seeds), also load a checkpoint "
                        "that needs unpickling (an old "
                        ".vecnormalize.pkl, a zip with entries that cannot be rebuilt) - this runs code from the "
                        "file; only for files you made yourself or fully trust")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seeds", default=None, help="train one run per seed (comma-separated) into OUT/seed_<s>/; "
                   "finished seeds are skipped, unfinished ones resume from their latest checkpoint")
    p.add_argument("--ray", action="store_true", help="with --seeds: run the seeds as Ray tasks (one CPU each)")
    p.add_argument("--address", default=None, help="with --ray: address of a Ray cluster (default: a local instance)")
    p.add_argument("--eval-every", type=int, default=None,
                   help="simulator steps between periodic evaluations (default: the recipe's eval_every_env_steps)")
    p.add_argument("--max-minutes", type=float, default=None, help="stop (and save) after this wall time")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--figure-format", choices=FIGURE_FORMATS, default=DEFAULT_FIGURE_FORMAT,
                   help=f"format of the learning-curve figures (default {DEFAULT_FIGURE_FORMAT}; "
                        "pdf and svg are vector)")
    p.add_argument("--verbose", type=int, default=0, help="stable-baselines3 verbosity (0, 1, 2)")
    return p


def main(argv: list[str], prog: str = "wt-inspect train") -> int:
    """``wt-inspect train``: train (or clone) with the options in ``argv``; returns the exit code."""
    with interrupts_raise():   # SIGTERM = Ctrl-C: a checkpoint is saved either way
        return _main(argv, prog)


def _main(argv: list[str], prog: str) -> int:
    args = build_parser(prog).parse_args(argv)
    try:   # before any work: an existing file or an uncreatable directory as --out is one line
        check_out_dir(args.out, "--out")
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    if args.algo == "bc":
        return _clone(args, prog)
    if args.algo == "dagger":
        from .dagger import cli as dagger_cli
        return dagger_cli(args, prog)
    if args.dagger_options is not None:
        print(f"{prog}: error: --dagger-options is for --algo dagger only", file=sys.stderr)
        return 2
    if args.timesteps is None:
        print(f"{prog}: error: --timesteps is required for --algo {args.algo}", file=sys.stderr)
        return 2
    if args.dataset is not None:
        print(f"{prog}: error: --dataset is for --algo bc only", file=sys.stderr)
        return 2
    args.task = args.task or "surface"
    if args.seeds is not None:
        return _seeds(args, prog)
    if args.ray or args.address:
        print(f"{prog}: error: --ray/--address need --seeds", file=sys.stderr)
        return 2
    if len(_recipes(args)) > 1:
        print(f"{prog}: error: several --recipe files need --seeds (one run per recipe and seed)", file=sys.stderr)
        return 2
    from .training import TrainingInterrupted, train  # imports torch only once the arguments are valid
    try:
        summary = train(args.algo, args.task, args.timesteps, args.n_envs, args.out, recipe=args.recipe,
                        resume=args.resume, seed=args.seed, max_minutes=args.max_minutes, eval_every=args.eval_every,
                        progress_bar=not args.no_progress, verbose=args.verbose, backend=args.backend,
                        trust_model=args.trust_model, figure_format=args.figure_format)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except TrainingInterrupted as exc:
        how = f"\n{prog}: interrupted ({signal_name(exc)}) after {exc.env_steps} env steps; "
        if exc.checkpoint is not None:
            print(how + f"saved the checkpoint {exc.checkpoint} - continue with --resume {exc.checkpoint}",
                  file=sys.stderr)
        else:
            print(how + "nothing saved (the checkpoint could not be written)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except KeyboardInterrupt as exc:   # before the model existed
        print(f"\n{prog}: interrupted ({signal_name(exc)}) before training started; nothing saved", file=sys.stderr)
        return EXIT_INTERRUPTED
    m = summary["final_evaluation"]["mean"]
    print(f"trained {summary['env_steps_this_call']} steps in {summary['train_wall_time_this_call_s']:.0f} s "
          f"({summary['env_steps_per_s']:.0f} steps/s); total {summary['env_steps']} steps, "
          f"{summary['wall_time_s'] / 60:.1f} min")
    print(f"final evaluation: coverage {m['coverage']:.3f}, SM {m['safety_sm']:.3f}, CM {m['centering_cm']:.3f}")
    print(json.dumps({"model": summary["final_model"], "summary": str(args.out) + "/summary.json"}))
    return 0


def _recipes(args) -> list[str]:
    return [r.strip() for r in str(args.recipe).split(",") if r.strip()] if args.recipe else []


def _seed_run_kwargs(args) -> dict:
    """What every run of a ``--seeds`` sweep gets from the command line (the recipe aside)."""
    return dict(ray=args.ray, address=args.address, algo=args.algo, task=args.task, timesteps=args.timesteps,
                n_envs=args.n_envs, resume=args.resume, max_minutes=args.max_minutes, verbose=args.verbose,
                eval_every=args.eval_every,
                backend=args.backend, progress_bar=not args.no_progress, trust_model=args.trust_model,
                figure_format=args.figure_format)


def _seeds(args, prog: str) -> int:
    """``--seeds``: one run per seed (see :mod:`agents.seeds`); with several ``--recipe`` files,
    one run per recipe and seed."""
    from .seeds import parse_seeds, train_recipes, train_seeds
    if len(_recipes(args)) > 1:
        try:
            seeds = parse_seeds(args.seeds)
            res = train_recipes(_recipes(args), seeds, args.out, **_seed_run_kwargs(args))
        except ValueError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
        for name, r in res["summary"]["recipes"].items():
            print(f"{name}: {r['n_reached']} of {len(seeds)} seeds reached its target {r['target']}")
        print(f"{args.out}/recipes.json, {args.out}/<recipe>/seeds.json")
        return 0
    try:
        seeds = parse_seeds(args.seeds)
        doc = train_seeds(seeds, args.out, recipe=args.recipe, **_seed_run_kwargs(args))
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    for r in doc["seeds"]:
        f = r["final"] or {}
        when = (f"at {r['reached_at_env_steps']} steps ({r['reached_at_wall_s']:.0f} s)" if r["reached_target"]
                else "not reached")
        print(f"seed {r['seed']}: coverage {f.get('coverage', float('nan')):.3f}, "
              f"SM {f.get('safety_sm', float('nan')):.3f}, "
              f"CM {f.get('centering_cm', float('nan')):.3f}; target {when}")
    for name, t in doc["targets"].items():
        print(f"{t['n_reached']} of {len(doc['seeds'])} seeds reached the {name} target {t['target']}")
    print(f"{args.out}/seeds.json, {args.out}/learning_curves_seeds.{args.figure_format}")
    return 0


def _clone(args, prog: str) -> int:
    """``--algo bc``: behaviour cloning of ``--dataset`` with the recipe's policy (default bc_full)."""
    if args.dataset is None:
        print(f"{prog}: error: --algo bc needs --dataset (a folder written by wt-inspect demos)", file=sys.stderr)
        return 2
    from pathlib import Path

    from .imitation import BCConfig, behaviour_clone
    from .recipe import load_recipe
    try:
        rec = load_recipe(args.recipe or str(Path(__file__).parent / "recipes" / "bc_full.json"))
        if args.seeds is not None:
            from .seeds import clone_seeds, parse_seeds
            doc = clone_seeds(parse_seeds(args.seeds), args.dataset, args.out, recipe=rec, task=args.task or "full",
                              epochs=args.bc_epochs, progress=not args.no_progress)
            print(f"{doc['n_reached']} of {len(doc['seeds'])} seeds reached the target; {args.out}/seeds.json")
            return 0
        summary = behaviour_clone(args.dataset, args.out, recipe=rec, task=args.task or "full",
                                  config=BCConfig(epochs=args.bc_epochs, seed=args.seed), progress=not args.no_progress)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    last = summary["history"][-1]
    print(f"cloned {summary['samples']} samples of {summary['episodes']} episodes in {summary['fit_s']:.0f} s "
          f"(train MSE {last['train_mse']:.4f}, validation MSE {last['val_mse']:.4f}) -> {summary['model']}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
