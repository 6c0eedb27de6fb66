"""The harness's own metrics (wt_inspect.evaluation.harness_metrics): clearance to the turbine
against a brute force over every mesh triangle, and the energy model against momentum theory.

Flights are a few simulated seconds of the ``surface`` / ``blade`` scenarios in still air
(Dryden at 0 m/s), so their outcome is known: a hover holds m g / 4 on every rotor.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
import trimesh.triangles as tt
from stub_policies import Climb, Hover

from wt_inspect.evaluation import evaluate_policy, load_run, run_evaluation
from wt_inspect.evaluation.harness_metrics import (
    D_MIN_RATIO,
    clearance_metrics,
    energy_metrics,
    geometry_index,
    mesh_clearance,
)
from wt_inspect.evaluation.report import CSV_COLUMNS, read_csv
from wt_inspect.evaluation.runner import make_env, save_run
from wt_inspect.evaluation.scenarios import env_options
from wt_inspect_env.physics.quadrotor import GRAVITY, electrical_power, get_preset
from wt_inspect_env.planner.proximity import MeshProximity


def _brute(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest of *all* triangles (trimesh's closest point on
    every triangle, no spatial search)."""
    tri = np.asarray(triangles, dtype=float)
    return np.array([np.linalg.norm(tt.closest_point(tri, np.repeat(p[None], len(tri), 0)) - p, axis=1).min()
                     for p in np.asarray(points, dtype=float)])


def _trap() -> np.ndarray:
    """A mesh on which the nearest-centroid search misses the nearest triangle: twenty small
    triangles 0.5 m from the origin (their centroids nearest to it) and one long one, with a
    vertex 0.1 m from the origin but its centroid 0.9 m away (its size within the 3x median that
    keeps it out of MeshProximity's always-tested large triangles)."""
    tris = []
    for k in range(20):
        phi, th = 2 * math.pi * k / 20, 0.35 + 0.8 * (k % 4) / 3
        u = np.array([math.sin(th) * math.cos(phi), math.sin(th) * math.sin(phi), math.cos(th)])
        a = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(u, a)
        c = 0.5 * u
        tris.append([c + 0.32 * (math.cos(g) * a + math.sin(g) * b) for g in (0, 2 * math.pi / 3, 4 * math.pi / 3)])
    tris.append([[0.0, 0.0, -0.1], [0.05, 1.35, -0.1], [-0.05, 1.35, -0.1]])
    return np.array(tris)


def test_clearance_is_exact_against_a_brute_force_even_where_the_candidate_search_misses():
    trap = _trap()
    origin = np.zeros((1, 3))
    assert MeshProximity(trap).distance(origin)[0] > 0.4            # the MPCs' structure alone: 0.5 m
    assert mesh_clearance(origin, [trap])[0] == pytest.approx(0.1, abs=1e-12)
    # a small closed mesh plus the trap, random points near and far: the minimum and every
    # sample below d_min are exact, no sample is ever below the truth
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.5).triangles + [4.0, 0.0, 0.0]
    mesh = np.concatenate([trap, sphere])
    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(0.0, 0.4, (150, 3)), rng.normal([4.0, 0.0, 0.0], 2.5, (150, 3))])
    truth = _brute(pts, mesh)
    for d_min in (0.3, 1.0):
        got = mesh_clearance(pts, [mesh], d_min=d_min)
        assert got.min() == pytest.approx(truth.min(), abs=1e-12)
        np.testing.assert_allclose(got[truth < d_min], truth[truth < d_min], atol=1e-12)
        assert np.all(got >= truth - 1e-12)
    # non-finite positions (a diverged state) are NaN and left out of the metrics
    got = mesh_clearance(np.array([[np.nan, 0, 0], [0.0, 0.0, 0.0]]), [trap])
    assert np.isnan(got[0]) and got[1] == pytest.approx(0.1)
    m = clearance_metrics([0.0, 0.01], got, d_min=0.2, body_radius=0.05)
    assert m["clearance_min_m"] == pytest.approx(0.1) and m["time_below_d_min_s"] == pytest.approx(0.01)
    assert m["clearance_body_min_m"] == pytest.approx(0.05)


def test_geometry_index_counts_the_phase_change_holds():
    """The env swaps to the next rotor position's mesh at the first sample of a hold (env.py
    ``_set_phase`` on ``hold_started``) and keeps it after the hold: the index is the number of
    holds started so far, capped at the last mesh."""
    waiting = np.array([0, 0, 1, 1, 0, 0, 1, 0], dtype=bool)
    np.testing.assert_array_equal(geometry_index(waiting, 2), [0, 0, 1, 1, 1, 1, 1, 1])
    np.testing.assert_array_equal(geometry_index(waiting, 3), [0, 0, 1, 1, 1, 1, 2, 2])
    # each sample is measured against its own mesh
    a, b = _trap(), _trap() + [0.0, 0.0, 5.0]
    pts = np.zeros((3, 3))
    expected = [_brute(pts[:1], a)[0], _brute(pts[:1], b)[0], _brute(pts[:1], a)[0]]    # 0.1, 4.9, 0.1
    np.testing.assert_allclose(mesh_clearance(pts, [a, b], np.array([0, 1, 0])), expected, atol=1e-12)


