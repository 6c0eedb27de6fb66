"""Several seeds of one recipe: trained side by side (locally or on Ray), resumed, and compared.

``wt-inspect train ... --seeds 0,1,2,3,4 [--ray [--address ADDR]]`` trains one run per seed into
``OUT/seed_<s>/`` (each a normal run directory). A seed whose ``summary.json`` exists is done and
skipped, one with checkpoints resumes from its latest - the resume behaviour of single runs - so an
interrupted sweep is continued by the same command; so is one stopped by ``--max-minutes`` short of
its ``--timesteps`` (a long run trained in chunks, one per call). Locally the seeds run one after another (each
with its own progress bar); on Ray (``--ray``; a local Ray instance, or a cluster by
``--address``, as the evaluation backend) each seed is a task of one CPU and a bar counts the
finished seeds. ``OUT/seeds.json`` lists, per seed, whether and when (env steps, wall time) it
reached the target, and ``OUT/learning_curves_seeds.png`` draws every seed's evaluation curve
with the mean and spread over seeds. With several recipes (``--recipe a.json,b.json --seeds ...``)
every (recipe, seed) run goes into ``OUT/<recipe>/seed_<s>/`` - on Ray all of them at once - each
recipe gets its own report, and ``OUT/recipes.json`` compares them (:func:`train_recipes`).
"""
from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from wt_inspect_env.util.atomic_io import write_text_atomic
from wt_inspect_env.util.ray_session import check_ray_address, import_ray, init_ray

from .curves import draw_targets, read_evaluations

TARGET = {"coverage": 0.99, "safety_sm": 0.99, "centering_cm": 0.995}   # the full-mission target of the issue


def report_targets(recipe_target: Mapping[str, float] | None) -> dict[str, dict[str, float]]:
    """The targets a seeds report judges: the recipe's own (if it has one) first, then ``mission``
    (:data:`TARGET`)."""
    out = {"recipe": dict(recipe_target)} if recipe_target else {}
    out["mission"] = dict(TARGET)
    return out


def _recipe_target(train_kwargs: Mapping[str, Any]) -> dict[str, float] | None:
    from .recipe import default_recipe_path, load_recipe
    path = train_kwargs.get("recipe") or default_recipe_path(train_kwargs.get("algo", "ppo"))
    return load_recipe(path).target


