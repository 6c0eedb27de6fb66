"""Make a trained model a shipped one: ``python -m agents.ship SOURCE.zip NAME``.

A shipped model is what ``ppo:NAME`` loads by name (:func:`agents.safe_load.resolve_model_path`),
and each of its files is checked against ``agents/models/MANIFEST.json`` before it is loaded
(:func:`agents.safe_load.verify_shipped`). Copying the files by hand and forgetting the manifest
gives a model that refuses to load; so one function copies everything a shipped model consists of
and rewrites the manifest:

* ``NAME.zip``, ``NAME.json`` (the sidecar), ``NAME.vecnormalize.json`` - the loaded files;
* ``NAME_learning_curve.png`` and ``NAME_training.json`` - the run's learning curve and summary
  (from the source's folder, when the source is a training run's ``model.zip`` / ``best_model.zip``),
  which ``agents/models/README.md`` cites.

The source is checked first: it must load as a safe model (no pickled code), so nothing is shipped
that :func:`agents.policy.load_sb3_policy` would refuse.
"""
from __future__ import annotations

import argparse
import re
import shutil
import sys
from pathlib import Path

from wt_inspect_env.util.atomic_io import atomic_paths

from .policy import load_sb3_policy, load_sidecar, sidecar_paths
from .safe_load import MODELS_DIR, write_manifest

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


def _check_source(source: Path) -> tuple[list[Path], str]:
    """The source's files that exist (zip, sidecar, normalisation statistics if any) and its algorithm."""
    if source.suffix != ".zip" or not source.is_file():
        raise ValueError(f"source {str(source)!r} is not a model .zip file")
    algo = str(load_sidecar(source).get("algo"))      # ValueError naming the sidecar if missing or invalid
    return [f for f in sidecar_paths(source) if f.is_file()], algo


def ship_model(source: str | Path, name: str, *, models_dir: Path | None = None, overwrite: bool = False) -> list[Path]:
    """Copy the model ``source`` (a ``.zip`` with its sidecars) into ``models_dir`` (default the
    shipped models') as ``name``, with the run's learning curve and summary when they sit beside it,
    and rewrite the manifest. Returns the files written.

    ValueError (naming the argument) for a bad name, a missing source file, a model that would
    not load safely, or an existing model of that name unless ``overwrite``."""
    source = Path(source)
    models_dir = MODELS_DIR if models_dir is None else Path(models_dir)
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(f"name {name!r} must be lower-case letters, digits and _ (starting with a letter)")
    files, algo = _check_source(source)
    load_sb3_policy(algo, source)   # refuses unsafe or broken files
    target = models_dir / f"{name}.zip"
    if target.exists() and not overwrite:
        raise ValueError(f"name {name!r}: {str(target)!r} exists (pass overwrite=True / --overwrite to replace it)")
    pairs = [(f, t) for f, t in zip(sidecar_paths(source), sidecar_paths(target)) if f in files]
    extras = {source.parent / "learning_curve.png": models_dir / f"{name}_learning_curve.png",
              source.parent / "summary.json": models_dir / f"{name}_training.json"}
    pairs += [(s, d) for s, d in extras.items() if s.is_file()]
    models_dir.mkdir(parents=True, exist_ok=True)
    with atomic_paths(*(d for _, d in pairs)) as tmp:
        for (src, _), t in zip(pairs, tmp):
            shutil.copyfile(src, t)
    for stale in set(sidecar_paths(target)) - {d for _, d in pairs}:     # an overwritten model's leftovers
        stale.unlink(missing_ok=True)
    write_manifest(models_dir)
    return [d for _, d in pairs]


def main(argv: list[str] | None = None) -> int:
    """Command line: exit 2 with one line naming the bad argument, no traceback."""
    p = argparse.ArgumentParser(prog="python -m agents.ship", description=__doc__.splitlines()[0])
    p.add_argument("source", help="a trained model .zip (e.g. results/training/RUN/seed_1/best_model.zip)")
    p.add_argument("name", help="the shipped name (ppo:NAME loads it)")
    p.add_argument("--overwrite", action="store_true", help="replace a shipped model of that name")
    args = p.parse_args(argv)
    try:
        written = ship_model(args.source, args.name, overwrite=args.overwrite)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for f in written:
        print(f)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
