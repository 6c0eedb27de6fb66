"""``wt-inspect study imitation``: demonstrations, DAgger and the analysis in one resumable command."""
import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("minari")

from agents.recipe import RECIPE_DIR, Recipe, load_recipe  # noqa: E402
from wt_inspect.demonstrations import DemoConfig  # noqa: E402
from wt_inspect.studies import imitation  # noqa: E402


def test_label_stats_count_the_spread_and_the_saturated_share():
    Y = np.array([[1.0, 0.0, -1.0, 0.5], [-1.0, 0.0, 0.2, 0.5], [0.0, 0.0, 0.9985, 0.5], [0.0, 0.0, 0.0, 0.5]])
    s = imitation.label_stats(Y)
    assert s["samples"] == 4
    assert s["saturated_share"] == [0.5, 0.0, 0.25, 0.0]      # 0.9985 is not at the bound, -1 is
    assert s["label_std"][1] == 0.0 and s["label_std"][3] == 0.0
    assert s["label_std"][0] == pytest.approx(np.sqrt(0.5), abs=1e-4)
    assert imitation.label_stats(np.zeros((0, 4)))["samples"] == 0


def _tiny_recipe(name: str = "dagger_full.json") -> Recipe:
    d = load_recipe(RECIPE_DIR / name).to_dict()
    d["env"]["time_limit_s"] = 0.4
    d["eval_env"]["time_limit_s"] = 0.3
    d["policy_kwargs"]["net_arch"] = {"pi": [8], "vf": [8]}
    return Recipe.from_dict(d)


@pytest.mark.slow
def test_the_study_runs_from_nothing_resumes_and_refuses_other_demonstrations(tmp_path, monkeypatch):
    """From a relative --out, as the manifest gives it (Minari once doubled such a path)."""
    monkeypatch.chdir(tmp_path)
    demos = DemoConfig(winds=[{"type": "gust", "mean_speed": 4.0}], episodes=2, time_limit_s=0.4, full_missions=0)
    kw = dict(rounds=1, episodes_per_round=1, demo_config=demos, recipe=_tiny_recipe(), hold_seconds=0.2,
              progress=False, command="wt-inspect study imitation --out X --rounds 1")
    a = imitation.run_study("study", **kw)
    tmp_path = tmp_path / "study"
    labels = a["labels (agent actions [p, q, r, thrust] in [-1, 1])"]
    assert list(labels) == ["demonstrations", "dagger round 1 (beta 0.5)"]
    for s in labels.values():
        assert s["samples"] > 0 and all(0.0 <= x <= 1.0 for x in s["saturated_share"])
    md = (tmp_path / "results.md").read_text()
    assert "| 0 (behaviour cloning) |" in md and "| 1 | 0.5 |" in md and "`wt-inspect study imitation --out X" in md
    assert json.loads((tmp_path / "analysis.json").read_text()) == json.loads(json.dumps(a))
    assert (tmp_path / "summary.json").is_file() and (tmp_path / "learning_curve.png").is_file()
    from agents.policy import load_sidecar
    assert load_sidecar(tmp_path / "best_model.zip")["algo"] == "ppo"     # the result flies as ppo:OUT/best_model.zip
    # a rerun with one more round reuses the demonstrations and the finished round
    stamp = (tmp_path / "demos" / "wt-inspect" / imitation.DATASET / "wt_inspect_demos.json").stat().st_mtime_ns
    a2 = imitation.run_study("study", **{**kw, "rounds": 2})
    assert list(a2["labels (agent actions [p, q, r, thrust] in [-1, 1])"])[1:] == [
        "dagger round 1 (beta 0.5)", "dagger round 2 (beta 0.25)"]
    assert a2["labels (agent actions [p, q, r, thrust] in [-1, 1])"]["dagger round 1 (beta 0.5)"] == \
        labels["dagger round 1 (beta 0.5)"]
    assert (tmp_path / "demos" / "wt-inspect" / imitation.DATASET / "wt_inspect_demos.json").stat().st_mtime_ns == stamp
    with pytest.raises(ValueError, match="demonstrations of another configuration"):
        imitation.run_study("study", **{**kw, "demo_config": DemoConfig(**{**demos.__dict__, "episodes": 3})})


