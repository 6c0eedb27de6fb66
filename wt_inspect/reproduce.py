"""``wt-inspect reproduce``: rerun every committed result from one manifest, and check that the
committed results are what the current code makes.

The manifest (``results/reproduce.toml``) lists every committed study as a results folder and the
commands that make it, run in order from the checkout's root. After a study's commands have all
succeeded, ``FOLDER/provenance.json`` records them with the package version, the machine, the code
version (a hash of :func:`wt_inspect.evaluation.runner.code_fingerprint` and of the subcommands'
modules) and - for a study that flies - *behaviour digests* of its first and last run
(:mod:`wt_inspect.behaviour`: the flown state over the first seconds, rounded).

``--check``: a study is *current* when its folder's provenance records exactly the manifest's
commands, all finished, and - behaviour decides, not the files - its digested runs flown again by
the current code agree with the recorded digests (a refactor that moves code keeps a study
current; a changed weight makes the studies that fly it stale). A study whose commands fly nothing
(training, tuning, analyses) is current when its code version is. A stale study must be named in
``results/STALE.md`` with the reason (else the check fails, as it does for a listed study that is
current again, a committed results folder the manifest does not cover, or a number in the README
that is not in the results file it names). Numbers in the README come from committed files: each
table between ``<!-- numbers: results/X/results.md -->`` and ``<!-- /numbers -->`` must consist of
lines of that file, verbatim (``--update-readme`` rewrites them from the files); docs pages include
the files themselves (``--8<-- "results/..."``), which must exist. ``--record-behaviour`` gives
studies that are current by their code version (that code made them) digests flown now.

Running: studies are run in manifest order, skipping those that are current (``--force`` reruns
them); each command resumes where it was interrupted (the commands themselves resume), and a study
whose commands did not all succeed gets no provenance. ``--only`` selects studies by name,
``--jobs``/``--backend`` are passed to the commands that take them; with ``--check``, ``--jobs``
processes re-fly the studies' digests side by side (same verdicts, same report).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib.util
import json
import platform
import re
import shlex
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

MANIFEST = Path("results/reproduce.toml")
STALE_FILE = Path("results/STALE.md")
PROVENANCE = "provenance.json"
README = Path("README.md")
DOCS = Path("docs")
# files under results/ that are no study's output
NOT_STUDY_FILES = {"results/reproduce.toml", "results/STALE.md", "results/.gitignore"}
# subcommands that take --jobs / --backend (the others run as given)
TAKES_JOBS = {"evaluate", "ablation", "tune", "campaign"}
TAKES_BACKEND = {"evaluate"}
NUMBERS_OPEN = re.compile(r"<!--\s*numbers:\s*(\S+)\s*-->")
NUMBERS_CLOSE = "<!-- /numbers -->"
SNIPPET = re.compile(r'^\s*--8<--\s*"([^"]+)"', re.M)


@dataclass(frozen=True)
class Study:
    """One manifest entry: a results folder and the commands that make it."""

    name: str
    folder: str
    commands: tuple[str, ...]
    missing: str = ""   # why the commands do not (yet) remake everything in the folder


def load_manifest(path: str | Path) -> list[Study]:
    """The manifest's studies (ValueError naming the file and the entry for a malformed one)."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"manifest {str(p)!r}: {exc}") from None
    studies, seen = [], set()
    for i, entry in enumerate(data.get("study", [])):
        unknown = set(entry) - {"name", "folder", "commands", "missing"}
        name, folder, commands = entry.get("name"), entry.get("folder"), entry.get("commands")
        if unknown or not isinstance(name, str) or not isinstance(folder, str) or not isinstance(commands, list) \
                or not all(isinstance(c, str) and c.startswith("wt-inspect ") for c in commands):
            extra = f"; unknown keys {sorted(unknown)}" if unknown else ""
            raise ValueError(f"manifest {str(p)!r}: study #{i} ({name!r}) needs name, folder and commands "
                             f"(a list of 'wt-inspect ...' strings){extra}")
        if name in seen:
            raise ValueError(f"manifest {str(p)!r}: study {name!r} is listed twice")
        seen.add(name)
        studies.append(Study(name, folder.rstrip("/"), tuple(commands), str(entry.get("missing", ""))))
    return studies


