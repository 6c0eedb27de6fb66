"""A recipe that names a ``base``: it states only what a training stage changes, and loads as the
complete recipe, exactly as if written out in full."""
import json
from pathlib import Path

import pytest

from agents.recipe import RECIPE_DIR, load_recipe

ROOT = Path(__file__).resolve().parents[2]


def _write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("recipe, runs", [
    ("ppo_full_scratch_near.json", "ppo_full_scratch_near_seeds"),
    ("ppo_full_scratch_ff.json", "ppo_full_scratch_ff_seeds"),
    ("ppo_full_many.json", "ppo_full_many_seeds"),
    ("ppo_full_many_robust.json", "ppo_full_many_robust_seeds"),
    ("ppo_full_many_wind.json", "ppo_full_many_wind_seeds"),
])
def test_a_stage_written_as_a_diff_is_the_recipe_its_committed_runs_trained_with(recipe, runs):
    """These recipes name their base; every committed seed of their study recorded the complete
    recipe it trained with, and the diff must resolve to that, key for key and in order (so the
    runs' sidecars and digests do not change)."""
    recorded = sorted((ROOT / "results/training" / runs).glob("seed_*/recipe.json"))
    assert len(recorded) == 5, f"the study's committed recipe.json files are missing: {recorded}"
    assert "base" in json.loads((RECIPE_DIR / recipe).read_text())
    resolved = json.dumps(load_recipe(RECIPE_DIR / recipe).to_dict(), indent=1)
    for path in recorded:
        assert resolved == json.dumps(json.loads(path.read_text()), indent=1), path


def test_objects_merge_key_by_key_and_lists_and_values_replace_whole(tmp_path):
    base = load_recipe(RECIPE_DIR / "ppo_full_many_robust.json").to_dict()
    _write(tmp_path / "base.json", base)
    stage = _write(tmp_path / "stage.json", {
        "base": "base.json", "env": {"reward": {"clearance_margin": 1.5}, "start_noise": 0.25},
        "env_variants": [{"wind": "none"}], "env_variant_weights": None, "turbines": {"n_turbines": 2}})
    got = load_recipe(stage).to_dict()
    assert got["env"]["reward"] == {**base["env"]["reward"], "clearance_margin": 1.5}
    assert got["env"]["start_noise"] == 0.25 and got["env"]["wind"] == base["env"]["wind"]
    assert got["env_variants"] == [{"wind": "none"}] and got["env_variant_weights"] is None
    assert got["turbines"] == {**base["turbines"], "n_turbines": 2}
    assert {k: v for k, v in got.items() if k not in ("env", "env_variants", "env_variant_weights", "turbines")} \
        == {k: v for k, v in base.items() if k not in ("env", "env_variants", "env_variant_weights", "turbines")}
    # a chain of bases resolves from the root down
    third = _write(tmp_path / "third.json", {"base": "stage.json", "env": {"reward": {"crash": 5.0}}})
    got3 = load_recipe(third).to_dict()
    assert got3["env"]["reward"] == {**got["env"]["reward"], "crash": 5.0}


def test_every_stage_recipe_is_checked_like_a_full_one(tmp_path):
    """A misspelt key in a stage is the same error as in a full recipe, not silently merged away."""
    _write(tmp_path / "base.json", load_recipe(RECIPE_DIR / "ppo_full_many_robust.json").to_dict())
    with pytest.raises(ValueError, match="start_nois"):
        load_recipe(_write(tmp_path / "a.json", {"base": "base.json", "env": {"start_nois": 1.0}}))


@pytest.mark.parametrize("files, match", [
    ({"a.json": {"base": "missing.json"}}, r"missing\.json.*the base of .*a\.json.*not found"),
    ({"a.json": {"base": "b.json"}, "b.json": {"base": "a.json"}},
     r"leads back to itself \(a\.json -> b\.json -> a\.json\)"),
    ({"a.json": {"base": "a.json"}}, r"leads back to itself"),
    ({"a.json": {"base": 3}}, r"base must be the file name of another recipe, got 3"),
    ({"a.json": {"base": "b.json"}, "b.json": [1, 2]}, r"b\.json.*must hold a JSON object, got list"),
])
def test_bad_bases_are_one_line_errors_naming_the_file(tmp_path, files, match):
    for name, data in files.items():
        _write(tmp_path / name, data)
    with pytest.raises(ValueError, match=match):
        load_recipe(tmp_path / "a.json")
