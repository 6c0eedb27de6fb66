"""Demonstrations as a Minari dataset, and behaviour cloning from it."""
from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401

pytest.importorskip("minari")
pytest.importorskip("stable_baselines3")

from agents.imitation import (  # noqa: E402
    BCConfig,
    behaviour_clone,
    check_dataset_matches,
    dataset_arrays,
    invert_action,
    load_demonstrations,
)
from agents.recipe import Recipe, load_recipe  # noqa: E402
from agents.wrappers import AgentSpec, FeatureEncoder, ResidualHoverAction  # noqa: E402
from wt_inspect.demonstrations import DemoConfig, record_demonstrations  # noqa: E402
from wt_inspect.demonstrations import main as demos_main

RECIPE = "agents/recipes/bc_full.json"


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("demos")
    cfg = DemoConfig(winds=["none", {"type": "gust", "mean_speed": 4.0}], episodes=1, time_limit_s=0.4,
                     full_missions=0, action_noise=0.05)
    summary = record_demonstrations(cfg, root, "tiny-v0", progress=False)
    return root / "wt-inspect" / "tiny-v0", summary


def test_invert_action_undoes_the_residual_hover_decoder():
    env = gym.make("WindTurbineInspection-v0").unwrapped
    spec = AgentSpec()
    dec = ResidualHoverAction(spec.action, env.scaling)
    rng = np.random.default_rng(0)
    u = rng.uniform(-0.6, 0.6, (50, 4))
    q = rng.normal(size=(50, 4)) * [0.1, 0.1, 1.0, 1.0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    a = np.stack([dec(u[i], q[i]) for i in range(50)])
    np.testing.assert_allclose(invert_action(spec, env.scaling, a, q), u, atol=2e-6)
    with pytest.raises(ValueError, match="action mode 'rates'"):
        invert_action(AgentSpec(action={"mode": "attitude"}), env.scaling, a, q)
    env.close()


def test_dataset_is_minari_with_clean_expert_labels_and_metadata(tiny_dataset):
    path, summary = tiny_dataset
    ds, meta = load_demonstrations(path)
    assert ds.total_episodes == 2 == meta["total_episodes"]
    ep = next(ds.iterate_episodes())
    T = len(ep.actions)
    assert T == 40 and ep.observations["position"].shape == (T + 1, 3)
    labels = np.asarray(ep.infos["expert_action"])[1:]
    # executed = label + noise: close to but not the expert's action
    diff = np.asarray(ep.actions) - labels
    assert 0.01 < np.std(diff) < 0.1
    assert meta["drone"]["standoff"] == 7.0 and meta["episodes"][0]["metrics"]["safety_sm"] == 1.0
    # the features are the deployed encoder's, replayed with the executed actions
    env = gym.make("WindTurbineInspection-v0").unwrapped
    rec = load_recipe(RECIPE)
    X, Y = dataset_arrays(ds, rec.spec, env.scaling, standoff=7.0, dt=env.dt)
    assert X.shape == (2 * T, rec.spec.features.size) and Y.shape == (2 * T, 4)
    enc = FeatureEncoder(rec.spec.features, standoff=7.0, dt=env.dt, max_rate=env.scaling.max_rate)
    obs = {k: np.asarray(v) for k, v in ep.observations.items()}
    enc.update({k: v[0] for k, v in obs.items()})
    executed = invert_action(rec.spec, env.scaling, np.asarray(ep.actions), obs["quaternion"][:T])
    for t in range(5):
        np.testing.assert_array_equal(X[t], enc.features())
        enc.note_action(executed[t])
        enc.update({k: v[t + 1] for k, v in obs.items()})
    env.close()


def test_behaviour_cloning_fits_and_saves_a_loadable_agent(tiny_dataset, tmp_path):
    path, _ = tiny_dataset
    rec = load_recipe(RECIPE)
    summary = behaviour_clone(path, tmp_path / "bc", recipe=rec, config=BCConfig(epochs=40, batch_size=32),
                              progress=False, evaluate=False)
    h = summary["history"]
    assert h[-1]["train_mse"] < 0.5 * h[0]["train_mse"]
    from agents.policy import load_sb3_policy
    env = gym.make("WindTurbineInspection-v0").unwrapped
    policy = load_sb3_policy("ppo", summary["model"], env)
    obs, _ = env.reset(seed=0)
    policy.reset(0)
    for _ in range(5):
        obs, *_ = env.step(policy.act(obs))
    assert json.loads((tmp_path / "bc" / "bc_summary.json").read_text())["samples"] == summary["samples"]
    env.close()


def test_evaluation_variants_fly_each_condition_and_keep_the_worst_score(tiny_dataset, tmp_path):
    """A recipe's eval_variants: every evaluation flies each variant, and its score is the worst
    variant's (a model is kept for doing the task in every condition, not on average)."""
    path, _ = tiny_dataset
    d = load_recipe(RECIPE).to_dict()
    d["eval_env"] = {"start_noise": 0.0, "time_limit_s": 0.3}
    d["eval_variants"] = [{"time_limit_s": 0.3}, {"time_limit_s": 1.5, "wind": "none"}]
    rec = Recipe.from_dict(d)
    behaviour_clone(path, tmp_path / "bc", recipe=rec, config=BCConfig(epochs=2, batch_size=32), progress=False)
    (entry,) = json.loads((tmp_path / "bc" / "evaluations.json").read_text())
    short, long_ = entry["variants"]
    assert [e["eval_variant"] for e in entry["episodes"]] == [0] * rec.eval_episodes + [1] * rec.eval_episodes
    assert short["mean"]["flight_time_s"] < 0.5 < long_["mean"]["flight_time_s"]
    assert short["score"] != long_["score"] and entry["score"] == min(short["score"], long_["score"])
    assert entry["mean"]["flight_time_s"] == pytest.approx((short["mean"]["flight_time_s"]
                                                            + long_["mean"]["flight_time_s"]) / 2)


def test_dataset_for_another_standoff_is_refused(tiny_dataset):
    _, meta = load_demonstrations(tiny_dataset[0])
    env = gym.make("WindTurbineInspection-v0", standoff=5.0)
    with pytest.raises(ValueError, match="standoff 7.0"):
        check_dataset_matches(meta, env)
    env.close()


def test_bad_demo_input(tmp_path, tiny_dataset, capsys):
    with pytest.raises(ValueError, match="demo episodes"):
        DemoConfig(episodes=-1)
    with pytest.raises(ValueError, match="exists already"):
        record_demonstrations(DemoConfig(episodes=1, full_missions=0), tiny_dataset[0].parent.parent, "tiny-v0")
    assert demos_main(["--out", str(tmp_path), "--config", '{"epsiodes": 1}']) == 2
    err = capsys.readouterr().err
    assert "unknown --config demo config option(s) ['epsiodes']" in err and "'episodes'" in err
    assert demos_main(["--out", str(tmp_path), "--config", '{"expert": "nope"}']) == 2
    with pytest.raises(ValueError, match="not a wt-inspect Minari dataset"):
        load_demonstrations(tmp_path)
