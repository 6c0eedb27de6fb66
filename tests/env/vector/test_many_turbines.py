"""Many turbines in one vector env: G worlds on drawn turbines, drone i is the single env on its
world's turbine, the same seed draws the same turbines, and a redraw truncates the flying drones."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import wt_inspect_env  # noqa: F401 - registers the ids
from wt_inspect_env.task.turbine_draws import TurbineDistribution
from wt_inspect_env.vector import WindTurbineInspectionVectorEnv
from wt_inspect_env.vector.turbines import REDRAW, many_turbine_kwargs, turbine_stream

ENV = "WindTurbineInspection-v0"
# generated turbines plan fastest; the kinds are the distribution's business, tested below
FAST = {"kinds": {"generated": 1.0}}


def _venv(n: int, g: int, **options) -> WindTurbineInspectionVectorEnv:
    return WindTurbineInspectionVectorEnv(num_envs=n, turbines=options.pop("turbines", FAST), n_turbines=g,
                                          **options)


def test_drone_i_is_the_single_env_on_its_worlds_turbine():
    # Bit for bit: each world is an InspectionWorld whose per-drone arithmetic does not depend on
    # its batch (the vector env's contract), and the single env is a world of one on the same
    # turbine option, seeded as drone i. Drones 1 and 2: the second of world 0, the first of world 1.
    opts = {"start_noise": 0.5, "time_limit_s": 0.25}
    venv = _venv(4, 2, redraw_every=100, **opts)
    singles = {}
    try:
        vobs, info = venv.reset(seed=3)
        assert [int(d) for d in info["turbine_draw"]] == [0, 0, 0, 0]
        for i in (1, 2):
            draw = venv.draws[i // 2]
            assert info["turbine"]["tower_height"][i] == draw.sizes["tower_height"]
            singles[i] = gym.make(ENV, turbine=draw.turbine_option(), **opts).unwrapped
            obs, _ = singles[i].reset(seed=3 + i)
            for k in obs:
                assert np.array_equal(vobs[k][i], obs[k]), (k, i)
        assert venv.draws[0] != venv.draws[1]
        hover = venv.scaling.hover_action()
        rng = np.random.default_rng(1)
        resets = 0
        for t in range(60):
            act = np.clip(hover + rng.normal(0.0, 0.05, (4, 4)), -1, 1).astype(np.float32)
            vobs, vrew, vterm, vtrunc, vinfo = venv.step(act)
            for i, env in singles.items():
                obs, rew, term, trunc, sinfo = env.step(act[i])
                assert vrew[i] == rew and (vterm[i], vtrunc[i]) == (term, trunc), (t, i)
                if term or trunc:
                    resets += 1
                    for k in obs:
                        assert np.array_equal(vinfo["final_obs"][i][k], obs[k]), (t, i, k)
                    assert vinfo["final_info"]["metrics"]["coverage"][i] == sinfo["metrics"]["coverage"]
                    assert vinfo["final_info"]["turbine"]["blade_length"][i] == venv.draws[i // 2].sizes["blade_length"]
                    obs, _ = env.reset()
                for k in obs:
                    assert np.array_equal(vobs[k][i], obs[k]), (t, i, k)
        assert resets >= 4 and venv.draw_count.tolist() == [0, 0]     # autoresets, no redraw
    finally:
        venv.close()
        for env in singles.values():
            env.close()


def test_world_g_draws_from_the_stream_of_its_first_drones_seed():
    env = gym.make_vec(ENV, num_envs=4, vectorization_mode="vector_entry_point", turbines={}, n_turbines=2)
    venv = env.unwrapped
    try:
        obs, _ = env.reset(seed=7)
        assert env.observation_space.contains(obs) and len(venv.worlds) == 2
        for g in range(2):
            expect = TurbineDistribution().draw(turbine_stream(7 + 2 * g))
            assert venv.draws[g] == expect
            assert venv.worlds[g].config.turbine.rotor_azimuth_deg == expect.rotor_azimuth_deg
    finally:
        venv.close()


def test_the_same_seed_gives_the_same_turbines_and_episodes_another_seed_does_not():
    a, b = _venv(2, 2), _venv(2, 2)
    try:
        hover = np.tile(a.scaling.hover_action(), (2, 1))
        oa, _ = a.reset(seed=5)
        ob, _ = b.reset(seed=5)
        assert a.draws == b.draws
        for k in oa:
            assert np.array_equal(oa[k], ob[k])
        first = [a.step(hover)[0]["position"].copy() for _ in range(5)]
        assert all(np.array_equal(x, b.step(hover)[0]["position"]) for x in first)
        worlds = list(a.worlds)
        a.reset(seed=5)                     # the same draws: the worlds are kept, the episodes replayed
        assert all(w is v for w, v in zip(a.worlds, worlds))
        assert all(np.array_equal(x, a.step(hover)[0]["position"]) for x in first)
        draws = list(a.draws)
        a.reset(seed=6)
        assert a.draws != draws and not np.array_equal(a.step(hover)[0]["position"], first[0])
    finally:
        a.close()
        b.close()


def test_a_redraw_truncates_the_flying_drones_and_changes_the_turbine():
    # two drones, redraw_every=1: the world's second ended episode (drone 0 climbs and loses its
    # pose first, then either ends again) redraws the turbine and cuts the other drone short
    venv = _venv(2, 1, redraw_every=1, pose_error_limit=0.5, time_limit_s=5.0)
    space = venv.single_observation_space
    try:
        obs, info = venv.reset(seed=2)
        assert venv.observation_space.contains(obs)
        old = venv.draws[0]
        act = np.tile(venv.scaling.hover_action(), (2, 1))
        act[0, 3] = 1.0
        ended = 0
        for _ in range(400):
            obs, rew, term, trunc, info = venv.step(act)
            assert venv.observation_space.contains(obs) and rew.shape == (2,)
            ended += int((term | trunc).sum())
            if venv.draw_count[0]:
                break
        else:
            pytest.fail("no redraw within 400 steps")
        assert ended >= 2
        cut = [i for i in range(2) if info["termination"][i] == REDRAW]
        assert len(cut) <= 1
        for i in cut:         # a drone still flying: truncated, with its final observation and info
            assert trunc[i] and not term[i]
            assert info["_final_obs"][i] and space.contains(info["final_obs"][i])
            assert info["final_info"]["termination"][i] == REDRAW
            assert info["final_info"]["turbine"]["tower_height"][i] == old.sizes["tower_height"]
        assert (term | trunc).all()          # every drone of the world ended this step
        assert venv.draws[0] != old and info["turbine_draw"].tolist() == [1, 1]
        assert info["turbine"]["tower_height"][0] == venv.draws[0].sizes["tower_height"]
        assert venv.steps.tolist() == [0, 0]
        obs, *_ = venv.step(act)       # the new world flies
        assert venv.steps.tolist() == [1, 1] and venv.observation_space.contains(obs)
    finally:
        venv.close()


def test_redraw_after_flown_seconds_staggers_the_worlds_and_cuts_every_flying_drone():
    # 2 worlds, T = 0.3 s at 100 Hz: world 0's first turbine lasts T/2 (15 steps), world 1's T (30);
    # then every 30 steps each. Hovering drones end no episode, so every redraw cuts both of a world.
    venv = _venv(4, 2, redraw_after_s=0.3, time_limit_s=5.0)
    try:
        venv.reset(seed=5)
        first = list(venv.draws)
        act = np.tile(venv.scaling.hover_action(), (4, 1))
        cuts = {}
        for t in range(1, 61):
            _, _, term, trunc, info = venv.step(act)
            assert not term.any()
            for i in np.flatnonzero(trunc):
                assert info["termination"][i] == REDRAW
                cuts.setdefault(int(i) // 2, []).append(t)
        assert cuts == {0: [15, 15, 45, 45], 1: [30, 30, 60, 60]}
        assert venv.draw_count.tolist() == [2, 2] and venv.draws[0] != first[0] and venv.draws[1] != first[1]
    finally:
        venv.close()


def test_the_redraw_cut_reaches_sb3_as_a_time_limit_truncation():
    """The SB3 adapter reports a redraw cut as ``TimeLimit.truncated`` (PPO bootstraps from it)
    with the ended episode's turbine."""
    pytest.importorskip("stable_baselines3")
    from agents.recipe import Recipe, default_recipe_path, load_recipe
    from agents.training import recipe_vec_env

    base = load_recipe(default_recipe_path("ppo")).to_dict()
    rec = Recipe.from_dict({**base, "env": {**base["env"], "time_limit_s": 2.0, "wind": "none", "start_noise": 0.5,
                                            "pose_error_limit": 0.6},
                            "turbines": {"n_turbines": 1, "redraw_every": 1, "distribution": FAST}})
    venv = recipe_vec_env(rec, "surface", 2, seed=4)
    try:
        u = venv.venv.venv
        assert u.n_turbines == 1 and u.drones_per_world == 2
        venv.reset()
        first = u.draws[0]
        seen: dict[str, int] = {}
        for _ in range(60):
            _, rew, done, infos = venv.step(np.ones((2, 4), dtype=np.float32))
            assert np.isfinite(rew).all()
            for d, inf in zip(done, infos):
                if d:
                    seen[inf["termination"]] = seen.get(inf["termination"], 0) + 1
                    assert inf["turbine"]["kind"] == "generated"
                    if inf["termination"] == REDRAW:
                        assert inf["TimeLimit.truncated"]
            if seen.get(REDRAW):
                break
        assert seen.get(REDRAW) and u.draw_count[0] >= 1 and u.draws[0] != first, seen
    finally:
        venv.close()


