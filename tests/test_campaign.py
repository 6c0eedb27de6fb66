"""``wt-inspect campaign``: randomised episodes from one master seed, each recorded, with
crashes, exceptions, non-finite states, fallbacks and memory reported."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from wt_inspect.commands import campaign as cp
from wt_inspect.evaluation.runner import load_run, make_spec


def test_draws_are_seeded_in_range_and_prefix_stable() -> None:
    cfg = cp.CampaignConfig(episodes=20, seed=3)
    a, b = cp.draw_episodes(cfg), cp.draw_episodes(cfg)
    assert a == b
    assert cp.draw_episodes(cp.CampaignConfig(episodes=5, seed=3)) == a[:5]
    assert a != cp.draw_episodes(cp.CampaignConfig(episodes=20, seed=4))
    for d in a:
        for name, (lo, hi) in cp.SIZE_RANGES.items():
            assert lo <= d[name] <= hi
        assert 0 <= d["wind"] <= 10 and 0 <= d["rotor_azimuth_deg"] < 120
        assert abs(d["wind_direction_deg"]) <= cp.MAX_DIRECTION_DEG
        off = np.asarray(d["start_offset"])
        assert off[2] >= 0 and np.isclose(np.linalg.norm(off), d["start_offset_m"]) and d["start_offset_m"] <= 30
    assert len({d["seed"] for d in a}) == 20


@pytest.mark.parametrize("bad", [{"episodes": 0}, {"episodes": "5"}, {"max_wind": 60.0}, {"max_wind": "5"},
                                 {"max_time": -1.0}, {"task": "rotor"}, {"seed": True}])
def test_bad_config_one_line(bad) -> None:
    key = next(iter(bad))
    with pytest.raises(ValueError, match=key if key != "task" else "unknown task"):
        cp.CampaignConfig(**bad)


@pytest.mark.slow
def test_an_exception_is_caught_and_recorded(monkeypatch) -> None:
    d = cp.draw_episodes(cp.CampaignConfig(episodes=1))[0]
    spec = make_spec("campaign", "vtnmpc-plus", d["wind"], d["seed"], cp.episode_options(d, "surface"), 0.05)

    def broken(name):
        def factory(env):
            raise RuntimeError("solver exploded\nsecond line")
        return factory
    monkeypatch.setattr(cp.registry, "resolve", broken)
    res = cp.run_episode(spec)
    assert res.termination == "exception" and res.metrics["error"].startswith("RuntimeError: solver exploded (")
    assert res.solve["rss_mb"] > 0
    row = cp._row(d, res)
    assert row["exception"] and not row["crashed"] and row["error"]


@pytest.mark.slow
def test_two_episode_campaign_writes_everything(tmp_path) -> None:
    out = tmp_path / "camp"
    cfg = cp.CampaignConfig(episodes=2, task="surface", max_time=0.3, record_every=1, seed=1)
    doc = cp.run_campaign(cfg, out, jobs=1, progress=False)
    s = doc["summary"]
    assert s["episodes"] == 2 and s["exceptions"] == 0 and s["non_finite_states"] == 0
    assert s["steps"] == 60 and 0 <= s["fallback_fraction"] <= 1 and s["rss_first_mb"] > 0
    rows = list(csv.DictReader((out / "episodes.csv").open()))
    assert [int(r["episode"]) for r in rows] == [0, 1] and all(r["termination"] == "max_time" for r in rows)
    for r in rows:
        run = load_run(out / "runs" / r["run_file"])
        assert run.arrays["position"].shape == (31, 3) and np.all(np.isfinite(run.arrays["position"]))
        assert run.spec.env_options["rotor_turn_deg"] is None
    js = json.loads((out / "campaign.json").read_text())
    assert js["complete"] and js["draws"] == cp.draw_episodes(cfg)
    assert "QP fallbacks" in (out / "results.md").read_text() and (out / "campaign.png").is_file()
    again = cp.run_campaign(cfg, out, jobs=1, progress=False)   # resumed from the run files
    assert again["summary"]["steps"] == 60 and again["wall_time_s"] < doc["wall_time_s"]
    # the resumed campaign reports the cost of both invocations
    assert again["wall_time_total_s"] == pytest.approx(doc["wall_time_s"] + again["wall_time_s"])
    assert f"{again['wall_time_total_s']:.1f} s over every invocation" in (out / "results.md").read_text()


def test_a_start_drawn_inside_the_turbine_gets_a_new_direction_deterministically() -> None:
    # campaign episodes 94 and 166 of seed 0 drew starts inside a blade and the tower (collision
    # at the first step); the campaign now redraws such a direction from the episode's seed
    from wt_inspect.evaluation.runner import make_env
    from wt_inspect_env.proximity import TurbineProximity
    d = cp.draw_episodes(cp.CampaignConfig(episodes=167))[166]
    spec = make_spec(cp.SCENARIO, "vtnmpc-plus", d["wind"], d["seed"], cp.episode_options(d, "full"), 1.0, 10)
    env = make_env(spec.env_options)
    try:
        u = env.unwrapped
        near = TurbineProximity.from_mission(u.mission).phases[0]
        u.reset(seed=spec.seed)
        assert near.distance(u.sim.state[0:1, 0:3])[0] < 1.0          # the drawn start is in the tower
        offset, redraws = cp.clear_start(env, spec)
        assert redraws >= 1 and np.isclose(np.linalg.norm(offset), d["start_offset_m"])
        assert near.distance(u.sim.state[0:1, 0:3])[0] >= cp.START_CLEARANCE_RATIO * 7.0
        assert cp.clear_start(env, spec) == (offset, redraws)            # seeded by the episode
        clear = cp.draw_episodes(cp.CampaignConfig(episodes=1))[0]
        spec0 = make_spec(cp.SCENARIO, "vtnmpc-plus", clear["wind"], clear["seed"], cp.episode_options(clear, "full"),
                          1.0, 10)
        env0 = make_env(spec0.env_options)
        try:
            assert cp.clear_start(env0, spec0) == (list(clear["start_offset"]), 0)   # a clear start is kept
        finally:
            env0.close()
    finally:
        env.close()
