"""DAgger: the expert flying in shadow (its observer told the applied command) and the DAgger loop."""
from __future__ import annotations

import json

import casadi as ca
import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401

pytest.importorskip("minari")
pytest.importorskip("stable_baselines3")

from agents.dagger import DAggerConfig, ShadowExpert, dagger, expert_factory, rollout  # noqa: E402
from agents.recipe import Recipe, load_recipe  # noqa: E402
from agents.train_cli import main as train_main  # noqa: E402
from controllers.vtnmpc import VTNMPC_PLUS, VTNMPCPolicy  # noqa: E402
from wt_inspect.demonstrations import DemoConfig, record_demonstrations  # noqa: E402
from wt_inspect_env.physics.dynamics import QuadrotorModel  # noqa: E402
from wt_inspect_env.physics.quadrotor import get_preset  # noqa: E402

RECIPE = "agents/recipes/dagger_full.json"


def _fly(expert, env, n, *, shadow, offset=None):
    """``n`` steps of the expert's plan; with ``offset`` the env gets the expert's action plus it
    (another policy flies) and, in shadow mode, the expert is told so."""
    obs, _ = env.reset(seed=3)
    expert.reset(3)
    actions, estimates = [], []
    for _ in range(n):
        a = expert.act(obs)
        applied = a if offset is None else np.clip(a + offset, -1.0, 1.0).astype(np.float32)
        if shadow:
            expert.note_applied_action(applied)
        obs, *_ = env.step(applied)
        actions.append(a.copy())
        estimates.append(expert.disturbance_estimate)
    return np.array(actions), np.array(estimates)


def test_shadow_with_its_own_command_is_bit_identical_to_normal_mode():
    env = gym.make("WindTurbineInspection-Surface-v0", wind={"type": "gust", "mean_speed": 4.0})
    make = expert_factory("vtnmpc-plus")
    a1, h1 = _fly(make(env.unwrapped), env, 60, shadow=False)
    a2, h2 = _fly(make(env.unwrapped), env, 60, shadow=True)
    assert np.array_equal(a1, a2) and np.array_equal(h1, h2)
    assert np.linalg.norm(h1[-1]) > 0.1          # the observer is active (4 m/s gust), not trivially zero
    env.close()


def _model_plant(params, a_true):
    """The controller's own RK4 model with a constant world-frame disturbance acceleration."""
    x, u = ca.SX.sym("x", 10), ca.SX.sym("u", 4)
    F = ca.Function("plant", [x, u], [QuadrotorModel(params).rk4_expr(x, u, 0.01, a_ext=ca.DM(a_true), steps=1)])
    return lambda xs, us: np.asarray(F(xs, us), dtype=float).ravel()


def test_shadow_observer_tracks_a_constant_disturbance_under_a_foreign_command():
    """First principles: on a plant that *is* the model plus a constant acceleration a, the
    observer of an MPC told the applied command converges to a whatever command flies (here the
    MPC's own plus a fixed roll-rate and thrust offset); untold, it absorbs the offset's effect."""
    params = get_preset("matrice100")
    a_true = np.array([0.6, -0.4, 0.3])
    plant = _model_plant(params, a_true)
    offset = np.array([0.02, 0.0, 0.0, 0.03], np.float32)

    def run(shadow: bool) -> np.ndarray:
        pol = VTNMPCPolicy(params=params, **VTNMPC_PLUS)
        point, normal = np.array([0.0, 0.0, 50.0]), np.array([0.0, -1.0, 0.0])
        x = np.concatenate([point + 7.0 * normal, np.zeros(3), [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]])
        for _ in range(300):
            obs = {"position": x[0:3], "velocity_body": x[3:6], "quaternion": x[6:10], "point": point,
                   "normal": normal, "point_velocity": np.zeros(3), "body_rates": np.zeros(3), "coverage": [0.0],
                   "progress": [0.0]}
            a = pol.act(obs)
            applied = np.clip(a + offset, -1.0, 1.0).astype(np.float32)
            if shadow:
                pol.note_applied_action(applied)
            x = plant(x, pol.scaling.to_command(applied))
            x[6:10] /= np.linalg.norm(x[6:10])
        return pol.disturbance_estimate

    told, untold = run(True), run(False)
    assert np.linalg.norm(told - a_true) < 0.02
    assert np.linalg.norm(untold - a_true) > 0.1       # the check can fail: without the correction it is off


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("demos")
    cfg = DemoConfig(winds=[{"type": "gust", "mean_speed": 4.0}], episodes=2, time_limit_s=0.4, full_missions=0)
    record_demonstrations(cfg, root, "tiny-v0", progress=False)
    return root / "wt-inspect" / "tiny-v0"


