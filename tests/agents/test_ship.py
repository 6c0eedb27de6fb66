"""``agents.ship``: a trained run's model becomes a shipped one that loads by name and passes the
manifest check; bad input is refused before anything is written."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from agents import safe_load  # noqa: E402
from agents.policy import load_sb3_policy, sidecar_paths  # noqa: E402
from agents.safe_load import MODELS_DIR  # noqa: E402
from agents.ship import main, ship_model  # noqa: E402

SOURCE = "ppo_surface"


def _training_run(folder: Path) -> Path:
    """A run folder as ``wt-inspect train`` leaves it: best_model.* plus its curve and summary."""
    folder.mkdir(parents=True)
    for src, dst in zip(sidecar_paths(MODELS_DIR / f"{SOURCE}.zip"), sidecar_paths(folder / "best_model.zip")):
        shutil.copyfile(src, dst)
    (folder / "learning_curve.png").write_bytes(b"\x89PNG fake")
    (folder / "summary.json").write_text(json.dumps({"env_steps": 123}))
    return folder / "best_model.zip"


def test_a_shipped_model_loads_by_name_and_matches_the_manifest(tmp_path, monkeypatch):
    source = _training_run(tmp_path / "run" / "seed_1")
    models = tmp_path / "models"
    written = ship_model(source, "ppo_new", models_dir=models)
    assert {f.name for f in written} == {"ppo_new.zip", "ppo_new.json", "ppo_new.vecnormalize.json",
                                         "ppo_new_learning_curve.png", "ppo_new_training.json"}
    assert json.loads((models / "ppo_new_training.json").read_text()) == {"env_steps": 123}
    listed = json.loads((models / "MANIFEST.json").read_text())["files"]
    assert set(listed) == {"ppo_new.zip", "ppo_new.json", "ppo_new.vecnormalize.json"}
    monkeypatch.setattr(safe_load, "MODELS_DIR", models)
    assert safe_load.resolve_model_path("ppo_new") == models / "ppo_new.zip"
    safe_load.verify_shipped(models / "ppo_new.zip")
    load_sb3_policy("ppo", models / "ppo_new.zip")
    (models / "ppo_new.zip").write_bytes((models / "ppo_new.zip").read_bytes() + b"x")
    with pytest.raises(ValueError, match="SHA-256"):         # the manifest holds the shipped digest
        safe_load.verify_shipped(models / "ppo_new.zip")


def test_bad_input_is_refused_naming_it_and_writes_nothing(tmp_path, capsys):
    source = _training_run(tmp_path / "run")
    models = tmp_path / "models"
    with pytest.raises(ValueError, match=r"name 'Bad-Name'"):
        ship_model(source, "Bad-Name", models_dir=models)
    with pytest.raises(ValueError, match="not a model .zip"):
        ship_model(tmp_path / "run" / "missing.zip", "ppo_x", models_dir=models)
    assert not models.exists()
    (tmp_path / "run" / "best_model.json").unlink()
    with pytest.raises(ValueError, match="best_model.json"):
        ship_model(source, "ppo_x", models_dir=models)
    assert not models.exists()
    assert main([str(tmp_path / "nothing.zip"), "ppo_x"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: source") and "Traceback" not in err


def test_an_existing_name_needs_overwrite(tmp_path):
    source = _training_run(tmp_path / "run")
    models = tmp_path / "models"
    ship_model(source, "ppo_new", models_dir=models)
    with pytest.raises(ValueError, match="exists"):
        ship_model(source, "ppo_new", models_dir=models)
    ship_model(source, "ppo_new", models_dir=models, overwrite=True)
