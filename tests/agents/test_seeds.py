"""Several seeds of one recipe (local and Ray), resumption, the seed report; models by name."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

from agents.recipe import Recipe, default_recipe_path  # noqa: E402
from agents.safe_load import resolve_model_path, shipped_models  # noqa: E402
from agents.seeds import measured, parse_seeds, reached, seed_report, train_seeds  # noqa: E402


def _tiny_recipe_file(tmp_path):
    data = json.loads(default_recipe_path("ppo").read_text())
    data["env"] = {**data["env"], "time_limit_s": 2.0}
    data["eval_env"] = {"start_noise": 0.0, "time_limit_s": 1.0}
    data["algo_kwargs"] = {**data["algo_kwargs"], "n_steps": 32, "batch_size": 32, "n_epochs": 1}
    data["policy_kwargs"] = {**data["policy_kwargs"], "net_arch": {"pi": [8], "vf": [8]}}
    data.update(eval_every_env_steps=300, checkpoint_every_env_steps=300)
    Recipe.from_dict(data)
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps(data))
    return str(path)


def test_parse_seeds():
    assert parse_seeds("0, 1,4") == [0, 1, 4]
    for bad in ("", "a", "1,1", "-1", "1.5"):
        with pytest.raises(ValueError, match="--seeds"):
            parse_seeds(bad)


@pytest.mark.slow
def test_local_seeds_train_report_and_skip_finished_runs(tmp_path):
    kw = dict(algo="ppo", task="surface", timesteps=600, n_envs=2, recipe=_tiny_recipe_file(tmp_path),
              progress_bar=False)
    doc = train_seeds([0, 1], tmp_path / "out", **kw)
    assert [r["seed"] for r in doc["seeds"]] == [0, 1]
    assert all(r["evaluations"] >= 2 for r in doc["seeds"])
    assert (tmp_path / "out" / "learning_curves_seeds.png").stat().st_size > 1000
    stamp = (tmp_path / "out" / "seed_0" / "summary.json").stat().st_mtime_ns
    doc2 = train_seeds([0, 1], tmp_path / "out", **kw)        # both finished: nothing retrained
    assert (tmp_path / "out" / "seed_0" / "summary.json").stat().st_mtime_ns == stamp
    assert doc2["seeds"] == doc["seeds"]
    # the report finds when a seed met a target it can meet
    low = seed_report(tmp_path / "out", [0, 1], {"low": {"coverage": 0.0, "safety_sm": 0.0, "centering_cm": -1.0}})
    assert low["n_reached"] == 2 and low["seeds"][0]["reached_at_env_steps"] > 0
    assert not reached({"mean": {"coverage": 0.98, "safety_sm": 1.0, "centering_cm": 1.0}})


def _fake_evaluations(run, entries):
    run.mkdir(parents=True)
    (run / "evaluations.json").write_text(json.dumps(
        [{"env_steps": n, "wall_time_s": n / 1000.0, "mean": dict(zip(("coverage", "safety_sm", "centering_cm"), m))}
         for n, m in entries]))


def test_seed_report_judges_the_recipe_target_first_and_the_mission_target_beside_it(tmp_path):
    from agents.seeds import TARGET, report_targets
    _fake_evaluations(tmp_path / "seed_0", [(1000, (0.95, 0.92, 0.98)), (2000, (1.0, 1.0, 0.996))])
    _fake_evaluations(tmp_path / "seed_1", [(1000, (0.95, 0.85, 0.98)), (2000, (0.99, 0.91, 0.99))])
    targets = report_targets({"coverage": 0.9, "safety_sm": 0.9})
    assert list(targets) == ["recipe", "mission"] and targets["mission"] == TARGET
    doc = seed_report(tmp_path, [0, 1], targets)
    assert doc["target_name"] == "recipe" and doc["n_reached"] == 2
    assert [r["reached_at_env_steps"] for r in doc["seeds"]] == [1000, 2000]
    assert doc["targets"]["mission"]["n_reached"] == 1
    assert doc["seeds"][0]["targets"]["mission"] == {"reached": True, "measured": True, "env_steps": 2000,
                                                     "wall_s": 2.0, "stage_env_steps": 2000, "stage_wall_s": 2.0}
    # a fine-tune stage's evaluations count the base model's steps: the stage columns subtract them
    staged = seed_report(tmp_path, [0, 1], targets, base={"env_steps": 500, "wall_time_s": 0.5})
    assert staged["seeds"][0]["targets"]["recipe"]["stage_env_steps"] == 500
    assert staged["seeds"][0]["targets"]["recipe"]["stage_wall_s"] == pytest.approx(0.5)
    assert doc["seeds"][1]["targets"]["mission"]["reached"] is False
    assert list(report_targets(None)) == ["mission"]
    # the Markdown table the docs include: one row per seed, its last evaluation and when it met the target
    from agents.seeds import seeds_markdown
    rows = [line for line in seeds_markdown(tmp_path, doc).splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == 3 and "recipe target met at" in rows[0]
    assert rows[1].startswith("| 0 |") and "| 100.0 % | 100.0 % | 99.6 % |" in rows[1]
    assert rows[1].endswith("| 1,000 steps, 0.0 min |")
    assert rows[2].startswith("| 1 |") and "| 99.0 % | 91.0 % | 99.0 % |" in rows[2]
    assert rows[2].endswith("| 2,000 steps, 0.0 min |")
    mission = seeds_markdown(tmp_path, seed_report(tmp_path, [0, 1], {"mission": TARGET}))
    assert "mission target met at" in mission and mission.count("| not met |") == 1
    assert rows[1].startswith("| 0 | 2,000 | 0.0 min | running |")   # no summary.json yet: its last evaluation's steps
    # a target on a metric no evaluation recorded (the clearance of an env that does not observe the
    # structure) is not measured - not missed
    unmeasured = seed_report(tmp_path, [0, 1], {"clearance": {**TARGET, "clearance_min_m": 2.9}})
    assert unmeasured["n_reached"] == 0
    assert [r["targets"]["clearance"]["measured"] for r in unmeasured["seeds"]] == [False, False]
    table = seeds_markdown(tmp_path, unmeasured)
    assert table.count("| not measured |") == 2 and "| not met |" not in table


@pytest.mark.parametrize("bad, match", [({"coverage": 1.5}, "recipe target coverage must be a fraction"),
                                        ({"coverage": "0.9"}, "recipe target coverage must be a fraction"),
                                        ({"clearance_min_m": 0.0}, "clearance_min_m must be a positive distance"),
                                        ({"clearance_min_m": float("inf")}, "clearance_min_m must be a positive"),
                                        ({"speed": 0.9}, "speed"), ({}, "non-empty dict")])
def test_recipe_target_is_checked(bad, match):
    data = json.loads(default_recipe_path("ppo").read_text())
    with pytest.raises(ValueError, match=match):
        Recipe.from_dict({**data, "target": bad})
    assert Recipe.from_dict({**data, "target": {"coverage": 0.9}}).target == {"coverage": 0.9}
    assert Recipe.from_dict({**data, "target": {"clearance_min_m": 2.9}}).target == {"clearance_min_m": 2.9}


def test_a_clearance_target_needs_the_recorded_clearance_and_the_best_model_pays_for_a_close_pass():
    from agents.training import episode_score, summarize_episodes
    target = {"coverage": 0.99, "clearance_min_m": 2.9}
    assert reached({"mean": {"coverage": 1.0, "clearance_min_m": 2.95}}, target)
    assert not reached({"mean": {"coverage": 1.0, "clearance_min_m": 2.5}}, target)
    assert not reached({"mean": {"coverage": 1.0}}, target)          # not recorded: not met
    # several conditions (eval_variants): each must reach it, their mean over conditions does not count
    calm, gust = {"coverage": 1.0, "safety_sm": 0.997}, {"coverage": 1.0, "safety_sm": 0.983}
    both = {"mean": {"coverage": 1.0, "safety_sm": 0.990}, "variants": [{"mean": calm}, {"mean": gust}]}
    sm = {"coverage": 0.99, "safety_sm": 0.99}
    assert reached({"mean": both["mean"]}, sm) and not reached(both, sm)
    assert reached({**both, "variants": [{"mean": calm}, {"mean": calm}]}, sm)
    assert not measured({**both, "variants": [{"mean": calm}, {"mean": {"coverage": 1.0}}]}, sm)
    close = {"coverage": 1.0, "safety_sm": 0.995, "clearance_min_m": 2.4, "d_min_m": 3.0}
    clear = {"coverage": 1.0, "safety_sm": 0.96, "clearance_min_m": 3.1, "d_min_m": 3.0}
    assert episode_score(close) == pytest.approx(0.8) and episode_score(clear) == pytest.approx(0.96)
    assert episode_score({"coverage": 0.7, "safety_sm": 0.9}) == pytest.approx(0.7)   # no structure observed
    from agents.training import METRIC_KEYS as keys
    eps = [{**dict.fromkeys(keys, 1.0), **close, "episode_return": 1.0, "steps": 1},
           {**dict.fromkeys(keys, 1.0), **clear, "episode_return": 1.0, "steps": 1}]
    out = summarize_episodes(eps)
    assert out["score"] == pytest.approx(0.88) and out["mean"]["clearance_min_m"] == pytest.approx(2.4)


def test_each_seed_can_start_from_its_own_base_and_the_report_counts_its_own_stage(tmp_path):
    from agents.seeds import check_seed_bases, seed_base
    assert seed_base("blade/seed_{seed}/model.zip", 3) == "blade/seed_3/model.zip"
    assert seed_base("base.zip", 3) == "base.zip" and seed_base(None, 3) is None
    (tmp_path / "seed_0").mkdir()
    (tmp_path / "seed_0" / "model.zip").write_bytes(b"x")
    check_seed_bases(str(tmp_path / "seed_{seed}" / "model.zip"), [0])
    with pytest.raises(ValueError, match=r"--resume: no model .*seed_1.* for seed 1"):
        check_seed_bases(str(tmp_path / "seed_{seed}" / "model.zip"), [0, 1])
    # per-seed bases: each seed's stage steps and wall time subtract its own base's
    _fake_evaluations(tmp_path / "r" / "seed_0", [(1500, (1.0, 1.0, 0.996))])
    _fake_evaluations(tmp_path / "r" / "seed_1", [(2500, (1.0, 1.0, 0.996))])
    bases = {0: {"env_steps": 1000, "wall_time_s": 1.0}, 1: {"env_steps": 2000, "wall_time_s": 1.5}}
    doc = seed_report(tmp_path / "r", [0, 1], base=bases)
    assert [r["targets"]["mission"]["stage_env_steps"] for r in doc["seeds"]] == [500, 500]
    assert [r["targets"]["mission"]["stage_wall_s"] for r in doc["seeds"]] == [0.5, 1.0]
    assert doc["base"] == {"0": bases[0], "1": bases[1]}
    one = {"env_steps": 1000, "wall_time_s": 1.0}
    assert seed_report(tmp_path / "r", [0, 1], base=one)["base"] == one


@pytest.mark.slow
def test_curriculum_seeds_fine_tune_their_own_seeds_models(tmp_path):
    """``--resume DIR/seed_{seed}/model.zip``: seed s fine-tunes seed s's model of the stage before."""
    recipe = _tiny_recipe_file(tmp_path)
    kw = dict(algo="ppo", task="surface", timesteps=300, n_envs=1, recipe=recipe, progress_bar=False)
    train_seeds([0, 1], tmp_path / "stage1", **kw)
    with pytest.raises(ValueError, match="--resume: no model"):
        train_seeds([0, 2], tmp_path / "bad",
                    **{**kw, "resume": str(tmp_path / "stage1" / "seed_{seed}" / "model.zip")})
    assert not (tmp_path / "bad").exists()
    doc = train_seeds([0, 1], tmp_path / "stage2",
                      **{**kw, "resume": str(tmp_path / "stage1" / "seed_{seed}" / "model.zip")})
    for s in (0, 1):
        summary = json.loads((tmp_path / "stage2" / f"seed_{s}" / "summary.json").read_text())
        assert summary["resumed_from"] == str(tmp_path / "stage1" / f"seed_{s}" / "model.zip")
        first = json.loads((tmp_path / "stage1" / f"seed_{s}" / "summary.json").read_text())["env_steps"]
        assert doc["base"].get(str(s), doc["base"])["env_steps"] == first   # one dict when the bases agree
    assert (tmp_path / "stage2" / "learning_curves_seeds.png").is_file()


