"""``wt-inspect campaign``: randomised episodes from one master seed, each recorded, with
crashes, exceptions, non-finite states, fallbacks and memory reported."""
from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest

from wt_inspect.commands import campaign as cp
from wt_inspect.evaluation import registry
from wt_inspect.evaluation.runner import load_run, make_spec


def test_draws_are_seeded_in_range_and_prefix_stable() -> None:
    cfg = cp.CampaignConfig(episodes=60, seed=3)
    a, b = cp.draw_episodes(cfg), cp.draw_episodes(cfg)
    assert a == b
    assert cp.draw_episodes(cp.CampaignConfig(episodes=5, seed=3)) == a[:5]
    assert a != cp.draw_episodes(cp.CampaignConfig(episodes=60, seed=4))
    assert {d["turbine"] for d in a} == set(cp.TURBINE_KINDS)   # generated, the preset and scaled presets
    for d in a:
        if d["turbine"] == "generated":
            for name, (lo, hi) in cp.SIZE_RANGES.items():
                assert lo <= d[name] <= hi and d["turbine_spec"][name] == d[name]
            assert d["turbine_scale"] is None
        elif d["turbine"] == "nrel-5mw":
            assert d["turbine_spec"] == {"preset": "nrel-5mw"} and d["turbine_scale"] == 1.0
        else:
            s = d["turbine_scale"]
            assert cp.NREL_SCALE_RANGE[0] <= s <= cp.NREL_SCALE_RANGE[1]
            assert d["turbine_spec"]["preset"] == "nrel-5mw"
            assert np.isclose(d["turbine_spec"]["tower_height"], 90.0 * s)
            assert np.isclose(d["turbine_spec"]["blade_length"], 61.5 * s)
        assert 0 <= d["wind"] <= 10 and 0 <= d["rotor_azimuth_deg"] < 120
        assert -180 <= d["wind_direction_deg"] < 180
        off = np.asarray(d["start_offset"])
        assert off[2] >= 0 and np.isclose(np.linalg.norm(off), d["start_offset_m"]) and d["start_offset_m"] <= 30
    # the wind comes from every side, not only within 45 deg of the rotor axis
    assert max(abs(d["wind_direction_deg"]) for d in a) > 150
    assert len({d["seed"] for d in a}) == 60
    opts = cp.episode_options(a[0], "full")
    assert opts["randomization"] == cp.AIRFRAME_RANDOMIZATION and opts["rotor_turn_deg"] is None
    assert "randomization" not in cp.episode_options(a[0], "full", airframe_randomization=False)


def test_every_controller_gets_the_same_episodes() -> None:
    cfg = cp.CampaignConfig(episodes=8, seed=5)
    d1, s1 = cp.campaign_specs(cfg)
    d2, s2 = cp.campaign_specs(dataclasses.replace(cfg, controller="ppo:ppo_full_vec128"))
    assert d1 == d2
    assert [(s.seed, s.wind, s.env_options, s.max_time) for s in s1] == \
           [(s.seed, s.wind, s.env_options, s.max_time) for s in s2]
    assert {s.controller for s in s2} == {"ppo:ppo_full_vec128"}


def test_an_agent_that_observes_the_structure_gets_it_in_every_episode() -> None:
    cfg = cp.CampaignConfig(episodes=4, seed=5)
    d1, s1 = cp.campaign_specs(cfg)
    d2, s2 = cp.campaign_specs(dataclasses.replace(cfg, controller="ppo:ppo_full_scratch_ff"))
    assert d1 == d2
    assert all(s.env_options.get("structure_observation") is True for s in s2)
    assert not any("structure_observation" in s.env_options for s in s1)
    # otherwise the same episodes
    assert [{k: v for k, v in s.env_options.items() if k != "structure_observation"} for s in s2] == \
           [s.env_options for s in s1]


def test_the_default_is_no_time_cap(tmp_path) -> None:
    args = cp.build_parser("x").parse_args(["--out", str(tmp_path)])
    assert args.max_time is None and cp.CampaignConfig().max_time is None
    _, specs = cp.campaign_specs(cp.CampaignConfig(episodes=3))
    assert all(s.max_time is None for s in specs)   # fly() then runs to the env's time limit or the mission's end
    _, capped = cp.campaign_specs(cp.CampaignConfig(episodes=3, max_time=5.0))
    assert all(s.max_time == 5.0 for s in capped)