def test_d_min_is_the_mpcs_default():
    from controllers.vtnmpc import VTNMPCConfig
    from wt_inspect_env.task.env_config import EnvConfig
    for d_ref in (7.0, 0.5):
        assert VTNMPCConfig(d_ref=d_ref).d_min == pytest.approx(EnvConfig(standoff=d_ref).d_min)
        assert EnvConfig(standoff=d_ref).d_min == pytest.approx(D_MIN_RATIO * d_ref)


@pytest.mark.slow
def test_crafted_line_past_a_blade_matches_the_brute_force():
    """A straight pass 2 m off a blade face of the paper turbine, from 8 m before to 8 m after
    the closest point, sampled at 100 Hz at 2 m/s: the minimum is the 2 m of the pass, and the
    time below d_min is the stretch the brute force puts below 3 m."""
    env = make_env(env_options("blade", 0.0, wind_type="dryden"))
    try:
        env.reset(seed=0)
        m = env.unwrapped.mission
        tri = m.turbines[0].mesh.triangles
        k = len(m.points) // 2
        p0, n = m.points[k], m.normals[k]
        along = np.cross(n, [0.0, 0.0, 1.0])
        along /= np.linalg.norm(along)
        t = np.arange(0.0, 8.0 + 1e-9, 0.01)
        pos = p0 + 2.0 * n + (t[:, None] - 4.0) * 2.0 * along
        truth = _brute(pos[::5], tri)
        got = mesh_clearance(pos, [m.turbines[0].mesh], d_min=3.0)
        np.testing.assert_allclose(got[::5], truth, atol=1e-9)
        assert got.min() == pytest.approx(min(truth.min(), 2.0), abs=0.02)
        res = clearance_metrics(t, got, 3.0, 0.5)
        below = _brute(pos[1:], tri) < 3.0
        assert res["time_below_d_min_s"] == pytest.approx(0.01 * below.sum(), abs=1e-9)
        assert 0.5 < res["time_below_d_min_s"] < 8.0
    finally:
        env.close()


def make_hover(env):
    """A factory (the harness takes a class with act/reset for a policy object, not a factory)."""
    return Hover(env)


def test_flight_close_to_a_blade_reports_its_clearance(tmp_path):
    """Hovering 2.5 m from the blade (start offset 4.5 m from the 7 m stand-off towards the
    point): the run's clearance is the brute force's at every sample, below d_min all the time."""
    env = make_env(env_options("blade", 0.0, wind_type="dryden"))
    try:
        obs, info = env.reset(seed=0)
        toward = obs["point"].astype(float) - info["ideal_position"]
        toward[2] = 0.0
        offset = (4.5 * toward / np.linalg.norm(toward)).tolist()
        tri = env.unwrapped.mission.turbines[0].mesh.triangles
    finally:
        env.close()
    res = evaluate_policy(make_hover, scenario="blade", wind=0.0, wind_type="dryden", max_time=1.0, name="hover",
                          env_overrides={"start_offset": offset}, save_dir=tmp_path)
    a = res.arrays
    truth = _brute(a["position"].astype(float), tri)
    np.testing.assert_allclose(a["clearance"], truth, atol=2e-5)      # float32 positions and array
    m = res.metrics
    assert m["clearance_min_m"] == pytest.approx(truth.min(), abs=2e-5) and m["clearance_min_m"] < 2.6
    assert m["d_min_m"] == pytest.approx(3.0) and m["time_below_d_min_s"] == pytest.approx(1.0)
    r = float(np.linalg.norm(get_preset("matrice100").collision_half_extents))
    assert m["clearance_body_min_m"] == pytest.approx(m["clearance_min_m"] - r)
    assert m["min_distance_m"] > m["clearance_min_m"] - 1e-6    # the point distance is the other number
    row = load_run(res.path).row()
    assert row["clearance_min_m"] == m["clearance_min_m"] and row["time_below_d_min_s"] == pytest.approx(1.0)


