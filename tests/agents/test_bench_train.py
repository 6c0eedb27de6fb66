"""``wt-inspect bench train``: throughput numbers and where ``model.learn``'s time goes."""
from __future__ import annotations

import pytest

pytest.importorskip("stable_baselines3")

from agents.bench import run_bench  # noqa: E402


@pytest.mark.slow
def test_learn_time_splits_into_env_policy_and_update():
    """A tiny vector-env run: positive rates, and the split of the learning time into stepping the
    envs, the rest of the rollout and the update covers it exactly, each part taking a real share
    (every PPO iteration steps the envs, runs the network and updates it)."""
    r = run_bench("ppo", "surface", n_envs=2, steps=256, repeats=1, backend="vector")
    assert r["vecenv_steps_per_s"] > 0 and r["learn_steps_per_s"] > 0
    sp = r["learn_time_split"]
    assert sum(sp.values()) == pytest.approx(1.0, abs=1e-9)
    assert all(0.0 < v < 1.0 for v in sp.values()), sp