@pytest.mark.slow
def test_fine_tune_seeds_start_from_one_base_take_the_recipes_rollout_and_resume(tmp_path):
    """``--seeds`` with ``--resume``: every seed fine-tunes the same base model, seeded (the same
    seed twice gives the same weights, two seeds differ), with the recipe's rollout length (not
    the base's), and an interrupted seed resumes counting only its own stage's steps."""
    import zipfile

    from agents.training import train
    recipe = _tiny_recipe_file(tmp_path)
    base = train("ppo", "surface", 300, 1, tmp_path / "base", recipe=recipe, progress_bar=False)["final_model"]
    data = json.loads(Path(recipe).read_text())
    data["algo_kwargs"]["n_steps"] = 16
    data["algo_kwargs"]["batch_size"] = 16
    ft = tmp_path / "ft.json"
    ft.write_text(json.dumps(data))
    kw = dict(algo="ppo", task="surface", timesteps=600, n_envs=2, recipe=str(ft), resume=base, progress_bar=False)
    doc = train_seeds([0, 1], tmp_path / "a", **kw)
    base_steps = doc["base"]["env_steps"]
    assert base_steps > 0 and doc["resumed_from"] == base

    def params(run):
        with zipfile.ZipFile(run / "model.zip") as z:
            return z.read("policy.pth")

    def n_steps(run):
        with zipfile.ZipFile(run / "model.zip") as z:
            return json.loads(z.read("data"))["n_steps"]

    a0, a1 = tmp_path / "a" / "seed_0", tmp_path / "a" / "seed_1"
    assert n_steps(a0) == 16
    assert params(a0) != params(a1)
    train_seeds([0], tmp_path / "b", **kw)
    assert params(tmp_path / "b" / "seed_0") == params(a0)
    # interrupted after its first checkpoint: the rerun trains only the rest of the stage
    for f in ("summary.json", "model.zip", "model.json"):    # killed before its end: no final model
        (a1 / f).unlink()
    step = lambda f: int(f.name.split("_")[1].split(".")[0])   # noqa: E731
    ckpts = sorted(a1.glob("checkpoints/ckpt_*"), key=step)
    first = step(ckpts[0])
    for late in ckpts:
        if step(late) != first:
            late.unlink()
    assert (a1 / "checkpoints" / f"ckpt_{first}.zip").is_file() and first < base_steps + 600
    train_seeds([1], tmp_path / "a", **kw)
    total = json.loads((a1 / "summary.json").read_text())["env_steps"]
    assert base_steps + 600 <= total < base_steps + 600 + 2 * 16 * 4 * 2