def test_only_flies_the_same_spec_as_the_campaign() -> None:
    cfg = cp.CampaignConfig(episodes=10, seed=2, max_time=2.5)
    _, every = cp.campaign_specs(cfg)
    _, one = cp.campaign_specs(dataclasses.replace(cfg, only=(7,)))
    assert [s.filename for s in one] == [every[7].filename]
    with pytest.raises(ValueError, match="only"):
        cp.CampaignConfig(episodes=10, only=(10,))


def test_wall_time_sums_the_invocations(tmp_path) -> None:
    cfg = cp.CampaignConfig(episodes=2)
    path = tmp_path / "campaign.json"
    assert cp.earlier_invocations(path, cfg) == []
    path.write_text(json.dumps({"config": cp.config_json(cfg), "wall_time_invocations_s": [10.0, 5.5]}))
    assert cp.earlier_invocations(path, cfg) == [10.0, 5.5]
    assert cp.earlier_invocations(path, cp.CampaignConfig(episodes=2, seed=1)) == []   # another campaign
    # the same campaign given more episodes reuses the finished ones, so their cost counts
    assert cp.earlier_invocations(path, cp.CampaignConfig(episodes=3)) == [10.0, 5.5]
    path.write_text(json.dumps({"config": cp.config_json(cfg), "wall_time_s": 3.0, "wall_time_total_s": 12.0}))
    assert cp.earlier_invocations(path, cfg) == [12.0]                         # a format-/1 file's total


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
    monkeypatch.setattr(registry, "resolve", broken)
    res = cp.run_episode(spec)
    assert res.termination == "exception" and res.metrics["error"].startswith("RuntimeError: solver exploded (")
    assert res.solve["rss_mb"] > 0
    row = cp.episode_row(d, res)
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
    assert len(doc["wall_time_invocations_s"]) == 1 and doc["wall_time_s"] == doc["wall_time_this_invocation_s"]
    again = cp.run_campaign(cfg, out, jobs=1, progress=False)   # resumed from the run files
    assert again["summary"]["steps"] == 60 and again["wall_time_this_invocation_s"] < doc["wall_time_s"]
    # the resumed campaign's wall time is the cost of both invocations, each also listed
    assert again["wall_time_invocations_s"] == [doc["wall_time_s"], again["wall_time_this_invocation_s"]]
    assert again["wall_time_s"] == pytest.approx(doc["wall_time_s"] + again["wall_time_this_invocation_s"])
    assert f"{again['wall_time_s']:.1f} s over 2 invocation(s)" in (out / "results.md").read_text()
    # run files discarded (as wt-inspect reproduce does for other code): flown afresh, only this cost
    for f in (out / "runs").glob("*.npz"):
        f.unlink()
    fresh = cp.run_campaign(cfg, out, jobs=1, progress=False)
    assert fresh["wall_time_invocations_s"] == [fresh["wall_time_this_invocation_s"]]


@pytest.mark.slow
def test_a_start_drawn_inside_the_turbine_gets_a_new_direction_deterministically() -> None:
    # campaign episodes 94 and 166 of seed 0 (format /1 draws) drew starts inside a blade and the
    # tower (collision at the first step); the campaign redraws such a direction from the episode's
    # seed. A draw whose start is crafted to lie on the tower's axis:
    from wt_inspect.evaluation.runner import make_env
    from wt_inspect_env.planner.proximity import TurbineProximity
    clear = next(d for d in cp.draw_episodes(cp.CampaignConfig(episodes=10)) if d["turbine"] == "generated")
    spec0 = make_spec(cp.SCENARIO, "vtnmpc-plus", clear["wind"], clear["seed"], cp.episode_options(clear, "full"),
                      1.0, 10)
    env0 = make_env({**spec0.env_options, "start_offset": [0.0, 0.0, 0.0]})
    try:
        env0.unwrapped.reset(seed=spec0.seed)
        pose = np.array(env0.unwrapped.sim.state[0, 0:3])
    finally:
        env0.close()
    offset = np.array([0.0, 0.0, 0.5 * clear["tower_height"]]) - pose          # tower axis at (0, 0)
    d = {**clear, "start_offset": offset.tolist(), "start_offset_m": float(np.linalg.norm(offset))}
    spec = make_spec(cp.SCENARIO, "vtnmpc-plus", d["wind"], d["seed"], cp.episode_options(d, "full"), 1.0, 10)
    env = make_env(spec.env_options)
    try:
        u = env.unwrapped
        near = TurbineProximity.from_mission(u.mission).phases[0]
        u.reset(seed=spec.seed)
        # the drawn start is on the tower's axis: its radius (1.5 m) from the surface, inside it
        assert near.distance(u.sim.state[0:1, 0:3])[0] < 1.6
        offset, redraws = cp.clear_start(env, spec)
        assert redraws >= 1 and np.isclose(np.linalg.norm(offset), d["start_offset_m"])
        assert near.distance(u.sim.state[0:1, 0:3])[0] >= cp.START_CLEARANCE_RATIO * 7.0
        assert cp.clear_start(env, spec) == (offset, redraws)            # seeded by the episode
        env1 = make_env(spec0.env_options)
        try:
            assert cp.clear_start(env1, spec0) == (list(clear["start_offset"]), 0)   # a clear start is kept
        finally:
            env1.close()
    finally:
        env.close()