def test_the_default_distribution_draws_every_kind_and_the_campaigns_ranges():
    rng = np.random.default_rng(0)
    draws = [TurbineDistribution().draw(rng) for _ in range(200)]
    assert {d.kind for d in draws} == {"generated", "nrel-5mw", "nrel-5mw-scaled"}
    assert all(0.0 <= d.rotor_azimuth_deg < 120.0 for d in draws)
    assert all(80.0 <= d.sizes["tower_height"] <= 130.0 for d in draws if d.kind == "generated")
    assert all(d.spec == {"preset": "nrel-5mw"} for d in draws if d.kind == "nrel-5mw")


@pytest.mark.parametrize("kwargs, match", [
    ({"num_envs": 4, "turbines": {}, "n_turbines": 3}, r"n_turbines must divide num_envs=4, got 3"),
    ({"num_envs": 4, "turbines": {}, "n_turbines": -2}, r"n_turbines must be a positive integer, got -2"),
    ({"num_envs": 4, "turbines": {}, "redraw_every": 0}, r"redraw_every must be a positive integer, got 0"),
    ({"num_envs": 4, "n_turbines": 2}, r"n_turbines=2 needs turbines="),
    ({"num_envs": 4, "turbines": {}, "redraw_after_s": -1.0}, r"redraw_after_s must be"),
    ({"num_envs": 4, "turbines": {}, "redraw_after_s": 10.0, "redraw_every": 3},
     r"either redraw_every .* or redraw_after_s"),
    ({"num_envs": 4, "redraw_after_s": 10.0}, r"redraw_after_s needs turbines="),
    ({"num_envs": 2, "turbines": {"kinds": {"v236": 1.0}}}, r"turbines.kinds: unknown turbine kind or preset 'v236'"),
    ({"num_envs": 2, "turbines": {"kinds": {"generated": -1.0}}}, r"turbines.kinds\['generated'\] must be a weight"),
    ({"num_envs": 2, "turbines": {"tower_height": [90.0, 80.0]}}, r"turbines.tower_height must be \[lo, hi\]"),
    ({"num_envs": 2, "turbines": {"blade_length": [-5.0, 40.0]}}, r"turbines.blade_length must be \[lo, hi\]"),
    ({"num_envs": 2, "turbines": {"hub": 3}}, r"turbines"),
    ({"num_envs": 2, "turbines": {}, "turbine": {"preset": "nrel-5mw"}}, r"either turbines .* or turbine"),
])
def test_bad_options_are_one_line_errors_naming_the_field(kwargs, match):
    with pytest.raises(ValueError, match=match) as exc:
        WindTurbineInspectionVectorEnv(**kwargs)
    assert "\n" not in str(exc.value)