@pytest.mark.slow
def test_demonstrations_observe_what_the_recipes_features_need_and_the_seed_reaches_both(tmp_path):
    """structure_body features: the demonstrations are recorded with structure_observation, so the
    clone's features hold the structure (a dataset without it could not be encoded)."""
    demos = DemoConfig(winds=["none"], episodes=1, time_limit_s=0.4, full_missions=0, seed=3)
    imitation.run_study(tmp_path / "s", rounds=1, episodes_per_round=1, demo_config=demos, seed=3,
                        recipe=_tiny_recipe("dagger_full_structure.json"), hold_seconds=0.2, progress=False)
    meta = json.loads((tmp_path / "s" / "demos" / "wt-inspect" / imitation.DATASET / "wt_inspect_demos.json")
                      .read_text())
    assert meta["env_options"] == {"structure_observation": True} and meta["config"]["seed"] == 3
    with np.load(tmp_path / "s" / "run" / "demo_features.npz") as z:
        X = z["X"]
    n_plain = load_recipe(RECIPE_DIR / "dagger_full.json").spec.features.size
    assert X.shape[1] == n_plain + 4                     # structure_body: direction (3) and distance (1)
    assert np.all(X[:, -1] > 0) and np.ptp(X[:, -4:-1], axis=0).max() > 0
    assert json.loads((tmp_path / "s" / "summary.json").read_text())["config"]["seed"] == 3
    # the same folder with the plain recipe: the recorded demonstrations lack nothing it needs, but
    # were recorded for other options - refused rather than silently mixed
    with pytest.raises(ValueError, match="env options"):
        imitation.run_study(tmp_path / "s", rounds=1, episodes_per_round=1, demo_config=demos, seed=3,
                            recipe=_tiny_recipe(), hold_seconds=0.2, progress=False)


