"""A training study's behaviour digest (``agents.digest``): its first PPO update, planned from the
study's ``wt-inspect train`` command. It is the same when only the arithmetic's grouping could differ
(the learner's thread count) and differs when the task or the learner does."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from agents.digest import first_update_digest  # noqa: E402
from agents.recipe import load_recipe  # noqa: E402
from wt_inspect import behaviour  # noqa: E402

RECIPE = "agents/recipes/ppo_surface.json"


@pytest.fixture(scope="module")
def small():
    """The surface recipe with short rollouts (8 decisions of 8 drones), so that a digest takes seconds."""
    rec = load_recipe(RECIPE)
    return dataclasses.replace(rec, algo_kwargs={**rec.algo_kwargs, "n_steps": 8, "batch_size": 16})


def _digest(rec, seed: int = 0) -> dict:
    return first_update_digest("ppo", "surface", 8, 100_000, recipe=rec, seed=seed)


@pytest.fixture(scope="module")
def reference(small):
    return _digest(small)


def test_a_training_command_plans_one_digested_run_per_recipe_and_seed():
    runs = behaviour.study_runs(["wt-inspect train --algo ppo --task full --n-envs 128 --timesteps 5000000 "
                                 "--seeds 0,1,4 --resume OUT/seed_{seed}/model.zip --recipe a.json,b.json --out x"])
    assert [(r.runner, r.spec["recipe"], r.spec["seed"]) for r in runs] == [
        ("train", rec, s) for rec in ("a.json", "b.json") for s in (0, 1, 4)]
    assert runs[2].spec["resume"] == "OUT/seed_4/model.zip"
    assert {(r.spec["task"], r.spec["n_envs"], r.spec["timesteps"]) for r in runs} == {("full", 128, 5_000_000)}
    assert [r.spec["seed"] for r in behaviour.digested_runs([f"wt-inspect train --algo ppo --timesteps 9 --seeds "
                                                             f"0,1,2 --recipe {RECIPE} --out x"])] == [0, 2]
    # cloning and DAgger have no first PPO update to digest
    assert behaviour.study_runs(["wt-inspect train --algo bc --dataset d --out x"]) == []


def test_the_digest_records_the_first_rollout_and_update(reference, small):
    d = reference
    n = small.algo_kwargs["n_steps"]
    assert len(d["t"]) == n and np.shape(d["position"]) == (n, 6) and np.shape(d["reward"]) == (n, 3)
    assert np.shape(d["action"]) == (1, 12) and np.shape(d["update"]) == (1, 5)
    assert np.all(np.isfinite(d["update"]))
    assert d["update"][0][0] > 0.0            # the update moved the policy (approximate KL > 0)
    json.dumps(d)                              # plain data for provenance.json


@pytest.mark.slow
def test_the_digest_ignores_the_learners_thread_count_and_sees_a_changed_task_or_learner(reference, small):
    assert behaviour.compare(reference, _digest(dataclasses.replace(small, torch_threads=2))) == ""
    env = json.loads(json.dumps(small.env))
    env.setdefault("reward", {})["centering"] = 2.0 * env.get("reward", {}).get("centering", 0.5)
    why = behaviour.compare(reference, _digest(dataclasses.replace(small, env=env)))
    assert why.startswith("reward"), why
    clip = dataclasses.replace(small, algo_kwargs={**small.algo_kwargs, "clip_range": 0.05})
    why = behaviour.compare(reference, _digest(clip))
    assert why and not why.startswith(("position", "velocity", "reward")), why   # the same rollout, another update


@pytest.mark.slow
def test_a_many_turbine_recipe_is_digested_over_its_worlds():
    """With many turbines there is no single world: the digest reads every drone's state through
    the vector env (the first and the last drone fly different worlds' turbines)."""
    rec = load_recipe("agents/recipes/ppo_full_many.json")
    rec = dataclasses.replace(rec, algo_kwargs={**rec.algo_kwargs, "n_steps": 4, "batch_size": 16},
                              turbines={**rec.turbines, "n_turbines": 2})
    d = first_update_digest("ppo", "full", 8, 100_000, recipe=rec, seed=0)
    assert np.shape(d["position"]) == (4, 6) and np.all(np.isfinite(d["position"]))
    first, last = np.asarray(d["position"])[0].reshape(2, 3)
    assert np.linalg.norm(first - last) > 1.0      # two drones on two turbines' paths, not one spot