def test_many_turbine_kwargs_validate_plain_data():
    kw = many_turbine_kwargs({"n_turbines": 2, "redraw_every": 3, "distribution": {"kinds": {"nrel-5mw": 1}}})
    assert kw["n_turbines"] == 2 and kw["redraw_every"] == 3 and kw["turbines"].kinds == {"nrel-5mw": 1.0}
    with pytest.raises(ValueError, match="turbines.n_turbines is required"):
        many_turbine_kwargs({"redraw_every": 2})
    with pytest.raises(ValueError, match=r"turbines.redraw_every must be a positive integer, got 'x'"):
        many_turbine_kwargs({"n_turbines": 1, "redraw_every": "x"})
    assert many_turbine_kwargs({"n_turbines": 1, "redraw_after_s": 200})["redraw_after_s"] == 200.0
    with pytest.raises(ValueError, match=r"either redraw_every .* or redraw_after_s"):
        many_turbine_kwargs({"n_turbines": 1, "redraw_every": 2, "redraw_after_s": 200})


def test_the_single_world_attributes_name_the_per_world_ones_on_a_many_turbine_env():
    """``world``, ``sim``, ``mission``, ``n_triangles`` and ``time_limit`` belong to one turbine:
    a many-turbine env's raise an AttributeError that points at ``worlds[k]`` (getattr with a
    default still works), a single-turbine env's are its one world's."""
    venv = _venv(2, 2)
    try:
        venv.reset(seed=0)
        for name in ("world", "sim", "mission", "n_triangles", "time_limit"):
            with pytest.raises(AttributeError, match=r"worlds\[k\]"):
                getattr(venv, name)
            assert getattr(venv, name, None) is None
        assert venv.worlds[1].n_triangles > 0
    finally:
        venv.close()
    single = WindTurbineInspectionVectorEnv(num_envs=2)
    try:
        assert single.world is single.worlds[0] and single.sim is single.worlds[0].sim
        assert single.mission is single.worlds[0].mission
        assert single.n_triangles == single.worlds[0].n_triangles > 0 and single.time_limit > 0
    finally:
        single.close()
