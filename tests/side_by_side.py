"""The side-by-side check of the native vector env: drone i of the vector env against the single
env seeded s + i, stepped with the same random actions and compared bit for bit at every step
(observations, rewards, ends, reward terms, metrics, final observations across autoresets).
A plain module imported by name (``tests`` is on pytest's path), shared by the vector env's tests
and those of options the vector env must reproduce (randomisation, far starts)."""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

import wt_inspect_env  # noqa: F401 - registers the ids

ENV = "WindTurbineInspection-v0"


def _make_vec(n: int, env_id: str = ENV, **options):
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **options)


def _same(a, b) -> bool:
    return a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b))


def _run_side_by_side(n: int, steps: int, seed: int = 3, env_id: str = ENV, winds=None, action_sd: float = 0.05,
                      **options) -> dict:
    """Step the vector env and n single envs with the same random actions; assert equality at
    every step. Returns counters of what was exercised (resets, max phase)."""
    venv = _make_vec(n, env_id, winds=winds, **options) if winds else _make_vec(n, env_id, **options)
    singles = [gym.make(env_id, **options, **({"wind": winds[i]} if winds else {})).unwrapped for i in range(n)]
    rng = np.random.default_rng(1)
    seen = {"resets": 0, "max_phase": 1, "frames_with_new": 0}
    try:
        vobs, _ = venv.reset(seed=seed)
        for i, env in enumerate(singles):
            obs, _ = env.reset(seed=seed + i)
            for k in obs:
                assert np.array_equal(vobs[k][i], obs[k]), (k, i)
        hover = singles[0].scaling.hover_action()
        for t in range(steps):
            act = np.clip(hover + rng.normal(0.0, action_sd, (n, 4)), -1, 1).astype(np.float32)
            vobs, vrew, vterm, vtrunc, vinfo = venv.step(act)
            seen["max_phase"] = max(seen["max_phase"], int(vinfo["phase"].max()))
            for i, env in enumerate(singles):
                obs, rew, term, trunc, info = env.step(act[i])
                assert vrew[i] == rew, (t, i, vrew[i], rew)
                assert (vterm[i], vtrunc[i]) == (term, trunc), (t, i)
                for k, v in info["reward_terms"].items():
                    assert vinfo["reward_terms"][k][i] == v, (t, i, k)
                if info["reward_terms"]["coverage"] > 0:
                    seen["frames_with_new"] += 1
                if term or trunc:
                    seen["resets"] += 1
                    seen[info["termination"]] = seen.get(info["termination"], 0) + 1
                    assert vinfo["_final_obs"][i] and vinfo["_final_info"][i]
                    for k in obs:
                        assert np.array_equal(vinfo["final_obs"][i][k], obs[k]), (t, i, k)
                    for k, v in info["metrics"].items():
                        assert _same(float(vinfo["final_info"]["metrics"][k][i]), v), (t, i, k)
                    assert vinfo["final_info"]["termination"][i] == (info["termination"] or None)
                    obs, _ = env.reset()
                else:
                    vm = venv.unwrapped.metrics(i)
                    if t % 50 == 0:
                        for k, v in info["metrics"].items():
                            assert _same(vm[k], v), (t, i, k)
                    assert vinfo["coverage"][i] == info["coverage"]
                for k in obs:
                    assert np.array_equal(vobs[k][i], obs[k]), (t, i, k)
    finally:
        venv.close()
        for env in singles:
            env.close()
    return seen