@pytest.mark.parametrize("preset", ["matrice100", "lab250"])
def test_hover_power_is_momentum_theory_over_figure_of_merit_and_efficiency(preset):
    p = get_preset(preset)
    T = p.mass * GRAVITY / 4.0
    ideal = T ** 1.5 / math.sqrt(2.0 * 1.225 * math.pi * p.prop_radius ** 2)
    assert p.hover_power == pytest.approx(4 * ideal / (p.figure_of_merit * p.drive_efficiency), rel=1e-12)
    assert float(electrical_power(p, [T] * 4)) == pytest.approx(p.hover_power, rel=1e-12)
    # the same total thrust shared unevenly costs more (P grows as T^1.5)
    assert float(electrical_power(p, [1.5 * T, 0.5 * T, 1.5 * T, 0.5 * T])) > p.hover_power
    with pytest.raises(ValueError, match="figure_of_merit"):
        p.replace(figure_of_merit=1.2)


def test_hover_power_of_the_matrice100_preset():
    """3.6 kg, 13-inch rotors, figure of merit 0.65, motor + ESC 0.75: 8.83 N per rotor is 57.3 W
    of ideal induced power, 470 W electrical for the four."""
    assert get_preset("matrice100").hover_power == pytest.approx(470.2, abs=0.1)


def test_recorded_hover_uses_hover_power_times_time():
    res = evaluate_policy(make_hover, scenario="surface", wind=0.0, wind_type="dryden", max_time=2.0, name="hover")
    p = get_preset("matrice100")
    m, a = res.metrics, res.arrays
    np.testing.assert_allclose(a["rotor_thrust"], p.weight / 4.0, rtol=1e-6)
    np.testing.assert_allclose(a["power"], p.hover_power, rtol=1e-6)
    assert m["energy_wh"] * 3600.0 == pytest.approx(p.hover_power * 2.0, rel=1e-6)
    assert m["mean_power_w"] == pytest.approx(p.hover_power, rel=1e-6)
    assert m["hover_power_w"] == pytest.approx(p.hover_power)
    e = energy_metrics(a["t"], a["power"], p)
    assert e["energy_wh"] == pytest.approx(m["energy_wh"], rel=1e-6)


def test_straight_climb_path_length_and_energy():
    res = evaluate_policy(lambda env: Climb(env), scenario="surface", wind=0.0, wind_type="dryden", max_time=1.0,
                          name="climb")
    a, m = res.arrays, res.metrics
    pos = a["position"].astype(float)
    rise = pos[-1] - pos[0]
    assert rise[2] > 0.3 and np.linalg.norm(rise[:2]) < 1e-3 * rise[2]    # straight up
    assert m["path_length_m"] == pytest.approx(np.linalg.norm(rise), rel=1e-4)
    # more thrust than hover: more power, after the motors' 0.04 s lag 1.2^1.5 times hover's
    p = get_preset("matrice100")
    assert a["power"][-1] == pytest.approx(1.2 ** 1.5 * p.hover_power, rel=1e-3)
    assert p.hover_power < m["mean_power_w"] < 1.2 ** 1.5 * p.hover_power


@pytest.mark.slow
def test_tables_and_figures_carry_clearance_and_energy(tmp_path):
    out = tmp_path / "ev"
    kw = dict(winds=[0.0], max_time=0.5, wind_type="dryden", jobs=1, progress=False)
    ev = run_evaluation("surface", {"hover": make_hover}, out=out, **kw)
    rows = read_csv(out / "results.csv")
    new = ("clearance_min_m", "clearance_body_min_m", "time_below_d_min_s", "d_min_m", "energy_wh", "mean_power_w")
    assert set(new) <= set(CSV_COLUMNS) and list(rows[0]) == list(CSV_COLUMNS)
    r = rows[0]
    assert r["clearance_min_m"] == pytest.approx(7.0, abs=0.01) and r["time_below_d_min_s"] == 0.0
    assert r["energy_wh"] == pytest.approx(get_preset("matrice100").hover_power * 0.5 / 3600, rel=1e-6)
    md = (out / "results.md").read_text()
    for label in ("Min distance to the inspection point", "Min clearance to the turbine (centre)",
                  "Time below d_min (3 m)", "| Energy | 0.07 Wh |", "| Mean power | 470 W |", "Path length",
                  "hover power 470 W"):
        assert label in md, label
    assert (out / "energy_w0.png").stat().st_size > 10_000
    # a run file from before these metrics (no arrays, no keys): '-' in the tables, figures still drawn
    old = load_run(ev.results[0].path)
    for k in ("clearance", "rotor_thrust", "power"):
        old.arrays.pop(k)
    for k in new + ("hover_power_w",):
        old.metrics.pop(k)
    save_run(old, ev.results[0].path)
    run_evaluation("surface", {"hover": make_hover}, out=out, **kw)
    assert math.isnan(read_csv(out / "results.csv")[0]["energy_wh"])
    assert "| Energy | - |" in (out / "results.md").read_text()