def _same_flight(a, b) -> None:
    """Two run files of one episode: every array and metric equal (bit for bit), but the wall-clock
    timings measured while flying (solve_ms, act_ms, latency_ms), which no re-run can repeat."""
    timing = {"solve_ms", "act_ms", "latency_ms"}
    assert set(a.arrays) == set(b.arrays)
    for k in a.arrays:
        if k not in timing:
            assert np.array_equal(a.arrays[k], b.arrays[k], equal_nan=True), k
    assert json.dumps(a.metrics, sort_keys=True) == json.dumps(b.metrics, sort_keys=True)
    assert (a.termination, a.steps, a.sim_time_s) == (b.termination, b.steps, b.sim_time_s)


@pytest.mark.slow
def test_the_refly_command_reproduces_an_episode_bit_for_bit(tmp_path) -> None:
    import shlex
    out = tmp_path / "camp"
    cfg = cp.CampaignConfig(episodes=2, task="full", max_time=2.5, record_every=1, seed=1)
    doc = cp.run_campaign(cfg, out, jobs=1, progress=False, figure=False)
    rows = {r["episode"]: r for r in doc["episodes"]}
    cmds = {w["episode"]: w["command"] for w in doc["worst_episodes"]}
    assert set(cmds) == {0, 1} and all(f"`{c}`" in (out / "results.md").read_text() for c in cmds.values())
    argv = shlex.split(cmds[1])
    assert argv[:2] == ["wt-inspect", "campaign"] and argv[argv.index("--out") + 1] == str(out / "refly-1")
    assert cp.main(argv[2:] + ["--no-progress", "--no-figure"]) == 0
    again = json.loads((out / "refly-1" / "campaign.json").read_text())
    assert [r["episode"] for r in again["episodes"]] == [1]
    r1 = again["episodes"][0]
    assert r1["run_file"] == rows[1]["run_file"]      # the same run spec
    for k in ("coverage", "safety", "centering", "clearance_min_m", "min_distance", "energy_wh", "steps",
              "fallback_steps", "mass_factor", "termination"):
        assert r1[k] == rows[1][k], k
    _same_flight(load_run(out / "runs" / rows[1]["run_file"]), load_run(out / "refly-1" / "runs" / r1["run_file"]))


@pytest.mark.slow
def test_side_by_side_flies_the_same_episodes_for_each_controller(tmp_path) -> None:
    out = tmp_path / "cmp"
    cfg = cp.CampaignConfig(episodes=2, task="surface", max_time=0.3, record_every=5, seed=4)
    names = ["vtnmpc-plus", "nmpc"]
    doc = cp.run_comparison(cfg, names, out, jobs=1, progress=False, figure=True, command="test")
    assert doc["same_draws"] and doc["paired_episodes"] == [0, 1] and doc["controllers"] == names
    per = {c: json.loads((out / cp.controller_dir(c) / "campaign.json").read_text()) for c in names}
    assert per["vtnmpc-plus"]["draws"] == per["nmpc"]["draws"]
    for k in (0, 1):
        a, b = (per[c]["episodes"][k] for c in names)
        # the same drawn episode: conditions and the airframe the environment drew from the seed
        for col in ("seed", "wind", "wind_direction_deg", "turbine", "start_offset_m", "mass_factor",
                    "thrust_factor"):
            assert a[col] == b[col], col
        runs = [load_run(out / cp.controller_dir(c) / "runs" / per[c]["episodes"][k]["run_file"]) for c in names]
        assert runs[0].spec.env_options == runs[1].spec.env_options
        assert np.array_equal(runs[0].arrays["position"][0], runs[1].arrays["position"][0])   # same start
    md = (out / "comparison.md").read_text()
    assert "| missions completed |" in md and "Where they differ most" in md and (out / "comparison.png").is_file()
    rows = list(csv.DictReader((out / "comparison.csv").open()))
    assert [(r["episode"], r["controller"]) for r in rows] == [("0", "vtnmpc-plus"), ("0", "nmpc"),
                                                                ("1", "vtnmpc-plus"), ("1", "nmpc")]
