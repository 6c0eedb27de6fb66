"""``wt-inspect rescore``: recorded runs' coverage under another camera or coverage rule, without flying.

Why: the camera and the coverage rule do not act on the flight, so "what would this flight have
covered with a 35 mm lens / without occlusion / with a 12 m range" is a question about the
recorded frames, answered in seconds instead of minutes of flight
(:func:`~wt_inspect.evaluation.runner.rescore_coverage`)::

    wt-inspect rescore results/paper_faithful/runs --camera '{"focal_length_mm": 24}'
    wt-inspect rescore RUN.npz --occlusion on --out rescored.csv

Each run keeps its own options (scenario, turbine, wind) with only ``--camera`` fields
(``CameraConfig``: focal length, sensor, range, incidence, the rule's references) and
``--occlusion`` replaced. Prints one line per run (flown and re-scored coverage); ``--out``
writes the same as CSV (atomically). Runs need their full trajectory (``--record-every 1``, the
default of ``evaluate``). Bad input is a one-line error, exit 2.
"""
from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path
from typing import Any, Mapping

from wt_inspect.commands.args import json_object
from wt_inspect_env.util.atomic_io import write_text_atomic

from ..evaluation.runner import load_run, rescore_coverage

COLUMNS = ("run_file", "controller", "wind", "seed", "coverage_flown", "coverage_rescored", "area_coverage_rescored")


def run_files(paths: list[str]) -> list[Path]:
    """Run files named directly or found in directories (``DIR/*.npz`` and ``DIR/runs/*.npz``)."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(p.glob("*.npz")) or sorted((p / "runs").glob("*.npz"))
            if not found:
                raise ValueError(f"no run files (*.npz) in {str(p)!r} or {str(p / 'runs')!r}")
            files += found
        elif p.is_file():
            files.append(p)
        else:
            raise ValueError(f"run {str(p)!r} is neither a run file nor a directory")
    return files


def changed_options(options: Mapping[str, Any], camera: Mapping[str, Any], occlusion: bool | None) -> dict[str, Any]:
    """A run's env options with the camera fields and occlusion replaced."""
    out = dict(options)
    if camera:
        base = out.get("camera") or {}
        if not isinstance(base, Mapping):
            raise ValueError(f"the run's camera option is not a field mapping ({base!r}); cannot change its fields")
        out["camera"] = {**base, **camera}
    if occlusion is not None:
        out["occlusion"] = occlusion
    return out


def _camera(text: str | None) -> dict[str, Any]:
    if not text:
        return {}
    try:
        return json_object("--camera")(text)
    except argparse.ArgumentTypeError as exc:
        raise ValueError(str(exc)) from None


def main(argv: list[str], prog: str = "wt-inspect rescore") -> int:
    """``wt-inspect rescore``: re-score the recorded runs named in ``argv``; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run files (.npz) or directories holding them (DIR or DIR/runs)")
    ap.add_argument("--camera", default=None, help="JSON object of CameraConfig fields to change, e.g. "
                    "'{\"focal_length_mm\": 35, \"incidence_reference\": \"optical_axis\"}'")
    ap.add_argument("--occlusion", choices=("on", "off"), default=None, help="count occluded triangles or not")
    ap.add_argument("--out", default=None, help="also write the table as CSV")
    args = ap.parse_args(argv)
    try:
        camera = _camera(args.camera)
        occlusion = None if args.occlusion is None else args.occlusion == "on"
        if not camera and occlusion is None:
            raise ValueError("nothing to change: give --camera and/or --occlusion")
        files = run_files(args.runs)
        if args.out is not None and Path(args.out).is_dir():
            raise ValueError(f"--out {args.out!r} is a directory; give a CSV file name")
        rows = []
        for f in files:
            result = load_run(f)
            score = rescore_coverage(result, changed_options(result.spec.env_options, camera, occlusion))
            s = result.spec
            rows.append({"run_file": f.name, "controller": s.controller, "wind": s.wind, "seed": s.seed,
                         "coverage_flown": float(result.metrics.get("coverage", float("nan"))),
                         "coverage_rescored": score["coverage"], "area_coverage_rescored": score["area_coverage"]})
            print(f"{f.name}: {s.controller}, wind {s.wind:g}: "
                  f"coverage {100 * rows[-1]['coverage_flown']:.1f} % flown, "
                  f"{100 * score['coverage']:.1f} % re-scored", flush=True)
    except (ValueError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    if args.out is not None:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
        try:
            write_text_atomic(Path(args.out), buf.getvalue())
        except OSError as exc:
            print(f"{prog}: error: cannot write {args.out!r}: {exc.strerror or exc}", file=sys.stderr)
            return 2
    return 0