def _tiny_recipe() -> Recipe:
    d = load_recipe(RECIPE).to_dict()
    d["env"]["time_limit_s"] = 0.4
    d["eval_env"]["time_limit_s"] = 0.3
    d["policy_kwargs"]["net_arch"] = {"pi": [8], "vf": [8]}
    return Recipe.from_dict(d)


@pytest.mark.slow
def test_rollout_labels_every_decision_with_the_expert():
    from agents.imitation import new_clone_model
    from agents.training import _policy_from_model
    rec = _tiny_recipe()
    env = gym.make("WindTurbineInspection-v0", **rec.env)
    model, vecnorm, venv = new_clone_model(rec, "full", np.random.default_rng(0).normal(size=(64, 27)), 0)
    student = _policy_from_model(model, rec.spec, vecnorm, env)
    expert = ShadowExpert(expert_factory("vtnmpc-plus")(env.unwrapped))
    ro = rollout(student, expert, env, seed=1, beta=0.0, rng=np.random.default_rng(0), spec=rec.spec)
    k = rec.spec.action_repeat
    assert ro["steps"] == 40 and len(ro["labels"]) == len(ro["features"]) == 40 // k and ro["expert_share"] == 0.0
    # the labels are the expert's actions at the decision steps, inverted to agent actions: fly the
    # student's recorded decisions open loop with the expert in normal mode beside them
    obs, _ = env.reset(seed=1)
    expert.reset(1)
    student.reset(1)
    for t in range(40):
        a = expert.label(obs)
        if t % k == 0:
            from agents.imitation import invert_action
            q = np.asarray(obs["quaternion"], float)[None]
            np.testing.assert_allclose(invert_action(rec.spec, env.unwrapped.scaling, a[None], q)[0],
                                       ro["labels"][t // k], atol=1e-6)
        action = student.act(obs)
        expert.applied(action)
        obs, *_ = env.step(action)
    assert np.abs(ro["labels"]).max() <= 1.0 and np.std(ro["labels"]) > 0
    full = rollout(student, expert, env, seed=1, beta=1.0, rng=np.random.default_rng(0), spec=rec.spec)
    from agents.training import run_episode
    alone = run_episode(expert.policy, env, 1)          # beta = 1 is the expert flying on its own
    assert full["expert_share"] == 1.0 and full["steps"] == alone["steps"]
    assert full["metrics"]["rms_distance_error_m"] == alone["rms_distance_error_m"]
    venv.close()
    env.close()


@pytest.mark.slow
def test_dagger_runs_rounds_resumes_and_saves_a_resumable_model(tiny_dataset, tmp_path):
    rec = _tiny_recipe()
    out = tmp_path / "d"
    cfg = DAggerConfig(rounds=2, episodes_per_round=1, bc_epochs=1, refit_steps=3, batch_size=64)
    s = dagger(tiny_dataset, out, recipe=rec, config=cfg, progress=False)
    ev = json.loads((out / "evaluations.json").read_text())
    assert [e["round"] for e in ev] == [0, 1, 2] and ev[0]["beta"] == 1.0 and ev[2]["beta"] == 0.25
    assert ev[0]["env_steps"] == 0 < ev[1]["env_steps"] < ev[2]["env_steps"] == s["env_steps"]
    assert 0 < ev[1]["samples_dagger"] < ev[2]["samples_dagger"] == s["samples_dagger"]
    assert (out / "learning_curve.png").is_file() and (out / "rounds" / "round_2" / "model.zip").is_file()
    # resume: one more round, the earlier ones are not redone
    s3 = dagger(tiny_dataset, out, recipe=rec, config=DAggerConfig(**{**cfg.to_dict(), "rounds": 3}), progress=False)
    ev = json.loads((out / "evaluations.json").read_text())
    assert [e["round"] for e in ev] == [0, 1, 2, 3] and s3["env_steps"] > s["env_steps"]
    with pytest.raises(ValueError, match="other settings"):
        dagger(tiny_dataset, out, recipe=rec, config=DAggerConfig(**{**cfg.to_dict(), "beta0": 0.9}), progress=False)
    # a wall budget already spent: behaviour cloning and its evaluation, then no round starts
    sb = dagger(tiny_dataset, tmp_path / "b", recipe=rec, config=cfg, progress=False, max_minutes=1e-6)
    assert sb["stopped_by_wall_clock"] and sb["rounds_done"] == 0 and len(sb["per_round"]) == 1
    # saved like a trained model: PPO fine-tunes it
    from agents.training import train
    t = train("ppo", "full", 64, 1, tmp_path / "ft", resume=str(out / "model.zip"), progress_bar=False)
    assert t["env_steps"] > s3["env_steps"]


def test_bad_dagger_input_is_one_line_exit_2(tiny_dataset, tmp_path, capsys):
    base = ["--algo", "dagger", "--dataset", str(tiny_dataset), "--no-progress"]
    cases = [(['{"rounds": 0}'], "dagger rounds must be a positive integer, got 0"),
             (['{"rounds": 2.5}'], "dagger rounds must be a positive integer"),
             (['{"roundz": 2}'], "unknown dagger option(s) ['roundz']"),
             (['{"expert": "nope"}'], "dagger expert 'nope' is not a registered controller"),
             (['[1]'], "--dagger-options must be a JSON object")]
    for opts, msg in cases:
        out = tmp_path / "x"
        assert train_main([*base, "--out", str(out), "--dagger-options", *opts]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1 and not out.exists()
    # a dataset recorded for another stand-off
    d = load_recipe(RECIPE).to_dict()
    d["env"]["standoff"] = 5.0
    (tmp_path / "r.json").write_text(json.dumps(d))
    assert train_main([*base, "--out", str(tmp_path / "y"), "--recipe", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "dataset was recorded with standoff 7.0" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "y").exists()
    assert train_main(["--algo", "dagger", "--out", str(tmp_path / "z")]) == 2
    assert "needs --dataset" in capsys.readouterr().err


def test_the_expert_may_carry_its_argument_checked_before_anything_flies():
    """``vtnmpc-plus:backoff=0.5``: a tightened expert (the OCP keeps d_min + 0.5 m) to imitate;
    a bad argument or an argument to an entry that takes none is a one-line error."""
    import gymnasium as gym

    from agents.dagger import DAggerConfig, expert_factory
    assert DAggerConfig(expert="vtnmpc-plus:backoff=0.5").expert == "vtnmpc-plus:backoff=0.5"
    for name, match in [("vtnmpc-plus:backoff=-1", "backoff must be a finite number >= 0"),
                        ("nmpc-authors:backoff=0.5", "needs the clearance constraint"),
                        ("nope:backoff=1", "is not a registered controller"),
                        ("ppo", "needs no argument")]:
        with pytest.raises(ValueError, match=match):
            expert_factory(name)
    with pytest.raises(ValueError, match="NAME or NAME:ARGUMENT"):
        DAggerConfig(expert=":backoff=1")
    env = gym.make("WindTurbineInspection-v0", task="full")
    try:
        policy = expert_factory("vtnmpc-plus:backoff=0.5")(env.unwrapped)
        assert policy.config.clearance_backoff == 0.5 and policy.clearance_active
    finally:
        env.close()