@pytest.mark.slow
def test_a_seed_stopped_by_the_clock_is_resumed_from_its_final_model_by_the_same_command(tmp_path):
    """``--max-minutes`` chunks: a seed stopped by the wall clock short of its steps is not
    finished; the next call resumes it from its final model (saved after its last checkpoint) and
    trains only the rest; a seed that reached its steps is finished."""
    from agents.seeds import _latest_checkpoint, seed_finished
    kw = dict(algo="ppo", task="surface", timesteps=1200, n_envs=2, recipe=_tiny_recipe_file(tmp_path),
              progress_bar=False)
    run = tmp_path / "out" / "seed_0"
    train_seeds([0], tmp_path / "out", max_minutes=1e-4, **kw)
    first = json.loads((run / "summary.json").read_text())
    assert first["stopped_by_wall_clock"] and first["env_steps"] < first["target_env_steps"] == 1200
    assert not seed_finished(run)
    assert _latest_checkpoint(run) == run / "model.zip"
    assert "| unfinished (clock) |" in (tmp_path / "out" / "seeds.md").read_text()
    train_seeds([0], tmp_path / "out", **kw)
    done = json.loads((run / "summary.json").read_text())
    assert seed_finished(run) and not done["stopped_by_wall_clock"]
    assert done["resumed_from"] == str(run / "model.zip")
    assert 1200 <= done["env_steps"] < 1200 + 2 * 32 * 4 * 2
    assert done["wall_time_s"] >= first["wall_time_s"]
    assert "| finished |" in (tmp_path / "out" / "seeds.md").read_text()