def parse_seeds(text: str) -> list[int]:
    """``"0,1,2"`` -> [0, 1, 2] (ValueError naming --seeds otherwise)."""
    try:
        seeds = [int(s) for s in str(text).split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--seeds must be comma-separated non-negative integers, got {text!r}") from None
    if not seeds or any(s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds must be distinct comma-separated non-negative integers, got {text!r}")
    return seeds


def _latest_checkpoint(run: Path) -> Path | None:
    """The run's model with the most training: its newest checkpoint, or its final model when a
    wall-clock stop (``--max-minutes``) saved it after the last checkpoint."""
    ckpts = sorted(run.glob("checkpoints/ckpt_*.zip"), key=lambda p: int(re.findall(r"\d+", p.stem)[-1]))
    latest = ckpts[-1] if ckpts else None
    final = run / "model.zip"
    if final.is_file() and final.with_suffix(".json").is_file():
        if latest is None or _env_steps(final) > _env_steps(latest):
            latest = final
    return latest


def _env_steps(model: Path) -> int:
    """Env steps recorded in a saved model's sidecar."""
    from .policy import load_sidecar
    return int(load_sidecar(model)["training"]["env_steps"])


def _read_summary(run: Path) -> dict[str, Any] | None:
    path = run / "summary.json"
    return json.loads(path.read_text()) if path.is_file() else None


def _summary_finished(doc: Mapping[str, Any] | None) -> bool:
    """A run with this ``summary.json`` (None: none yet) is finished: it exists and the run was not
    stopped by the wall clock short of its steps - a ``--max-minutes`` chunk of a long run is
    resumed by the next call of the same command."""
    if doc is None:
        return False
    if not doc.get("stopped_by_wall_clock"):
        return True
    target = doc.get("target_env_steps")
    return target is None or int(doc["env_steps"]) >= int(target)


def seed_finished(run: Path) -> bool:
    """Whether the seed's run in ``run`` is finished (:func:`_summary_finished`)."""
    return _summary_finished(_read_summary(run))


def base_training(resume: str | Path | None) -> dict[str, float]:
    """Env steps and wall time already in the model every seed starts from (``--resume``: a
    fine-tune stage); zeros when the seeds train from scratch."""
    if resume is None:
        return {"env_steps": 0, "wall_time_s": 0.0}
    from .policy import load_sidecar
    training = load_sidecar(resume).get("training", {})
    return {"env_steps": int(training.get("env_steps", 0)), "wall_time_s": float(training.get("wall_time_s", 0.0))}


def _one_seed(kwargs: Mapping[str, Any], seed: int, run: str, progress: bool) -> dict[str, Any]:
    from .training import train
    run_dir = Path(run)
    ckpt = _latest_checkpoint(run_dir)
    kw = dict(kwargs)
    if ckpt is not None:   # the checkpoint's steps include those of the base model a fine-tune started from
        done = _env_steps(ckpt) - base_training(kw.get("resume"))["env_steps"]
        kw["timesteps"] = max(1, int(kw["timesteps"]) - done)
        kw["resume"] = str(ckpt)
        kw["recipe"] = None
    return train(out=run_dir, seed=seed, progress_bar=progress, **kw)


def _run_all(jobs: Sequence[tuple[Mapping[str, Any], int, Path]], *, ray: bool, address: str | None,
             progress: bool, n_total: int) -> None:
    """Train the unfinished ``(train kwargs, seed, run dir)`` jobs: on Ray all at once (one CPU
    each; a bar counts finished runs), otherwise one after another with their own bars."""
    from tqdm import tqdm
    if jobs and ray:
        ray_ = import_ray()
        # a session this call started is shut down when it is done (a second call must not find
        # it, with its address and CPUs, still there)
        started = init_ray(address, log_to_driver=False)
        try:
            task = ray_.remote(num_cpus=1)(_one_seed)
            pending = [task.remote(kw, s, str(run), False) for kw, s, run in jobs]
            with tqdm(total=n_total, initial=n_total - len(jobs), desc="runs", unit="run", file=sys.stderr) as bar:
                while pending:
                    ready, pending = ray_.wait(pending, num_returns=1)
                    ray_.get(ready[0])
                    bar.update(1)
        finally:
            if started:
                ray_.shutdown()
    else:
        for kw, s, run in jobs:
            _one_seed(kw, s, str(run), progress)


def _check_address(ray: bool, address: str | None) -> None:
    """A cluster address nothing answers on is refused before any directory is made."""
    if ray and address:
        check_ray_address(address)


SEED_FIELD = "{seed}"


def seed_base(resume: str | Path | None, seed: int) -> str | None:
    """The model seed ``seed`` starts from: ``resume`` itself, or with ``{seed}`` replaced by the
    seed - so each seed of a curriculum stage fine-tunes its own seed's model of the stage before
    (``--resume OUT_BLADE/seed_{seed}/model.zip``), not one shared base."""
    if resume is None:
        return None
    return str(resume).replace(SEED_FIELD, str(seed))


def check_seed_bases(resume: str | Path | None, seeds: Sequence[int]) -> None:
    """Every seed's base model exists (ValueError naming --resume and the missing file), checked
    before any run starts."""
    if resume is None:
        return
    for s in seeds:
        base = seed_base(resume, s)
        if not Path(base).is_file():
            raise ValueError(f"--resume: no model {base!r} for seed {s}")


def _unfinished(seeds: Sequence[int], out: Path,
                kwargs: Mapping[str, Any]) -> list[tuple[Mapping[str, Any], int, Path]]:
    return [({**kwargs, "resume": seed_base(kwargs.get("resume"), s)}, s, out / f"seed_{s}")
            for s in seeds if not seed_finished(out / f"seed_{s}")]


def _write_seed_report(seeds: Sequence[int], out: Path, train_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    targets = report_targets(_recipe_target(train_kwargs))
    resume = train_kwargs.get("resume")
    bases = {s: base_training(seed_base(resume, s)) for s in seeds}
    doc = seed_report(out, seeds, targets, base=bases)
    doc["resumed_from"] = None if resume is None else str(resume)
    doc["recipe"] = None if train_kwargs.get("recipe") is None else str(train_kwargs["recipe"])
    write_text_atomic(out / "seeds.json", json.dumps(doc, indent=1))
    write_text_atomic(out / "seeds.md", seeds_markdown(out, doc))
    try:
        plot_seed_curves(out, seeds, out / "learning_curves_seeds.png", train_kwargs.get("figure_format", "png"),
                         targets=targets, base_steps={s: b["env_steps"] for s, b in bases.items()})
    except Exception as exc:  # a figure must never lose finished runs
        print(f"warning: seed figure not drawn: {exc}", file=sys.stderr)
    return doc


def train_seeds(seeds: Sequence[int], out: str | Path, *, ray: bool = False, address: str | None = None,
                **train_kwargs: Any) -> dict[str, Any]:
    """Train every seed (see the module docstring); returns the ``seeds.json`` document.
    ``figure_format`` (in ``train_kwargs``, as for :func:`agents.training.train`) applies to the
    seeds' learning curves and the figure over the seeds."""
    out = Path(out)
    _check_address(ray, address)
    check_seed_bases(train_kwargs.get("resume"), seeds)
    out.mkdir(parents=True, exist_ok=True)
    progress = bool(train_kwargs.pop("progress_bar", True))
    _run_all(_unfinished(seeds, out, train_kwargs), ray=ray, address=address, progress=progress, n_total=len(seeds))
    return _write_seed_report(seeds, out, train_kwargs)


def recipe_names(recipes: Sequence[str | Path]) -> list[str]:
    """Each recipe's directory name under ``OUT`` (its file stem); ValueError naming ``--recipe``
    if two recipes share one."""
    names = [Path(r).stem for r in recipes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"--recipe: two recipes would share the directory {dup[0]!r} (same file name); rename one")
    return names


def train_recipes(recipes: Sequence[str | Path], seeds: Sequence[int], out: str | Path, *, ray: bool = False,
                  address: str | None = None, **train_kwargs: Any) -> dict[str, Any]:
    """Every recipe with every seed into ``OUT/<recipe name>/seed_<s>/`` - on Ray all the runs at
    once - each recipe with its ``seeds.json`` and figure, and ``OUT/recipes.json`` comparing them
    (how many seeds of each reached its target). Finished runs are skipped and unfinished ones
    resumed, as for :func:`train_seeds`."""
    from .recipe import load_recipe
    out = Path(out)
    names = recipe_names(recipes)
    for r in recipes:
        load_recipe(r)            # every recipe checked before any run starts
    _check_address(ray, address)
    check_seed_bases(train_kwargs.get("resume"), seeds)
    progress = bool(train_kwargs.pop("progress_bar", True))
    per = {n: {**train_kwargs, "recipe": str(r)} for n, r in zip(names, recipes)}
    jobs = []
    for n in names:
        (out / n).mkdir(parents=True, exist_ok=True)
        jobs += _unfinished(seeds, out / n, per[n])
    _run_all(jobs, ray=ray, address=address, progress=progress, n_total=len(seeds) * len(names))
    docs = {n: _write_seed_report(seeds, out / n, per[n]) for n in names}
    summary = {"seeds": list(seeds), "recipes": {
        n: {"recipe": per[n]["recipe"], "target": d["target"], "n_reached": d["n_reached"],
            "reached_at_env_steps": [r["reached_at_env_steps"] for r in d["seeds"]]} for n, d in docs.items()}}
    write_text_atomic(out / "recipes.json", json.dumps(summary, indent=1))
    return {"summary": summary, "recipes": docs}


def clone_seeds(seeds: Sequence[int], dataset: str | Path, out: str | Path, *, recipe, task: str = "full",
                epochs: int = 30, progress: bool = True) -> dict[str, Any]:
    """Behaviour cloning with each seed (network initialisation, batch order) into ``OUT/seed_<s>/``,
    each evaluated on the recipe's mission; finished seeds are skipped. Returns ``seeds.json``."""
    from .imitation import BCConfig, behaviour_clone
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for s in seeds:
        run = out / f"seed_{s}"
        if not (run / "bc_summary.json").is_file():
            behaviour_clone(dataset, run, recipe=recipe, task=task, config=BCConfig(epochs=epochs, seed=s),
                            progress=progress)
    doc = seed_report(out, seeds, report_targets(recipe.target))
    write_text_atomic(out / "seeds.json", json.dumps(doc, indent=1))
    return doc




def reached(entry: Mapping[str, Any], target: Mapping[str, float] = TARGET) -> bool:
    """Whether an evaluation entry's mean metrics reach every value of ``target`` (metric -> minimum;
    a metric the evaluation did not record, e.g. the clearance of an env that does not observe the
    structure, is not reached). An evaluation of several conditions (a recipe's ``eval_variants``)
    reaches it only when each condition's means do - their mean over all conditions could hide one
    that misses."""
    return all(m.get(k, -math.inf) >= v for m in _means(entry) for k, v in target.items())


def measured(entry: Mapping[str, Any], target: Mapping[str, float]) -> bool:
    """Whether an evaluation entry recorded every metric of ``target`` (a target no evaluation
    measured is reported as not measured, not as missed)."""
    return all(k in m for m in _means(entry) for k in target)


def _means(entry: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """The means an evaluation entry is judged by: each condition's when it flew several, else its own."""
    return [v["mean"] for v in entry.get("variants", ())] or [entry["mean"]]


def missed(result: Mapping[str, Any]) -> str:
    """How a report names a target a seed did not reach (its ``targets`` entry of :func:`seed_report`):
    "not met", or "not measured" when no evaluation recorded the target's metrics."""
    return "not met" if result.get("measured", True) else "not measured"


def seed_report(out: Path, seeds: Sequence[int],
                targets: Mapping[str, Mapping[str, float]] | None = None,
                base: Mapping[Any, Any] | None = None) -> dict[str, Any]:
    """Per seed: final evaluation, and for each of ``targets`` (name -> thresholds; default
    ``{"mission": TARGET}``) the first evaluation that met it. The first target is the headline:
    its result is also given as ``target`` / ``reached_target`` / ``n_reached``. ``base``: the
    env steps and wall time of the model a fine-tune stage started from (:func:`base_training`),
    or ``{seed: that}`` when every seed has its own base; the evaluations count them, so
    ``stage_env_steps`` / ``stage_wall_s`` subtract them."""
    targets = dict(targets or {"mission": TARGET})
    zero = {"env_steps": 0, "wall_time_s": 0.0}
    per_seed = bool(base) and all(isinstance(k, int) for k in base)
    bases = {s: dict(base.get(s, zero)) if per_seed else dict(base or zero) for s in seeds}
    rows = []
    for s in seeds:
        own = bases[s]
        evals = read_evaluations(out / f"seed_{s}")
        row: dict[str, Any] = {"seed": s, "evaluations": len(evals), "final": evals[-1]["mean"] if evals else None,
                               "targets": {}}
        for name, target in targets.items():
            hit = next((e for e in evals if reached(e, target)), None)
            row["targets"][name] = {"reached": hit is not None, "measured": any(measured(e, target) for e in evals),
                                    "env_steps": None if hit is None else hit["env_steps"],
                                    "wall_s": None if hit is None else hit["wall_time_s"],
                                    "stage_env_steps": None if hit is None else hit["env_steps"] - own["env_steps"],
                                    "stage_wall_s": None if hit is None else hit["wall_time_s"] - own["wall_time_s"]}
        head = row["targets"][next(iter(targets))]
        row.update(reached_target=head["reached"], reached_at_env_steps=head["env_steps"],
                   reached_at_wall_s=head["wall_s"])
        rows.append(row)
    summary = {name: {"target": dict(t), "n_reached": sum(r["targets"][name]["reached"] for r in rows)}
               for name, t in targets.items()}
    first = next(iter(targets))
    same = all(b == bases[seeds[0]] for b in bases.values()) if seeds else True
    shown: Any = (bases[seeds[0]] if seeds else dict(zero)) if same else {str(s): b for s, b in bases.items()}
    return {"target": dict(targets[first]), "target_name": first, "seeds": rows, "base": shown,
            "n_reached": summary[first]["n_reached"], "targets": summary}


def _steps(n: float) -> str:
    return f"{n / 1e6:.1f} M" if n >= 1e5 else f"{int(n):,}"


def _pct(x: Any) -> str:
    return "-" if x is None else f"{100.0 * float(x):.1f} %"


def seeds_markdown(out: Path, doc: Mapping[str, Any]) -> str:
    """The seeds report as a Markdown table the docs include: per seed its training so far (env
    steps, wall time, whether a ``--max-minutes`` chunk left it unfinished), its last evaluation
    (coverage, SM, CM, least clearance when recorded, how the episode ended) and when it first met
    the headline target."""
    lines = [f"| seed | env steps | wall time | status | coverage | SM | CM | least clearance | evaluation ended "
             f"| {doc.get('target_name', 'target')} target met at |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in doc["seeds"]:
        run = out / f"seed_{row['seed']}"
        found = _read_summary(run)
        summary = found or {}
        evals = read_evaluations(run)
        last = evals[-1] if evals else {}
        mean = last.get("mean", {})
        ends = sorted({str(e.get("termination") or ("complete" if e.get("mission_complete") else "time"))
                       for e in last.get("episodes", [])})
        status = ("running" if found is None else "finished" if _summary_finished(found) else "unfinished (clock)")
        least = mean.get("clearance_min_m")
        met = (f"{_steps(row['reached_at_env_steps'])} steps, {row['reached_at_wall_s'] / 60:.1f} min"
               if row["reached_target"] else missed(row["targets"].get(doc.get("target_name"), {})))
        lines.append(f"| {row['seed']} | {_steps(summary.get('env_steps', last.get('env_steps', 0)))} "
                     f"| {summary.get('wall_time_s', last.get('wall_time_s', 0.0)) / 60:.1f} min | {status} "
                     f"| {_pct(mean.get('coverage'))} | {_pct(mean.get('safety_sm'))} "
                     f"| {_pct(mean.get('centering_cm'))} "
                     f"| {'-' if least is None else f'{least:.2f} m'} | {', '.join(ends) or '-'} | {met} |")
    names = {"coverage": "coverage", "safety_sm": "SM", "centering_cm": "CM"}
    target = ", ".join(f"least clearance >= {v:g} m" if k == "clearance_min_m"
                       else f"{names.get(k, k)} >= {100 * v:g} %" for k, v in doc["target"].items())
    lines += ["", f"Last periodic evaluation of each seed (the recipe's evaluation mission); "
                  f"{doc.get('target_name', 'the')} target: {target}."]
    return "\n".join(lines) + "\n"


def plot_seed_curves(out: Path, seeds: Sequence[int], path: Path, fmt: str = "png",
                     targets: Mapping[str, Mapping[str, float]] | None = None,
                     base_steps: int | Mapping[int, int] = 0) -> Path:
    """Evaluation score min(coverage, SM) and CM against env steps, per seed and mean +- std, with
    each target's thresholds as dashed lines, as ``fmt`` (png, pdf, svg; ``path``'s suffix is
    replaced by it). ``base_steps``: a fine-tune stage's base model's steps (or ``{seed: steps}``),
    subtracted so the axis counts this stage's steps. The mean and spread cover the steps every seed has evaluated from
    (nothing extrapolated before a seed's first evaluation). Returns the written path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    curves = []
    for s in seeds:
        evals = read_evaluations(out / f"seed_{s}")
        if not evals:
            continue
        x = np.array([e["env_steps"] for e in evals], float) - (
            base_steps.get(s, 0) if isinstance(base_steps, Mapping) else base_steps)
        score = np.array([min(e["mean"]["coverage"], e["mean"]["safety_sm"]) for e in evals])
        cm = np.array([e["mean"]["centering_cm"] for e in evals])
        curves.append((x, score, cm))
        axes[0].plot(x, score, alpha=0.35, lw=1, label=f"seed {s}")
        axes[1].plot(x, cm, alpha=0.35, lw=1)
    if curves:
        grid = np.linspace(max(c[0].min() for c in curves), max(c[0].max() for c in curves), 50)
        for ax, k in ((axes[0], 1), (axes[1], 2)):
            ys = np.array([np.interp(grid, c[0], c[k]) for c in curves])
            m, sd = ys.mean(0), ys.std(0)
            ax.plot(grid, m, color="k", lw=2, label="mean over seeds")
            ax.fill_between(grid, m - sd, m + sd, color="k", alpha=0.15, label="+-1 std")
    draw_targets(axes, targets or {"mission": TARGET})
    fine_tune = any(base_steps.values()) if isinstance(base_steps, Mapping) else bool(base_steps)
    xlabel = "env steps in this stage" if fine_tune else "env steps"
    axes[0].set(xlabel=xlabel, ylabel="min(coverage, SM)", title="evaluation score")
    axes[1].set(xlabel=xlabel, ylabel="CM", title="centering")
    axes[0].legend(fontsize=7)
    if axes[1].get_legend_handles_labels()[0]:
        axes[1].legend(fontsize=7)
    fig.tight_layout()
    from wt_inspect_env.util.figure_io import save_and_close
    return save_and_close(fig, path, fmt)
