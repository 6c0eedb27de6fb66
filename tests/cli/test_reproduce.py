"""``wt-inspect reproduce``: the manifest covers every committed study, ``--check`` passes on the
checkout (every stale study named in results/STALE.md) and the machinery - run, provenance, check,
README numbers - works end to end on a study that does not fly."""
from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import pytest

from wt_inspect import reproduce
from wt_inspect.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]


def test_the_checkout_passes_the_check():
    """Everything but re-flying the behaviour digests (CI runs ``wt-inspect reproduce --check``
    after the tests, which flies them; tests/cli/test_behaviour.py checks that machinery)."""
    out = io.StringIO()
    studies = reproduce.load_manifest(ROOT / reproduce.MANIFEST)
    assert reproduce.check(ROOT, studies, out=out, fly=False) == 0, out.getvalue()
    assert len(studies) >= 30


def test_list_prints_every_study(capsys):
    assert cli_main(["reproduce", "--list", "--root", str(ROOT), "--only", "paper,lab", "--jobs", "2"]) == 0
    text = capsys.readouterr().out
    assert "paper  (results/paper;" in text and "--out results/paper --no-progress --jobs 2" in text
    assert "wt-inspect study wind-offset" in text


def test_bad_input_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli_main(["reproduce", "--list", "--root", str(ROOT), "--only", "nope"])
    assert e.value.code == 2 and "unknown study 'nope'" in capsys.readouterr().err
    bad = tmp_path / "m.toml"
    bad.write_text('[[study]]\nname = "x"\nfolder = "results/x"\ncommands = ["rm -rf /"]\n')
    with pytest.raises(SystemExit):
        cli_main(["reproduce", "--list", "--manifest", str(bad)])
    assert "wt-inspect ..." in capsys.readouterr().err


def _tiny_checkout(tmp_path: Path) -> Path:
    for d in ("paper_faithful", "paper_faithful_wind"):
        (tmp_path / "results" / d).mkdir(parents=True)
        shutil.copy(ROOT / "results" / d / "results.csv", tmp_path / "results" / d / "results.csv")
    (tmp_path / "results" / "reproduce.toml").write_text(
        '[[study]]\nname = "faithful"\nfolder = "results/paper_faithful"\ncommands = []\nmissing = "not here"\n\n'
        '[[study]]\nname = "smw"\nfolder = "results/paper_faithful_wind"\n'
        'commands = ["wt-inspect study sm-vs-wind --results results"]\n')
    return tmp_path


def test_a_study_listed_for_its_flown_digests_stays_listed_when_the_check_does_not_fly(tmp_path):
    root = _tiny_checkout(tmp_path)
    smw = reproduce.load_manifest(root / reproduce.MANIFEST)[1]
    prov = {"study": "smw", "commands": list(smw.commands), "complete": True, "code": "000000000000",
            "behaviour": {"seconds": 20.0, "runs": [{"run": "x", "digest": {}}]}}
    (root / smw.folder / "provenance.json").write_text(json.dumps(prov))
    (root / "results/STALE.md").write_text("| study | reason | measured difference |\n|---|---|---|\n"
                                           "| smw | flies differently here | 17 m |\n")
    out = io.StringIO()
    reproduce.check(root, [smw], out=out, fly=False)
    assert "still listed" not in out.getvalue() and "1 stale (1 of them listed" in out.getvalue()
    # a listed study judged by its code version is known to be current without flying: it must go
    del prov["behaviour"]
    prov["code"] = reproduce.code_version(smw)
    (root / smw.folder / "provenance.json").write_text(json.dumps(prov))
    out = io.StringIO()
    assert reproduce.check(root, [smw], out=out, fly=False) == 1 and "still listed in results/STALE.md: smw" in \
        out.getvalue()


