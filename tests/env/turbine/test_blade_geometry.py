"""Parametric blades and the NREL 5-MW preset: geometry against the reference tables, clustering
without labels, twisted path normals, the preset through gym.make, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.planner import cluster_surfaces, plan_inspection
from wt_inspect_env.planner.clearance import DistanceField
from wt_inspect_env.turbine.blade_geometry import BladeShape, section_contour
from wt_inspect_env.turbine.loading import load_turbine_mesh
from wt_inspect_env.turbine.mesh import build_turbine
from wt_inspect_env.turbine.presets import NREL_5MW_NODES
from wt_inspect_env.turbine.spec import TurbineSpec


@pytest.fixture(scope="module")
def nrel():
    return build_turbine(TurbineSpec(preset="nrel-5mw"))


@pytest.fixture(scope="module")
def nrel_plan(nrel):
    return plan_inspection(nrel, rotor_turn_deg=None)


def _blade_frame(spec: TurbineSpec, k: int):
    f = math.radians(spec.facing_deg)
    axis = np.array([math.cos(f), math.sin(f), 0.0])
    a = math.radians(spec.rotor_azimuth_deg + 120 * k)
    radial = np.array([0, 0, math.cos(a)]) + math.sin(a) * np.cross(axis, [0, 0, 1.0])
    return axis, radial, np.cross(axis, radial)


def test_nrel_preset_has_the_reference_dimensions(nrel):
    s = nrel.spec
    assert ((s.tower_height, s.hub_radius, s.overhang, s.tower_radius, s.tower_top_radius)
            == (90.0, 1.5, 5.0, 3.0, 1.935))
    assert s.blade_length == pytest.approx(61.5) and s.blade_width == pytest.approx(4.652)
    c = nrel.rotor_center
    axis, radial, chord_dir = _blade_frame(s, 0)
    v = np.concatenate([nrel.blade_vertices[nrel.triangle_blade == 0].reshape(-1, 3)]) - c
    r = v @ radial
    assert r.min() == pytest.approx(1.5) and r.max() == pytest.approx(63.0)        # rotor diameter 126 m
    # at every table node: the section's chord (its longest extent) and its twist (the angle of the
    # chord line out of the rotor plane) are the report's
    for rn, twist, chord, tc in NREL_5MW_NODES:
        ring = v[np.abs(r - rn) < 1e-6]
        assert len(ring) > 0, rn
        d = ring[:, None] - ring[None]
        i, j = np.unravel_index(np.argmax(np.linalg.norm(d, axis=2)), d.shape[:2])
        assert np.linalg.norm(ring[i] - ring[j]) == pytest.approx(chord, rel=0.02 if tc < 1 else 0.03), rn
        if tc < 0.5:                                       # a circle has no chord line to measure
            line = ring[i] - ring[j]
            ang = math.degrees(math.atan2(abs(line @ axis), abs(line @ chord_dir)))
            assert ang == pytest.approx(twist, abs=1.0), rn
            thick = (ring @ np.cross(radial, line / np.linalg.norm(line)))
            assert np.ptp(thick) == pytest.approx(tc * chord, rel=0.15), rn
    # closed, outward blades; a tapered tower from 6 m to 3.87 m diameter
    for b in range(3):
        solid = nrel.blade_solid(b)
        assert solid.is_watertight and solid.volume > 0
    ob = np.asarray(nrel.obstacle_mesh.vertices)
    rad = np.linalg.norm(ob[:, :2] - np.array(s.position), axis=1)
    assert rad[ob[:, 2] < 1e-6].max() == pytest.approx(3.0, abs=1e-6)
    mid = np.abs(ob[:, 2] - 45.0) < 1e-6                         # a tower ring half-way up
    assert rad[mid].max() == pytest.approx(3.0 + (1.935 - 3.0) * 0.5, abs=1e-6)


def test_section_is_a_circle_at_the_root_and_an_aerofoil_outboard():
    circle = section_contour(1.0, 25)
    np.testing.assert_allclose(np.linalg.norm(circle - [0.5, 0.0], axis=1), 0.5, atol=1e-12)
    foil = section_contour(0.18, 25)
    assert np.ptp(foil[:, 0]) == pytest.approx(1.0)
    assert np.ptp(foil[:, 1]) == pytest.approx(0.18 + 0.0, abs=0.03)             # t/c 18 % (+ camber)
    assert foil[np.argmax(foil[:, 1]), 0] < 0.45                                  # thickest ahead of mid-chord


def test_clustering_finds_the_four_sides_of_each_twisted_blade_without_labels(nrel, tmp_path):
    """Suction and pressure side, leading and trailing edge: the clusters agree with the design's
    labels (which use the known twist) on >= 99 % of the area; the loaded export clusters the same."""
    surfaces, ignored = cluster_surfaces(nrel)
    assert len(surfaces) == 12
    covered = 0.0
    for s in surfaces:
        lab = np.bincount(nrel.triangle_face[s.triangles], weights=nrel.blade_areas[s.triangles], minlength=4)
        assert lab.max() >= 0.99 * lab.sum()
        covered += lab.max()
    per_blade = [sorted(int(np.argmax(np.bincount(nrel.triangle_face[s.triangles], minlength=4)))
                        for s in surfaces if s.blade == b) for b in range(3)]
    assert per_blade == [[0, 1, 2, 3]] * 3
    assert covered >= 0.98 * nrel.blade_areas.sum()
    loaded = load_turbine_mesh(nrel.export(tmp_path / "nrel.stl"))
    again, _ = cluster_surfaces(loaded)
    assert len(again) == 12
    for a, b in zip(surfaces, again):          # the file's 32-bit coordinates may move a boundary triangle
        assert len(np.setxor1d(a.triangles, b.triangles)) <= max(2, 0.01 * len(a.triangles))


def test_nrel_plan_is_complete_clear_and_its_normals_turn_with_the_twist(nrel, nrel_plan):
    p = nrel_plan
    assert sorted(x.surface for x in p.tour) == list(range(12))
    assert p.min_clearance() >= p.config.clearance
    for sid in range(12):
        g = p.surface_geometry(sid)
        sel = p.surface == sid
        field = DistanceField(p.turbine(p.surface_phase[sid]).blade_vertices[g.triangles])
        # nodes on the surface; between them (<= 1.4 m) the circle-to-aerofoil transition at 8-12 m
        # bends along the span, so interpolated points sit up to ~0.2 m off it (SM band: 1 m)
        assert field.distance(g.nodes, 1.0).max() < 0.01
        assert field.distance(p.points[sel], 1.0).max() < 0.25
        assert max(g.trim) <= p.config.end_trim_limit
    # the suction side of the upright blade (blade 0, phase 1): the path normal turns about the span
    # axis as the report's twist does (13.3 deg near the root to 0.1 deg at the tip, plus the change
    # of the section from 35 % to 18 % thick), matching the design-labelled triangles station by station
    axis, radial, chord_dir = _blade_frame(nrel.spec, 0)
    sid = next(s.id for s in p.surfaces if s.blade == 0 and p.surface_phase[s.id] == 1
               and np.bincount(nrel.triangle_face[s.triangles]).argmax() == 0)
    sel = p.surface == sid
    r = (p.points[sel] - nrel.rotor_center) @ radial
    n = p.normals[sel]

    def angle(v):                                                  # turned from +axis towards -chord
        return np.degrees(np.arctan2(-(v @ chord_dir), v @ axis))

    side = np.flatnonzero((nrel.triangle_blade == 0) & (nrel.triangle_face == 0))
    r_tri = (nrel.blade_centroids[side] - nrel.rotor_center) @ radial
    mid = np.flatnonzero((r > 15.0) & (r < 58.0))[::10]           # aerofoil part, away from the tip cap
    want = []
    for i in mid:
        near = side[np.abs(r_tri - r[i]) < 1.0]
        m = nrel.blade_areas[near] @ nrel.blade_normals[near]
        want.append(angle(m / np.linalg.norm(m)))
    got = angle(n[mid])
    assert np.abs(got - np.array(want)).max() < 2.0
    assert np.ptp(got) > 9.0        # it does turn, by more than the twist's 11 deg less margin


def test_preset_through_gym_make_and_overrides():
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the ids
    env = gym.make("WindTurbineInspection-Surface-v0", turbine={"preset": "nrel-5mw", "mesh_step": 2.0}, wind="none")
    try:
        env.reset(seed=0)
        spec = env.unwrapped.mission.turbines[0].spec
        assert spec.preset == "nrel-5mw" and spec.tower_height == 90.0 and spec.mesh_step == 2.0
    finally:
        env.close()
    short = TurbineSpec(preset="nrel-5mw", blade_length=40.0)        # scaled geometrically
    assert short.blade_length == pytest.approx(40.0)
    assert short.blade_width == pytest.approx(4.652 * 40.0 / 61.5)
    assert TurbineSpec(preset="nrel-5mw", tower_height=100.0).tower_height == 100.0


@pytest.mark.parametrize("kw,match", [
    ({"preset": "nrel-6mw"}, "preset must be one of nrel-5mw"),
    ({"blade": {"span": [1, 2, 3], "chord": [1, 1], "twist_deg": [0, 0, 0], "thickness": [1, 1, 1]}},
     "blade chord has 2 values but span has 3"),
    ({"blade": {"span": [1, 3, 2], "chord": [1, 1, 1], "twist_deg": [0, 0, 0], "thickness": [1, 1, 1]}},
     "blade span must be positive and strictly increasing"),
    ({"blade": {"span": [1, 20], "chord": [1, -1], "twist_deg": [0, 0], "thickness": [1, 1]}}, "blade chord"),
    ({"blade": {"span": [1, 20], "chord": [1, 1], "twist_deg": [0, 0], "thickness": [1, 1.5]}}, "blade thickness"),
    ({"blade": {"span": [1, 20], "chord": [1, 1], "twist_deg": [0, 0], "thickness": [1, 1], "camber": 2}},
     "camber"),
    ({"blade": "long"}, "blade must be a dict"),
    ({"tower_top_radius": 2.0}, "tower_top_radius"),
    ({"nacelle_radius": 1.0}, "nacelle_length"),
])
def test_bad_blade_and_preset_input_is_one_line_naming_the_field(kw, match):
    with pytest.raises(ValueError, match=match) as err:
        TurbineSpec(**kw)
    assert "\n" not in str(err.value)


def test_a_custom_blade_shape():
    shape = BladeShape(span=(2.0, 10.0, 30.0), chord=(2.0, 2.5, 1.0), twist_deg=(10.0, 6.0, 0.0),
                       thickness=(1.0, 0.3, 0.18))
    t = build_turbine(TurbineSpec(blade=shape, hub_radius=2.0, tower_height=50.0, mesh_step=1.0))
    assert t.spec.blade_length == pytest.approx(28.0)
    surfaces, _ = cluster_surfaces(t)
    assert len(surfaces) >= 9                                   # sides and leading edges of 3 blades
    p = plan_inspection(t, rotor_turn_deg=None)
    assert sorted(x.surface for x in p.tour) == list(range(len(surfaces)))


def test_rotor_turn_auto_pins_the_paper_turn_only_on_the_paper_turbine():
    """``rotor_turn_deg="auto"`` (default): 120 deg on the paper's turbine, the planner's choice on any
    other - the NREL 5-MW has no fixed-120-deg plan at d_min = 3 m (its blade roots beside the hub)."""
    from wt_inspect_env.task.env_config import EnvConfig
    from wt_inspect_env.task.mission import build_mission

    assert EnvConfig().rotor_turn_deg == 120.0
    assert EnvConfig(turbine={"preset": "nrel-5mw"}).rotor_turn_deg is None
    assert EnvConfig(turbine={"rotor_azimuth_deg": 47.0}).rotor_turn_deg is None
    assert EnvConfig(rotor_turn_deg=90.0, turbine={"preset": "nrel-5mw"}).rotor_turn_deg == 90.0
    with pytest.raises(ValueError, match="rotor_turn_deg must be a number, None or 'auto', got 'sometimes'"):
        EnvConfig(rotor_turn_deg="sometimes")
    with pytest.raises(ValueError, match="surface .* cannot be inspected"):
        build_mission(EnvConfig(turbine={"preset": "nrel-5mw", "mesh_step": 2.0}, rotor_turn_deg=120.0))
    m = build_mission(EnvConfig(turbine={"preset": "nrel-5mw", "mesh_step": 2.0}))
    assert set(m.surface[m.surface >= 0].tolist()) == set(range(len(m.surfaces))) == set(range(12))
    assert m.plan.rotor_turns_deg and m.plan.rotor_turns_deg[0] != 120.0