@pytest.mark.parametrize("argv, match", [
    (["--out", "{tmp}", "--demo-config", "{nope"], "--demo-config is not valid JSON"),
    (["--out", "{tmp}", "--demo-config", '{"episods": 2}'], "episods"),
    (["--out", "{tmp}", "--hold-seconds", "0"], "--hold-seconds must be positive"),
    (["--out", "{tmp}", "--seed", "-1"], "--seed must be a non-negative integer"),
    (["--out", "{tmp}", "--recipe", "{tmp}-missing.json"], "missing.json"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, match):
    argv = [a.replace("{tmp}", str(tmp_path / "o")) for a in argv]
    assert imitation.main(argv) == 2
    err = capsys.readouterr().err
    assert match in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o" / "results.md").exists()


def _fake_seed(run, *, demo_s, evals, dagger_s=500.0, rounds=8):
    meta = run / "demos" / "wt-inspect" / imitation.DATASET / "wt_inspect_demos.json"
    meta.parent.mkdir(parents=True)
    meta.write_text(json.dumps({"config": {}, "wall_time_s": demo_s}))
    (run / "evaluations.json").write_text(json.dumps(evals))
    (run / "summary.json").write_text(json.dumps({"wall_time_s": dagger_s, "env_steps": evals[-1]["env_steps"],
                                                  "rounds_done": rounds, "stopped_by_wall_clock": False}))


def _eval(steps, wall, cov, clearance):
    return {"round": 1, "env_steps": steps, "wall_time_s": wall, "episodes": [],
            "mean": {"coverage": cov, "safety_sm": cov, "centering_cm": 0.999, "clearance_min_m": clearance}}


def test_the_seeds_report_adds_the_recording_to_the_time_to_each_target(tmp_path):
    # seed 0 meets the mission at 100 s of DAgger but keeps its distance only at 300 s;
    # seed 1 never keeps it; recording 50 / 70 s
    _fake_seed(tmp_path / "seed_0", demo_s=50.0,
               evals=[_eval(1000, 30.0, 0.5, 3.0), _eval(2000, 100.0, 1.0, 2.7), _eval(3000, 300.0, 1.0, 2.95)])
    _fake_seed(tmp_path / "seed_1", demo_s=70.0, evals=[_eval(1000, 40.0, 1.0, 2.5)])
    doc = imitation.seeds_document(tmp_path, [0, 1])
    s0, s1 = doc["seeds"]
    assert s0["targets"]["mission"]["from_nothing_s"] == 150.0
    assert s0["targets"]["mission and clearance"]["from_nothing_s"] == 350.0
    assert s1["targets"]["mission"]["from_nothing_s"] == 110.0
    assert not s1["targets"]["mission and clearance"]["reached"]
    assert doc["targets"]["mission and clearance"]["n_reached"] == 1 and doc["targets"]["mission"]["n_reached"] == 2
    md = imitation.seeds_markdown(tmp_path, doc, "wt-inspect study imitation --seeds 0,1")
    assert "mission and clearance target: 1 of 2; mission target: 2 of 2" in md
    assert "| 0 | 0.8 min | 8.3 min | 5.8 min | 2.5 min |" in md
    assert "| 1 | 1.2 min | 8.3 min | not met | 1.8 min |" in md
    # evaluations on an env that does not observe the structure record no clearance: that target
    # is reported as not measured, not as missed
    for s in (0, 1):
        path = tmp_path / f"seed_{s}" / "evaluations.json"
        evals = json.loads(path.read_text())
        for e in evals:
            del e["mean"]["clearance_min_m"]
        path.write_text(json.dumps(evals))
    md = imitation.seeds_markdown(tmp_path, imitation.seeds_document(tmp_path, [0, 1]), "wt-inspect study imitation")
    assert "mission and clearance target: not measured" in md and "mission target: 2 of 2" in md
    one = imitation.seeds_markdown(tmp_path, imitation.seeds_document(tmp_path, [0]), "wt-inspect study imitation")
    assert one.startswith("# DAgger from nothing over 1 seed\n")
    assert "| 1 | 1.2 min | 8.3 min | not measured | 1.8 min |" in md
    assert imitation._seed_done(tmp_path / "seed_0", 8) is False          # no results.md: not finished
    (tmp_path / "seed_0" / "results.md").write_text("x")
    assert imitation._seed_done(tmp_path / "seed_0", 8) and not imitation._seed_done(tmp_path / "seed_0", 9)


@pytest.mark.slow
def test_seeds_run_each_seed_into_its_folder_with_its_own_demonstrations_and_skip_finished_ones(tmp_path):
    demos = DemoConfig(winds=["none"], episodes=1, time_limit_s=0.4, full_missions=0)
    kw = dict(rounds=1, episodes_per_round=1, demo_config=demos, recipe=_tiny_recipe(), hold_seconds=0.2,
              progress=False, command="wt-inspect study imitation --seeds 0,1")
    doc = imitation.run_seeds(tmp_path, [0, 1], **kw)
    assert [r["seed"] for r in doc["seeds"]] == [0, 1]
    for s in (0, 1):
        meta = json.loads((tmp_path / f"seed_{s}" / "demos" / "wt-inspect" / imitation.DATASET
                           / "wt_inspect_demos.json").read_text())
        assert meta["config"]["seed"] == s and meta["wall_time_s"] > 0
        assert doc["seeds"][s]["demonstrations_s"] == meta["wall_time_s"] and doc["seeds"][s]["dagger_s"] > 0
    assert (tmp_path / "learning_curves_seeds.png").is_file()
    assert json.loads((tmp_path / "seeds.json").read_text()) == json.loads(json.dumps(doc))
    assert "# DAgger from nothing over 2 seeds" in (tmp_path / "results.md").read_text()
    stamp = (tmp_path / "seed_1" / "results.md").stat().st_mtime_ns
    imitation.run_seeds(tmp_path, [0, 1], **kw)
    assert (tmp_path / "seed_1" / "results.md").stat().st_mtime_ns == stamp