@pytest.mark.slow
def test_the_check_over_two_processes_reports_what_one_does(tmp_path):
    """``--check --jobs 2`` re-flies studies in spawned workers: the same verdicts, in manifest
    order, and the same exit status as in one process - with a stale unlisted study among them."""
    root = _tiny_checkout(tmp_path)
    smw = reproduce.load_manifest(root / reproduce.MANIFEST)[1]
    prov = {"study": "smw", "commands": list(smw.commands), "complete": True, "code": reproduce.code_version(smw)}
    (root / smw.folder / "provenance.json").write_text(json.dumps(prov))
    studies = reproduce.load_manifest(root / reproduce.MANIFEST)
    outs = []
    for jobs in (1, 2):
        out = io.StringIO()
        assert reproduce.check(root, studies, out=out, jobs=jobs) == 1
        outs.append(out.getvalue())
    assert outs[0] == outs[1]
    assert "stale, not in results/STALE.md: faithful" in outs[1] and "1 current, 1 stale" in outs[1]


@pytest.mark.slow
def test_run_writes_provenance_and_check_follows_it(tmp_path, monkeypatch):
    monkeypatch.setenv("MPLBACKEND", "Agg")
    root = _tiny_checkout(tmp_path)
    assert cli_main(["reproduce", "--root", str(root), "--no-progress"]) == 0
    prov = json.loads((root / "results/paper_faithful_wind/provenance.json").read_text())
    assert prov["complete"] and prov["commands"] == ["wt-inspect study sm-vs-wind --results results"]
    assert (root / "results/paper_faithful_wind/sm_vs_wind.csv").is_file()
    studies = reproduce.load_manifest(root / reproduce.MANIFEST)
    out = io.StringIO()
    assert reproduce.check(root, studies, out=out) == 1          # 'faithful' is stale and not listed
    assert "stale, not in results/STALE.md: faithful" in out.getvalue() and "smw" not in out.getvalue()
    (root / "results/STALE.md").write_text("| study | reason | measured difference |\n|---|---|---|\n"
                                           "| faithful | no command | not measured |\n")
    assert reproduce.check(root, studies, out=io.StringIO()) == 0
    # a changed command makes the study stale; so would other code
    changed = [studies[0], reproduce.Study("smw", studies[1].folder, ("wt-inspect study sm-vs-wind --results .",))]
    out = io.StringIO()
    assert reproduce.check(root, changed, out=out) == 1 and "commands differ" in out.getvalue()
    prov["code"] = "000000000000"
    (root / "results/paper_faithful_wind/provenance.json").write_text(json.dumps(prov))
    out = io.StringIO()
    assert reproduce.check(root, studies, out=out) == 1 and "made by code 000000000000" in out.getvalue()
    # a second run skips nothing that is stale and reruns it
    assert cli_main(["reproduce", "--root", str(root), "--no-progress", "--only", "smw"]) == 0
    assert reproduce.check(root, studies, out=io.StringIO()) == 0


def test_only_run_files_of_the_current_code_are_resumed(tmp_path):
    """A study regenerated after a code change must not be rebuilt from the old code's flights:
    run files made by other code are discarded before the commands run, the current code's kept
    (an interrupted regeneration resumes), unreadable ones left to the commands."""
    import numpy as np

    runs = tmp_path / "study" / "rows" / "00_a" / "runs"
    runs.mkdir(parents=True)
    for name, code in (("old.npz", "0ld"), ("new.npz", "n3w")):
        np.savez_compressed(runs / name, meta=np.array(json.dumps({"code": code})))
    (runs / "broken.npz").write_bytes(b"not a run file")
    chunks = tmp_path / "study" / "chunks"                     # a resumable study's finished chunks
    chunks.mkdir()
    (chunks / "old.json").write_text(json.dumps({"code": "0ld", "rows": []}))
    (chunks / "bare.json").write_text(json.dumps([{"start": 0}]))     # older format: names no code
    (chunks / "new.json").write_text(json.dumps({"code": "n3w", "rows": []}))
    log = io.StringIO()
    assert reproduce.discard_foreign_runs(tmp_path / "study", "n3w", log) == 3
    assert sorted(p.name for p in runs.iterdir()) == ["broken.npz", "new.npz"]
    assert sorted(p.name for p in chunks.iterdir()) == ["new.json"]
    assert "discarded 3 run or chunk file(s)" in log.getvalue()
    assert reproduce.discard_foreign_runs(tmp_path / "study", "n3w", io.StringIO()) == 0