def _subcommand_modules(command: str) -> list[Path]:
    """Source files of the ``wt-inspect`` subcommand a command runs (for the code version)."""
    from wt_inspect.cli import COMMANDS
    argv = shlex.split(command)[1:]
    if not argv or argv[0] not in COMMANDS:
        return []
    names = [COMMANDS[argv[0]][0]]
    if argv[0] == "study" and len(argv) > 1:
        from wt_inspect.studies import STUDIES
        if argv[1] in STUDIES:
            names.append(STUDIES[argv[1]][0])
    files = []
    for name in names:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin:
            files.append(Path(spec.origin))
    return files


def code_version(study: Study, fingerprint: str | None = None) -> str:
    """The code version of a study: the flight code's fingerprint and its subcommands' modules."""
    from wt_inspect.evaluation.runner import code_fingerprint
    h = hashlib.sha256((fingerprint or code_fingerprint()).encode())
    for f in sorted({f for c in study.commands for f in _subcommand_modules(c)}):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def read_provenance(root: Path, study: Study) -> dict | None:
    """The provenance record of a study's results folder, or None if it is missing or unreadable."""
    p = root / study.folder / PROVENANCE
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return None


def staleness(root: Path, study: Study, fingerprint: str | None = None, *, fly: bool = True,
              progress: Callable[[str], None] | None = None) -> str:
    """Why ``study`` is stale ("" when it is current). A study whose provenance records behaviour
    digests (:mod:`wt_inspect.behaviour`) is current when the current code flies them again
    (``fly``; without it they are taken as recorded); any other study when its code version is the
    current one."""
    if not (root / study.folder).is_dir():
        return "its folder does not exist"
    if not study.commands:
        return "no command in the manifest" + (f" ({study.missing})" if study.missing else "")
    prov = read_provenance(root, study)
    if prov is None:
        return f"no {PROVENANCE} (made before the manifest recorded provenance)"
    if list(prov.get("commands", [])) != list(study.commands):
        return "its recorded commands differ from the manifest's"
    if not prov.get("complete"):
        return "its commands did not all finish"
    if prov.get("behaviour"):
        if not fly:
            return ""
        from wt_inspect.behaviour import verify
        with contextlib.chdir(root):   # the commands' relative paths (model files) are the checkout's
            return verify(study.commands, prov["behaviour"], progress=progress)
    want = code_version(study, fingerprint)
    if prov.get("code") != want:
        return f"made by code {prov.get('code')}, the current code is {want}"
    return ""


def record_behaviour(root: Path, study: Study, log=sys.stderr) -> bool:
    """Fly the digested runs of ``study`` with the current code and store their digests in its
    provenance; False (provenance untouched) if its commands fly nothing."""
    from wt_inspect.behaviour import digested_runs, record
    from wt_inspect_env.util.atomic_io import write_text_atomic
    prov = read_provenance(root, study)
    if prov is None or not digested_runs(study.commands):
        return False
    with contextlib.chdir(root):
        prov["behaviour"] = record(study.commands,
                                   progress=lambda r: print(f"reproduce {study.name}: digest of {r}", file=log,
                                                            flush=True))
    write_text_atomic(root / study.folder / PROVENANCE, json.dumps(prov, indent=1) + "\n")
    return True


def listed_stale(root: Path) -> dict[str, str]:
    """Study name -> reason, from the table of ``results/STALE.md`` (``| name | reason | ... |``)."""
    p = root / STALE_FILE
    if not p.is_file():
        return {}
    out = {}
    for line in p.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.lstrip().startswith("|") and len(cells) >= 2 and cells[0] not in {"study", ""} \
                and not set(cells[0]) <= set("-: "):
            out[cells[0].strip("`")] = cells[1]
    return out