@pytest.mark.slow
def test_ray_seeds(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.setenv("RAY_ADDRESS", "192.0.2.2:6379")   # no --address: a private instance, not this
    kw = dict(algo="ppo", task="surface", timesteps=300, n_envs=1, recipe=_tiny_recipe_file(tmp_path),
              progress_bar=False)
    doc = train_seeds([3, 4], tmp_path / "out", ray=True, **kw)
    assert all((tmp_path / "out" / f"seed_{s}" / "model.zip").is_file() for s in (3, 4))
    assert len(doc["seeds"]) == 2
    import ray
    assert not ray.is_initialized()      # the private instance it started is gone


def test_shipped_models_resolve_by_name(tmp_path):
    assert "ppo_surface" in shipped_models()
    assert resolve_model_path("ppo_surface").name == "ppo_surface.zip"
    f = tmp_path / "m.zip"
    f.write_bytes(b"x")
    assert resolve_model_path(str(f)) == f
    with pytest.raises(ValueError, match="neither a file nor a shipped model; shipped: ppo_blade"):
        resolve_model_path("ppo_nothing")


def test_route_points_chain_runs_and_the_figure_is_drawn(tmp_path):
    from agents.curves import plot_routes, route_points
    _fake_evaluations(tmp_path / "stage1", [(2000, (1.0, 0.9, 0.98))])
    _fake_evaluations(tmp_path / "stage2", [(3000, (1.0, 1.0, 0.99)), (4000, (1.0, 1.0, 0.996))])
    pts = route_points([tmp_path / "stage2", tmp_path / "stage1"])
    assert [p["env_steps"] for p in pts] == [2000, 3000, 4000]        # ordered by time, not by argument
    assert pts[0]["wall_min"] == pytest.approx(2.0 / 60.0) and pts[0]["safety_sm"] == 0.9
    out = plot_routes({"a": pts}, tmp_path / "routes.png", target={"coverage": 0.99, "centering_cm": 0.995})
    assert out.stat().st_size > 1000
    with pytest.raises(ValueError, match="has no evaluations.json"):
        route_points([tmp_path / "missing"])


@pytest.mark.slow
def test_several_recipes_with_seeds_each_get_a_report_and_the_comparison(tmp_path):
    from agents.seeds import train_recipes
    a = _tiny_recipe_file(tmp_path)
    data = json.loads(Path(a).read_text())
    data["algo_kwargs"]["n_epochs"] = 2
    b = tmp_path / "tiny_b.json"
    b.write_text(json.dumps(data))
    res = train_recipes([a, str(b)], [0], tmp_path / "out", algo="ppo", task="surface", timesteps=300, n_envs=1,
                        progress_bar=False)
    assert set(res["summary"]["recipes"]) == {"tiny", "tiny_b"}
    for name in ("tiny", "tiny_b"):
        doc = json.loads((tmp_path / "out" / name / "seeds.json").read_text())
        assert doc["recipe"].endswith(f"{name}.json") and (tmp_path / "out" / name / "seed_0" / "model.zip").is_file()
    saved = json.loads((tmp_path / "out" / "recipes.json").read_text())
    assert saved["seeds"] == [0] and saved["recipes"]["tiny_b"]["recipe"] == str(b)


def test_several_recipes_need_seeds_and_distinct_names(tmp_path, capsys):
    from agents.train_cli import main
    a = _tiny_recipe_file(tmp_path)
    assert main(["--algo", "ppo", "--timesteps", "10", "--out", str(tmp_path / "o"), "--recipe", f"{a},{a}"]) == 2
    assert "several --recipe files need --seeds" in capsys.readouterr().err
    assert main(["--algo", "ppo", "--timesteps", "10", "--out", str(tmp_path / "o"), "--recipe", f"{a},{a}",
                 "--seeds", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "would share the directory 'tiny'" in err
    assert not (tmp_path / "o" / "tiny").exists()


@pytest.mark.slow
def test_eval_every_overrides_the_recipes_cadence_and_is_recorded(tmp_path):
    from agents.training import train
    recipe = _tiny_recipe_file(tmp_path)          # evaluates every 300 steps
    train("ppo", "surface", 600, 1, tmp_path / "dense", recipe=recipe, progress_bar=False, eval_every=150)
    train("ppo", "surface", 600, 1, tmp_path / "sparse", recipe=recipe, progress_bar=False)
    dense = json.loads((tmp_path / "dense" / "evaluations.json").read_text())
    sparse = json.loads((tmp_path / "sparse" / "evaluations.json").read_text())
    assert len(dense) > len(sparse) >= 2
    assert json.loads((tmp_path / "dense" / "recipe.json").read_text())["eval_every_env_steps"] == 150
    with pytest.raises(ValueError, match="eval_every"):
        train("ppo", "surface", 600, 1, tmp_path / "bad", recipe=recipe, progress_bar=False, eval_every=0)
    assert not (tmp_path / "bad").exists()        # refused before anything was written


def test_targets_that_share_a_threshold_share_one_labelled_line():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from agents.curves import draw_targets
    fig, axes = plt.subplots(1, 2)
    draw_targets(axes, {"recipe": {"coverage": 0.99, "safety_sm": 0.99},
                        "mission": {"coverage": 0.99, "safety_sm": 0.99, "centering_cm": 0.995}})
    assert [ln.get_label() for ln in axes[0].get_lines()] == ["recipe = mission target 0.99"]
    assert [ln.get_label() for ln in axes[1].get_lines()] == ["mission target 0.995"]
    draw_targets(axes, {"a": {"coverage": 0.9}, "b": {"coverage": 0.99}})
    assert len(axes[0].get_lines()) == 3
    plt.close(fig)


@pytest.mark.slow
def test_a_fine_tune_flies_its_own_learning_rate_and_its_model_loads_safely(tmp_path):
    """A fine-tune recipe's learning rate (a decaying schedule here) is the one the stage trains
    with, over the stage (SB3 counts the stage's decisions from 0), and the saved model agrees with
    its sidecar, so the safe loader (what ``evaluate`` uses) takes it."""
    import zipfile

    from agents.safe_load import check_safe
    from agents.training import algo_class, load_sidecar, train
    recipe = _tiny_recipe_file(tmp_path)
    base = train("ppo", "surface", 300, 1, tmp_path / "base", recipe=recipe, progress_bar=False)["final_model"]
    data = json.loads(Path(recipe).read_text())
    data["algo_kwargs"].update(learning_rate=1e-4, learning_rate_final=5e-5, clip_range=0.1)
    ft = tmp_path / "ft.json"
    ft.write_text(json.dumps(data))
    out = train("ppo", "surface", 300, 1, tmp_path / "ft", recipe=str(ft), resume=base, progress_bar=False)
    model = Path(out["final_model"])
    with zipfile.ZipFile(model) as z:
        stored = json.loads(z.read("data"))
    assert stored["learning_rate"]["start"] == 1e-4 and stored["learning_rate"]["end"] == 5e-5
    assert out["agent_decisions"] <= 300                   # the stage's own decisions
    check_safe(algo_class("ppo"), model, load_sidecar(model))  # no mismatch with the sidecar's recipe