def test_a_grown_study_resumes_from_committed_runs_only_when_they_fly_the_same(tmp_path, monkeypatch):
    """A study whose command grows (a campaign given more episodes) keeps its committed run files
    when the current code flies their behaviour digests the same, and flies only what is new;
    without digests, when they differ, or with --force, the old code's run files are discarded."""
    import numpy as np

    from wt_inspect import behaviour

    folder = tmp_path / "results" / "grow"
    runs = folder / "runs"
    runs.mkdir(parents=True)
    study = reproduce.Study("grow", "results/grow", ("wt-inspect study sm-vs-wind --results results",))

    def fresh_runs() -> None:
        np.savez_compressed(runs / "old.npz", meta=np.array(json.dumps({"code": "0ld"})))

    def prov(**extra) -> None:
        (folder / reproduce.PROVENANCE).write_text(json.dumps(
            {"commands": ["wt-inspect campaign --episodes 2"], "complete": True, **extra}))

    seen = []

    def verify(commands, recorded, progress=None):
        seen.append(list(commands))
        return "" if recorded == {"runs": ["same"]} else "behaviour differs: x"

    monkeypatch.setattr(behaviour, "verify", verify)
    fresh_runs()
    prov()                                                       # no digests: discarded
    assert reproduce.runs_fly_the_same(tmp_path, study) == "no complete provenance with behaviour digests"
    prov(behaviour={"runs": ["same"]})
    assert reproduce.runs_fly_the_same(tmp_path, study) == ""
    assert seen[-1] == ["wt-inspect campaign --episodes 2"]      # verified with the commands they were made by
    prov(behaviour={"runs": ["other"]})
    assert reproduce.runs_fly_the_same(tmp_path, study) == "behaviour differs: x"
    prov(behaviour={"runs": ["same"]}, complete=False)
    assert reproduce.runs_fly_the_same(tmp_path, study) != ""

    # through run_study: the command is replaced by a no-op so only the run files' fate is tested
    monkeypatch.setattr(reproduce.subprocess, "run", lambda *a, **k: type("R", (), {"returncode": 1})())
    prov(behaviour={"runs": ["same"]})
    log = io.StringIO()
    assert not reproduce.run_study(tmp_path, study, list(study.commands), log)
    assert (runs / "old.npz").is_file() and "resuming from its committed run files" in log.getvalue()
    assert not reproduce.run_study(tmp_path, study, list(study.commands), io.StringIO(), fresh=True)
    assert not (runs / "old.npz").exists()
    fresh_runs()
    prov(behaviour={"runs": ["other"]})
    assert not reproduce.run_study(tmp_path, study, list(study.commands), io.StringIO())
    assert not (runs / "old.npz").exists()


def test_readme_numbers_must_come_from_the_named_file(tmp_path):
    root = _tiny_checkout(tmp_path)
    (root / "results/paper_faithful_wind/results.md").write_text("| a | b |\n|---|---|\n| x | 1.0 % |\n")
    block = "<!-- numbers: results/paper_faithful_wind/results.md -->\n| a | b |\n|---|---|\n{row}\n<!-- /numbers -->\n"
    (root / "README.md").write_text(block.format(row="| x | 1.0 % |"))
    assert reproduce.number_problems(root) == []
    (root / "README.md").write_text(block.format(row="| x | 2.0 % |"))
    assert reproduce.number_problems(root) == ["README.md: table row not in results/paper_faithful_wind/results.md: "
                                               "| x | 2.0 % |"]
    (root / "docs").mkdir()
    (root / "docs/page.md").write_text('--8<-- "results/nope/results.md"\n')
    assert any("includes results/nope/results.md" in p for p in reproduce.number_problems(root))