def _tracked_results(root: Path) -> list[str]:
    res = subprocess.run(["git", "ls-files", "results"], cwd=root, capture_output=True, text=True)
    if res.returncode != 0:
        return [str(p.relative_to(root)) for p in (root / "results").rglob("*") if p.is_file()]
    return res.stdout.split()


def number_problems(root: Path) -> list[str]:
    """README tables not taken verbatim from the file they name, docs includes that do not exist."""
    problems = []
    readme = root / README
    text = readme.read_text() if readme.is_file() else ""
    for m in NUMBERS_OPEN.finditer(text):
        src = root / m.group(1)
        end = text.find(NUMBERS_CLOSE, m.end())
        if end < 0:
            problems.append(f"{README}: '<!-- numbers: {m.group(1)} -->' has no closing '{NUMBERS_CLOSE}'")
            continue
        if not src.is_file():
            problems.append(f"{README}: numbers from {m.group(1)}, which does not exist")
            continue
        have = set(src.read_text().splitlines())
        for line in text[m.end():end].splitlines():
            row = line.strip()
            if row.startswith("|") and not set(row) <= set("|-: ") and row not in have:
                problems.append(f"{README}: table row not in {m.group(1)}: {row[:80]}")
    for page in sorted((root / DOCS).rglob("*.md")) if (root / DOCS).is_dir() else []:
        for target in SNIPPET.findall(page.read_text()):
            if target.startswith("results/") and not (root / target).is_file():
                problems.append(f"{page.relative_to(root)}: includes {target}, which does not exist")
    return problems


def _table_after(lines: list[str], header: str) -> list[str] | None:
    """The table of ``lines`` whose header row is ``header``: that row, its rule and its rows (the
    first such table of the file), or None."""
    for i, line in enumerate(lines):
        if line.strip() == header:
            j = i + 1
            while j < len(lines) and lines[j].strip().startswith("|"):
                j += 1
            return [x.strip() for x in lines[i:j]]
    return None


def update_readme(root: Path) -> list[str]:
    """Rewrite each README table between ``<!-- numbers: FILE -->`` and ``<!-- /numbers -->`` with
    the table of FILE that has the same header row, so the README quotes what the results files
    say now; returns the problems it could not fix (no such file, no table with that header)."""
    readme = root / README
    text = readme.read_text()
    out, pos, problems = [], 0, []
    for m in NUMBERS_OPEN.finditer(text):
        end = text.find(NUMBERS_CLOSE, m.end())
        src = root / m.group(1)
        if end < 0 or not src.is_file():
            problems.append(f"{README}: cannot refresh the numbers from {m.group(1)}")
            continue
        block = text[m.end():end].strip("\n").splitlines()
        header = next((x.strip() for x in block if x.strip().startswith("|")), None)
        table = _table_after(src.read_text().splitlines(), header) if header else None
        if table is None:
            problems.append(f"{README}: {m.group(1)} has no table with the header {str(header)[:60]!r}")
            continue
        out.append(text[pos:m.end()] + "\n" + "\n".join(table) + "\n")
        pos = end
    out.append(text[pos:])
    new = "".join(out)
    if new != text:
        from wt_inspect_env.util.atomic_io import write_text_atomic
        write_text_atomic(readme, new)
    return problems


def _judged_by_flight(root: Path, study: Study) -> bool:
    """Whether ``study``'s verdict needs its behaviour digests flown (complete provenance with digests)."""
    prov = read_provenance(root, study)
    return bool(prov and prov.get("complete") and prov.get("behaviour"))


