"""DAgger of VT-NMPC+ on the full mission from nothing, and what each round learns (``results/imitation/dagger``).

One command records the demonstrations, runs behaviour cloning and a fixed number of DAgger rounds,
and explains the outcome::

    wt-inspect study imitation --out results/imitation/dagger --rounds 8

1. Demonstrations (:func:`wt_inspect.demonstrations.record_demonstrations`, the default
   :class:`~wt_inspect.demonstrations.DemoConfig` unless ``--demo-config`` says otherwise) into
   ``OUT/demos/``; an existing dataset is reused only when its recorded configuration is the requested one.
   The demonstrations observe what the recipe's features need (e.g. the nearest structure point for
   ``structure_body``: ``structure_observation``), so that the clone sees the same features as its rollouts.
   ``--seed s`` seeds both the recording (DemoConfig.seed) and DAgger (DAggerConfig.seed): one seed of
   the route from nothing.
2. DAgger (:func:`agents.dagger.dagger`, recipe ``--recipe``, by default ``agents/recipes/dagger_full.json``)
   into ``OUT/run/``
   for ``--rounds`` rounds and no wall-clock budget, so that the study is the same on every machine
   however fast (the budget of a training run, ``--max-minutes``, makes its length depend on the
   machine); a rerun resumes after the last finished round.
3. The labels by source (``analysis.json``): the spread of the expert's labels and the share at the
   action bounds, in the demonstrations and in each round's learner-visited states - where the
   learner drifts, the expert answers with saturated recovery commands the demonstrations never
   show, which the network has to learn before it stays near the path.
4. The hold check (:mod:`wt_inspect.studies.hold_check`): VT-NMPC+ flying its own decisions held
   like the learner's, so that the decision rate is ruled in or out as the cause.

With ``--seeds 0,1,2,3,4`` each seed's study goes into ``OUT/seed_<s>/`` (finished seeds are skipped,
an unfinished one resumes), and ``OUT/results.md`` / ``seeds.json`` / ``learning_curves_seeds.png``
compare the seeds: each one's last evaluation and least clearance, when it first met the full-mission
target with and without the clearance, and its wall time from nothing (recording + DAgger).

``OUT/results.md`` gives all of it with the command, and the best round's policy is copied to
``OUT/best_model.zip`` (``--controllers ppo:OUT/best_model.zip`` flies it); the dataset, every
round's model and the aggregated data stay in ``OUT/demos`` and ``OUT/run`` (large; not committed).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..demonstrations import DemoConfig
from .hold_check import label_stats

DATASET = "vtnmpc-plus-full-v0"
#: least clearance an agent must keep without a safety filter: d_min (3 m) less 0.1 m
CLEARANCE_TARGET_M = 2.9
#: the default length of the hold check [s]
HOLD_SECONDS = 12.0


def labels_by_source(run: Path, per_round: list[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """:func:`label_stats` of the demonstrations and of each DAgger round's new labels, from the
    run's cached arrays (``demo_features.npz``, ``dagger_data.npz``) and its summary's ``per_round``
    sample counts (``samples_dagger`` is cumulative; round 0 is the clone)."""
    out: dict[str, dict[str, Any]] = {}
    with np.load(run / "demo_features.npz") as z:
        out["demonstrations"] = label_stats(z["Y"])
    agg = run / "dagger_data.npz"
    if not agg.is_file():
        return out
    with np.load(agg) as z:
        Ya = z["Y"]
    before = 0
    for e in per_round[1:]:
        n = int(e.get("samples_dagger") or 0)
        out[f"dagger round {e['round']} (beta {e['beta']:g})"] = label_stats(Ya[before:n])
        before = n
    return out


def ensure_demonstrations(out: Path, cfg: Any, progress: bool, env_options: Mapping[str, Any] | None = None) -> Path:
    """The dataset of ``cfg`` recorded on envs made with ``env_options`` in ``out/demos`` (recorded
    unless already there with this configuration and these options)."""
    from wt_inspect.demonstrations import record_demonstrations
    path = out / "demos" / "wt-inspect" / DATASET
    wanted = json.loads(json.dumps({**cfg.__dict__, "winds": list(cfg.winds)}))
    options = dict(env_options or {})
    meta = path / "wt_inspect_demos.json"
    if meta.is_file():
        recorded = json.loads(meta.read_text())
        have = recorded.get("config")
        if have != wanted or recorded.get("env_options", {}) != options:
            raise ValueError(f"{str(path)!r} holds demonstrations of another configuration ({have!r}, env options "
                             f"{recorded.get('env_options', {})!r}); remove it or use another --out")
        return path
    record_demonstrations(cfg, out / "demos", DATASET, env_options=options, progress=progress)
    return path


def _pct(x: Any) -> str:
    return "-" if x is None else f"{100 * float(x):.1f} %"


def markdown(summary: Mapping[str, Any], labels: Mapping[str, Mapping[str, Any]], hold: Mapping[Any, Any],
             demos: Mapping[str, Any], command: str, hold_seconds: float,
             recipe_name: str = "agents/recipes/dagger_full.json") -> str:
    """results.md of the study (see the module docstring)."""
    cfg = summary["config"]
    lines = [f"# DAgger of {cfg['expert']} on the full mission", "", f"`{command}`", "",
             f"Demonstrations: {demos.get('total_episodes', '?')} episodes, {demos.get('steps', 0):,} control steps, "
             f"{summary['samples_demonstrations']:,} labelled states (configuration in "
             f"`demos/wt-inspect/{DATASET}/wt_inspect_demos.json`, not committed: "
             f"`{json.dumps(demos.get('config', {}))}`). DAgger: recipe `{recipe_name}`, seed {cfg.get('seed', 0)}, "
             f"{cfg['rounds']} round(s) of {cfg['episodes_per_round']} rollout(s), the expert's share beta "
             f"{cfg['beta0']:g} in round 1 and x{cfg['beta_decay']:g} per round after, no wall-clock budget. Each "
             "round is evaluated on the recipe's evaluation mission (one deterministic episode).", "",
             "| round | beta | env steps | labelled states | coverage | SM | CM | flight | end |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in summary["per_round"]:
        name = "0 (behaviour cloning)" if r["round"] == 0 else str(r["round"])
        lines.append(f"| {name} | {r['beta']:g} | {r['env_steps']:,} | {int(r.get('samples_dagger') or 0):,} | "
                     f"{_pct(r['coverage'])} | {_pct(r['safety_sm'])} | {_pct(r['centering_cm'])} | "
                     f"{r['flight_time_s']:.1f} s | {r['termination'] or 'complete'} |")
    lines += ["", "The expert's labels (agent actions [p, q, r, thrust] in [-1, 1]) by where they were asked:", "",
              "| source | samples | std p / q / r / thrust | at the bounds p / q / r / thrust |", "|---|---:|---|---|"]
    for name, s in labels.items():
        std = " / ".join("-" if v is None else f"{v:.3f}" for v in s["label_std"])
        sat = " / ".join(_pct(v) for v in s["saturated_share"])
        lines.append(f"| {name} | {s['samples']:,} | {std} | {sat} |")
    lines += ["", f"The expert with its decisions held for k control steps and decoded like the learner's "
              f"(`wt-inspect study hold-check --seconds {hold_seconds:g}`: {hold_seconds:g} s from the mission start, "
              "4 m/s gust; k = 4 is the learner's 25 Hz):", "",
              "| k | flight | end | coverage | SM | CM | RMS distance error |", "|---:|---:|---|---:|---:|---:|---:|"]
    for k, h in hold.items():
        lines.append(f"| {k} | {h['flight_s']:.1f} s | {h['termination'] or 'time limit'} | {_pct(h['coverage'])} | "
                     f"{_pct(h['safety_sm'])} | {_pct(h['centering_cm'])} | {h['rms_distance_error_m']:.3f} m |")
    lines += ["", "Files: `analysis.json` (the two tables above), `summary.json`, `evaluations.json` and "
              "`learning_curve.png` of the DAgger run, and its best round's policy `best_model.zip` (with its "
              "sidecars; `--controllers ppo:<this folder>/best_model.zip` flies it).", ""]
    return "\n".join(lines)


def run_study(out: str | Path, *, rounds: int, episodes_per_round: int = 4, demo_config: Any = None,
              recipe: Any = None, seed: int = 0, expert: str | None = None, hold_seconds: float = HOLD_SECONDS,
              progress: bool = True, command: str = "") -> dict[str, Any]:
    """The whole study into ``out`` (module docstring); returns the analysis. ``recipe``: a recipe
    file (default ``agents/recipes/dagger_full.json``) or a ``Recipe``; ``seed`` seeds DAgger and, unless
    ``demo_config`` is given, the demonstrations; ``expert``: the controller that demonstrates and
    labels (default VT-NMPC+; it replaces ``demo_config``'s)."""
    from agents.dagger import DAggerConfig, dagger
    from agents.interface import needed_env_options
    from agents.recipe import RECIPE_DIR, load_recipe
    from wt_inspect_env.util.atomic_io import check_out_dir, write_bytes_atomic, write_text_atomic

    from . import hold_check

    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {seed!r}")
    out = check_out_dir(out, "--out")
    cfg = DAggerConfig(rounds=rounds, episodes_per_round=episodes_per_round, seed=seed,
                       **({} if expert is None else {"expert": expert}))
    if recipe is None or isinstance(recipe, (str, Path)):
        recipe_path = Path(recipe) if recipe is not None else RECIPE_DIR / "dagger_full.json"
        rec, recipe_name = load_recipe(recipe_path), _shown_path(recipe_path)
    else:                                       # a Recipe built in code (tests, notebooks)
        rec, recipe_name = recipe, "(a recipe given in code)"
    demo_cfg = demo_config if demo_config is not None else DemoConfig(seed=seed)
    if expert is not None:
        demo_cfg = dataclasses.replace(demo_cfg, expert=expert)
    dataset = ensure_demonstrations(out, demo_cfg, progress, needed_env_options(rec.spec.features.groups))
    run = out / "run"
    summary = dagger(dataset, run, recipe=rec, task="full", config=cfg, progress=progress)
    labels = labels_by_source(run, summary["per_round"])
    hold = hold_check.run(hold_seconds)
    demos = json.loads((dataset / "wt_inspect_demos.json").read_text())
    # the run's best policy beside its numbers (small), so that the result flies:
    # --controllers ppo:OUT/best_model.zip
    for name in ("summary.json", "evaluations.json", "learning_curve.png", "best_model.zip", "best_model.json",
                 "best_model.vecnormalize.json"):
        src = run / name
        if src.is_file():
            write_bytes_atomic(out / name, src.read_bytes())
    analysis = {"labels (agent actions [p, q, r, thrust] in [-1, 1])": labels,
                f"expert decisions held for k control steps ({hold_seconds:g} s from the mission start, 4 m/s gust)":
                    {f"k={k}": v for k, v in hold.items()}}
    write_text_atomic(out / "analysis.json", json.dumps(analysis, indent=1) + "\n")
    write_text_atomic(out / "results.md", markdown(summary, labels, hold, demos, command, hold_seconds,
                                                   recipe_name))
    return analysis


def seed_targets() -> dict[str, dict[str, float]]:
    """The targets the seeds report judges, headline first: the full-mission target with the
    clearance kept without a filter, then the mission target alone."""
    from agents.seeds import TARGET
    return {"mission and clearance": {**TARGET, "clearance_min_m": CLEARANCE_TARGET_M}, "mission": dict(TARGET)}


def _seed_done(run: Path, rounds: int) -> bool:
    """A seed's study is finished: its results.md written after ``rounds`` DAgger rounds."""
    summary = run / "summary.json"
    return (run / "results.md").is_file() and summary.is_file() and \
        int(json.loads(summary.read_text()).get("rounds_done", -1)) >= rounds


def _demo_seconds(run: Path) -> float | None:
    """Wall time of the seed's demonstration recording (None: recorded before it was timed)."""
    meta = run / "demos" / "wt-inspect" / DATASET / "wt_inspect_demos.json"
    return json.loads(meta.read_text()).get("wall_time_s") if meta.is_file() else None


def seeds_document(out: Path, seeds: list[int]) -> dict[str, Any]:
    """:func:`agents.seeds.seed_report` of the seeds' evaluations under :func:`seed_targets`, with
    each seed's wall time from nothing: recording, DAgger, and to each target (recording + the DAgger
    wall time of the first round that met it)."""
    from agents.seeds import seed_report
    doc = seed_report(out, seeds, seed_targets())
    for row in doc["seeds"]:
        run = out / f"seed_{row['seed']}"
        demo_s = _demo_seconds(run)
        summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").is_file() else {}
        row["demonstrations_s"] = demo_s
        row["dagger_s"] = summary.get("wall_time_s")
        row["best"] = summary.get("best_evaluation")
        for t in row["targets"].values():
            t["from_nothing_s"] = None if (t["wall_s"] is None or demo_s is None) else round(demo_s + t["wall_s"], 1)
    return doc


def seeds_markdown(out: Path, doc: Mapping[str, Any], command: str) -> str:
    """OUT/results.md of a seeds run: the seeds table of :func:`agents.seeds.seeds_markdown` and the
    wall times from nothing."""
    from agents.seeds import missed
    from agents.seeds import seeds_markdown as table

    def minutes(x: Any) -> str:
        return "-" if x is None else f"{float(x) / 60:.1f} min"

    names = list(doc["targets"])
    count = len(doc["seeds"])
    lines = [f"# DAgger from nothing over {count} seed{'' if count == 1 else 's'}", "", f"`{command}`", "",
             "Each seed's study (demonstrations, DAgger, analysis) is in `seed_<s>/results.md`. Seeds meeting the "
             + "; ".join(f"{n} target: {doc['targets'][n]['n_reached']} of {count}"
                         if any(r["targets"][n].get("measured", True) for r in doc["seeds"])
                         else f"{n} target: not measured (the recipe's evaluation env does not observe the "
                              f"structure, so its evaluations record no clearance; the flown evaluations of the "
                              f"kept rounds do)" for n in names)
             + ".", "", table(out, doc), "",
             "Wall time from nothing (one core each): recording the demonstrations, the whole DAgger run, and "
             "recording plus DAgger up to the first round that met each target:", "",
             "| seed | demonstrations | DAgger | " + " | ".join(f"to the {n} target" for n in names) + " |",
             "|---|---:|---:|" + "---:|" * len(names)]
    for row in doc["seeds"]:
        lines.append(f"| {row['seed']} | {minutes(row['demonstrations_s'])} | {minutes(row['dagger_s'])} | "
                     + " | ".join(minutes(row["targets"][n]["from_nothing_s"]) if row["targets"][n]["reached"]
                                  else missed(row["targets"][n]) for n in names) + " |")
    def metres(x: Any) -> str:
        return "-" if x is None else f"{float(x):.2f} m"

    lines += ["", "The round each seed keeps (`seed_<s>/best_model.zip`: the best evaluation score), as evaluated:", "",
              "| seed | round | coverage | SM | CM | least clearance | RMS distance error |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for row in doc["seeds"]:
        best = row.get("best") or {}
        m = best.get("mean", {})
        lines.append(f"| {row['seed']} | {best.get('round', '-')} | {_pct(m.get('coverage'))} "
                     f"| {_pct(m.get('safety_sm'))} | {_pct(m.get('centering_cm'))} "
                     f"| {metres(m.get('clearance_min_m'))} | {metres(m.get('rms_distance_error_m'))} |")
    lines += ["", "Figure: `learning_curves_seeds.png` (every round's evaluation per seed, mean and spread).", ""]
    return "\n".join(lines)


def run_seeds(out: str | Path, seeds: list[int], *, rounds: int, progress: bool = True, command: str = "",
              **study: Any) -> dict[str, Any]:
    """:func:`run_study` for each seed into ``out/seed_<s>`` (finished ones skipped), then the
    seeds report (module docstring); returns ``seeds.json``."""
    from tqdm import tqdm

    from agents.seeds import plot_seed_curves
    from wt_inspect_env.util.atomic_io import check_out_dir, write_text_atomic

    out = check_out_dir(out, "--out")
    for s in tqdm(seeds, desc="seeds", unit="seed", disable=not progress, file=sys.stderr):
        run = out / f"seed_{s}"
        if not _seed_done(run, rounds):
            demos = study.get("demo_config")
            own = {**study, "demo_config": None if demos is None else dataclasses.replace(demos, seed=s)}
            run_study(run, rounds=rounds, seed=s, progress=progress,
                      command=f"{command} (seed {s} of the seeds run)", **own)
    doc = seeds_document(out, seeds)
    write_text_atomic(out / "seeds.json", json.dumps(doc, indent=1) + "\n")
    plot_seed_curves(out, seeds, out / "learning_curves_seeds.png", targets=seed_targets())
    write_text_atomic(out / "results.md", seeds_markdown(out, doc, command))
    return doc


def _shown_path(p: Path) -> str:
    """``p`` relative to the working directory when inside it (results name repository paths)."""
    try:
        return Path(p).resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return str(p)


def build_parser(prog: str = "wt-inspect study imitation") -> argparse.ArgumentParser:
    """The command line of the study (also how the behaviour digest reads a manifest command)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--rounds", type=int, default=3, help="DAgger rounds after behaviour cloning (default 3)")
    ap.add_argument("--episodes-per-round", type=int, default=4)
    ap.add_argument("--demo-config", default=None, help="JSON object of DemoConfig fields (default: its defaults)")
    ap.add_argument("--recipe", default=None, help="DAgger recipe file (default agents/recipes/dagger_full.json)")
    ap.add_argument("--expert", default=None,
                    help="registered controller that demonstrates and labels, with its argument if any "
                         "(default vtnmpc-plus; e.g. vtnmpc-plus:backoff=0.5, a tightened clearance)")
    seed = ap.add_mutually_exclusive_group()
    seed.add_argument("--seed", type=int, default=0, help="seed of the demonstrations and of DAgger (default 0)")
    seed.add_argument("--seeds", default=None,
                      help="comma-separated seeds, each into OUT/seed_<s>/ (its demonstrations seeded with s, "
                           "also under --demo-config), and a report over them in OUT")
    ap.add_argument("--hold-seconds", type=float, default=HOLD_SECONDS)
    ap.add_argument("--no-progress", action="store_true")
    return ap


def main(argv: list[str] | None = None, prog: str = "wt-inspect study imitation") -> int:
    """``wt-inspect study imitation``: run (or resume) the study given by ``argv``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    command = " ".join(["wt-inspect study imitation", *(argv if argv is not None else sys.argv[1:])])
    try:
        if not args.hold_seconds > 0:
            raise ValueError(f"--hold-seconds must be positive, got {args.hold_seconds!r}")
        demo_cfg = DemoConfig.from_json(args.demo_config, "--demo-config") if args.demo_config else None
        study = dict(rounds=args.rounds, episodes_per_round=args.episodes_per_round, demo_config=demo_cfg,
                     recipe=args.recipe, expert=args.expert, hold_seconds=args.hold_seconds,
                     progress=not args.no_progress,
                     command=command)
        if args.seeds is not None:
            from agents.seeds import parse_seeds
            run_seeds(args.out, parse_seeds(args.seeds), **study)
        else:
            run_study(args.out, seed=args.seed, **study)
    except ValueError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}/results.md, " + ("seeds.json" if args.seeds is not None else "analysis.json"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