def _staleness_all(root: Path, studies: list[Study], fingerprint: str, *, fly: bool, jobs: int,
                   progress: bool) -> list[str]:
    """:func:`staleness` of every study, in the studies' order, over ``jobs`` processes.

    Why processes: re-flying the digests is nearly all of the check's time, one study's flights
    are independent of another's, and each flight is single-threaded Python and C. Workers are
    spawned, not forked - the parent may hold PyBullet and torch state that a fork would copy
    half-initialised."""
    from tqdm import tqdm
    bar = tqdm(total=len(studies), desc="check", unit="study", disable=not progress, file=sys.stderr)
    reasons: list[str] = [""] * len(studies)
    with bar:
        if jobs <= 1 or not fly or len(studies) < 2:
            for i, s in enumerate(studies):
                bar.set_postfix_str(s.name)
                reasons[i] = staleness(root, s, fingerprint, fly=fly)
                bar.update()
            return reasons
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed
        with ProcessPoolExecutor(max_workers=min(jobs, len(studies)),
                                 mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {pool.submit(staleness, root, s, fingerprint, fly=fly): i for i, s in enumerate(studies)}
            for fut in as_completed(futures):
                i = futures[fut]
                reasons[i] = fut.result()
                bar.set_postfix_str(studies[i].name)
                bar.update()
    return reasons


def check(root: Path, studies: list[Study], out=sys.stdout, *, fly: bool = True, progress: bool = False,
          jobs: int = 1) -> int:
    """Print every problem (one line each) and a summary; 0 when nothing unlisted is stale.
    ``fly``: re-fly the recorded behaviour digests (else they are taken as recorded); ``jobs``:
    processes that re-fly them side by side (the verdicts and the report do not depend on it)."""
    from wt_inspect.evaluation.runner import code_fingerprint
    fp = code_fingerprint()
    listed = listed_stale(root)
    names = {s.name for s in studies}
    problems, stale = [], []
    reasons = _staleness_all(root, studies, fp, fly=fly, jobs=jobs, progress=progress)
    for s, why in zip(studies, reasons):
        if why:
            stale.append(s.name)
            if s.name not in listed:
                problems.append(f"stale, not in {STALE_FILE}: {s.name} ({s.folder}): {why}")
        elif s.name in listed and not fly and _judged_by_flight(root, s):
            # without flying, a study judged by its behaviour digests is not known to be current: one
            # listed because its digests fly differently (on this machine) stays listed
            stale.append(s.name)
        elif s.name in listed:
            problems.append(f"current, but still listed in {STALE_FILE}: {s.name} - remove it there")
    problems += [f"{STALE_FILE} names {n}, which is not in the manifest" for n in sorted(set(listed) - names)]
    folders = [s.folder + "/" for s in studies]
    uncovered = sorted({f for f in _tracked_results(root) if f not in NOT_STUDY_FILES
                        and not any(f.startswith(d) for d in folders)})
    problems += [f"committed but in no study of {MANIFEST}: {f}" for f in uncovered]
    problems += number_problems(root)
    for line in problems:
        print(line, file=out)
    print(f"{len(studies)} studies: {len(studies) - len(stale)} current, {len(stale)} stale"
          f" ({len(set(stale) & set(listed))} of them listed in {STALE_FILE}); code {fp}", file=out)
    return 1 if problems else 0


def plan(studies: list[Study], jobs: int | None, backend: str | None) -> list[tuple[Study, list[str]]]:
    """Each study with its commands as they will run (``--jobs``/``--backend`` added where taken)."""
    out = []
    for s in studies:
        cmds = []
        for c in s.commands:
            argv = shlex.split(c)
            sub = argv[1] if len(argv) > 1 else ""
            if jobs is not None and sub in TAKES_JOBS and "--jobs" not in argv:
                c += f" --jobs {jobs}"
            if backend is not None and sub in TAKES_BACKEND and "--backend" not in argv:
                c += f" --backend {shlex.quote(backend)}"
            cmds.append(c)
        out.append((s, cmds))
    return out


def discard_foreign_runs(folder: Path, fingerprint: str, log=sys.stderr) -> int:
    """Delete the run files under ``folder`` (in any ``runs`` directory) and the finished chunk
    files (in any ``chunks`` directory: ``{"code": ..., "rows": [...]}``) made by other code than
    ``fingerprint``; returns how many. The commands resume from the files they find, so without
    this a study regenerated after a code change would be rebuilt from flights of the old code
    while its provenance names the new one. Run files whose metadata cannot be read are left to
    the commands (they fly such runs again); a chunk that names no code (an older bare list of
    rows, which its command would read) is discarded."""
    n = 0
    for path in sorted(folder.rglob("runs/*.npz")):
        try:
            with np.load(path, allow_pickle=False) as data:
                code = json.loads(str(data["meta"])).get("code")
        except (OSError, ValueError, KeyError, AttributeError):
            continue
        if code != fingerprint:
            path.unlink()
            n += 1
    for path in sorted(folder.rglob("chunks/*.json")):
        try:
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(doc, dict) or doc.get("code") != fingerprint:
            path.unlink()
            n += 1
    if n:
        print(f"reproduce: discarded {n} run or chunk file(s) under {folder} made by other code than {fingerprint}",
              file=log, flush=True)
    return n


def runs_fly_the_same(root: Path, study: Study) -> str:
    """Why the run files of ``study``'s committed folder may not be resumed from ("" when they
    may): its provenance must be complete and record behaviour digests, and the current code must
    fly those digests again for the commands they were recorded with. Such run files were made by
    code that flies the same, so a grown study (a campaign given more episodes) keeps them and
    flies only what is new."""
    prov = read_provenance(root, study)
    if not prov or not prov.get("complete") or not prov.get("behaviour"):
        return "no complete provenance with behaviour digests"
    from wt_inspect.behaviour import verify
    with contextlib.chdir(root):
        return verify(list(prov.get("commands", [])), prov["behaviour"])


def run_study(root: Path, study: Study, commands: list[str], log=sys.stderr, *, fresh: bool = False) -> bool:
    """Run a study's commands in order from ``root`` - resuming from run files of the current code,
    or from the committed ones when the current code flies their behaviour digests the same
    (:func:`runs_fly_the_same`; never with ``fresh``), others discarded
    (:func:`discard_foreign_runs`); on success write its provenance."""
    from wt_inspect.cli import version
    from wt_inspect.evaluation.report import hardware
    from wt_inspect.evaluation.runner import code_fingerprint
    from wt_inspect_env.util.atomic_io import write_text_atomic
    t0 = time.perf_counter()
    why = "--force asks for fresh flights" if fresh else runs_fly_the_same(root, study)
    if why:
        discard_foreign_runs(root / study.folder, code_fingerprint(), log)
    else:
        print(f"reproduce {study.name}: resuming from its committed run files (the current code flies their "
              "behaviour digests the same)", file=log, flush=True)
    for c in commands:
        print(f"reproduce {study.name}: {c}", file=log, flush=True)
        res = subprocess.run([sys.executable, "-m", "wt_inspect.cli", *shlex.split(c)[1:]], cwd=root)
        if res.returncode != 0:
            print(f"reproduce {study.name}: failed (exit {res.returncode}); rerun to resume", file=log)
            return False
    prov = {"study": study.name, "commands": list(study.commands), "ran": commands,
            "code": code_version(study), "version": version(), "machine": hardware(),
            "python": platform.python_version(), "wall_time_s": round(time.perf_counter() - t0, 1),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "complete": True}
    write_text_atomic(root / study.folder / PROVENANCE, json.dumps(prov, indent=1) + "\n")
    record_behaviour(root, study, log)
    return True


def _record_current(root: Path, studies: list[Study], *, force: bool) -> int:
    """``--record-behaviour``: give the studies that are current by their code version (that
    code made their files) behaviour digests flown now; ``force`` replaces existing digests."""
    from wt_inspect.evaluation.runner import code_fingerprint
    fp = code_fingerprint()
    n = 0
    for s in studies:
        prov = read_provenance(root, s) or {}
        if prov.get("behaviour") and not force:
            continue
        why = "" if prov.get("code") == code_version(s, fp) and prov.get("complete") and \
            list(prov.get("commands", [])) == list(s.commands) else "not current by its code version"
        if why:
            print(f"reproduce {s.name}: skipped, {why}", file=sys.stderr)
            continue
        if record_behaviour(root, s):
            n += 1
    print(f"behaviour digests recorded for {n} stud{'y' if n == 1 else 'ies'}")
    return 0


def main(argv: list[str], prog: str = "wt-inspect reproduce") -> int:
    """``wt-inspect reproduce``: rerun (or, with ``--check``, check) the manifest's studies."""
    ap = argparse.ArgumentParser(prog=prog, description="Rerun every committed result from the manifest "
                                 f"({MANIFEST}), or check without flying that each is current.")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true",
                      help="verify provenance and the README's numbers; re-fly each study's behaviour digests")
    mode.add_argument("--record-behaviour", action="store_true",
                      help="record behaviour digests for studies that are current by their code version")
    mode.add_argument("--list", action="store_true", help="print the plan: every study, its state and commands")
    mode.add_argument("--update-readme", action="store_true",
                      help="rewrite the README's number tables from the results files they name")
    ap.add_argument("--only", default=None, help="comma-separated study names")
    ap.add_argument("--jobs", type=int, default=None,
                    help="passed to the commands that take --jobs; with --check, processes that re-fly the digests")
    ap.add_argument("--backend", choices=("local", "ray"), default=None, help="passed to the evaluations")
    ap.add_argument("--force", action="store_true", help="rerun current studies too")
    ap.add_argument("--root", default=".", help="the checkout's root (default: the current directory)")
    ap.add_argument("--manifest", default=None, help=f"manifest file (default ROOT/{MANIFEST})")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    root = Path(args.root)
    try:
        studies = load_manifest(args.manifest or root / MANIFEST)
    except ValueError as exc:
        ap.error(str(exc))
    if args.jobs is not None and args.jobs < 1:
        ap.error(f"--jobs must be >= 1, got {args.jobs}")
    if args.only:
        wanted = [n for n in args.only.split(",") if n]
        unknown = [n for n in wanted if n not in {s.name for s in studies}]
        if unknown:
            ap.error(f"unknown study {unknown[0]!r}; known: {', '.join(s.name for s in studies)}")
        studies = [s for s in studies if s.name in wanted]
    if args.check:
        return check(root, studies, progress=not args.no_progress, jobs=args.jobs or 1)
    if args.record_behaviour:
        return _record_current(root, studies, force=args.force)
    if args.update_readme:
        problems = update_readme(root)
        for line in problems:
            print(line, file=sys.stderr)
        return 1 if problems else 0
    steps = plan(studies, args.jobs, args.backend)
    if args.list:
        from wt_inspect.evaluation.runner import code_fingerprint
        fp = code_fingerprint()
        for s, cmds in steps:
            why = staleness(root, s, fp, fly=False)
            state = "stale: " + why if why else (
                "behaviour recorded (--check re-flies it)" if _judged_by_flight(root, s) else "current")
            print(f"{s.name}  ({s.folder}; {state})")
            for c in cmds:
                print(f"    {c}")
            if s.missing:
                print(f"    note: {s.missing}")
        return 0
    todo = [(s, c) for s, c in steps if args.force or staleness(root, s)]
    todo = [(s, c) for s, c in todo if c]   # a study without commands cannot be run
    from tqdm import tqdm
    failed = []
    with tqdm(total=sum(len(c) for _, c in todo), desc="reproduce", unit="command",
              disable=args.no_progress) as bar:
        for s, cmds in todo:
            bar.set_postfix_str(s.name)
            if not run_study(root, s, cmds, fresh=args.force):
                failed.append(s.name)
            bar.update(len(cmds))
    if failed:
        print(f"{prog}: {len(failed)} study(ies) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0
