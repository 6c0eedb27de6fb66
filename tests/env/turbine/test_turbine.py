"""Turbine spec and mesh: validity of the geometry, rotation identity, export/load, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.turbine.loading import load_turbine_mesh
from wt_inspect_env.turbine.mesh import TurbineMesh, build_turbine, rotation_matrix
from wt_inspect_env.turbine.spec import TurbineSpec


@pytest.fixture(scope="module")
def turb() -> TurbineMesh:
    return build_turbine()


def blade_frame(spec: TurbineSpec, k: int, turn_deg: float = 0.0):
    """Radial and chord directions of blade k, written out independently of the builder."""
    f = math.radians(spec.facing_deg)
    axis = np.array([math.cos(f), math.sin(f), 0.0])
    a = math.radians(spec.rotor_azimuth_deg + 120 * k + turn_deg)
    # rotate (0,0,1) about `axis` by a (Rodrigues, written for a horizontal axis)
    radial = np.array([0, 0, math.cos(a)]) + math.sin(a) * np.cross(axis, [0, 0, 1.0])
    return axis, radial, np.cross(axis, radial)


def test_defaults_are_the_papers_v100():
    s = TurbineSpec()
    assert (s.tower_height, s.blade_length, s.blade_width) == (120.0, 50.0, 3.0)
    assert s.blade_thickness == pytest.approx(1.0)            # b_w / 3
    assert s.hub_radius == pytest.approx(2.1)
    assert s.mesh_step == 1.5
    np.testing.assert_allclose(s.rotor_center, [0.0, s.overhang, 120.0], atol=1e-12)


@pytest.mark.parametrize("step", [1.5, 1.0, 0.7, 3.0, 2.2])
def test_triangle_counts_sizes_and_right_angles(step):
    spec = TurbineSpec(mesh_step=step)
    t = build_turbine(spec)
    nu, nv, nt = (math.ceil(50 / step), math.ceil(3 / step), math.ceil(1 / step))
    assert len(t.blade_vertices) == 3 * 2 * nu * (2 * nv + 2 * nt) == spec.n_blade_triangles
    assert len(t.cap_vertices) == 3 * 2 * 2 * nv * nt
    # total inspected area = 3 blades x 2 x (w + t) x L
    assert t.blade_areas.sum() == pytest.approx(3 * 2 * (3.0 + 1.0) * 50.0)
    # right-angle triangles whose legs do not exceed the step
    V = t.blade_vertices
    e = np.stack([V[:, 1] - V[:, 0], V[:, 2] - V[:, 1], V[:, 0] - V[:, 2]], axis=1)
    dots = np.stack([np.einsum("ij,ij->i", e[:, i], e[:, (i + 1) % 3]) for i in range(3)], axis=1)
    assert np.all(np.min(np.abs(dots), axis=1) < 1e-9)
    legs = np.sort(np.linalg.norm(e, axis=2), axis=1)[:, :2]
    assert legs.max() <= step + 1e-9


def test_blades_are_closed_outward_cuboids(turb):
    for b in range(3):
        solid = turb.blade_solid(b)
        assert solid.is_watertight and solid.is_winding_consistent
        assert solid.volume == pytest.approx(50.0 * 3.0 * 1.0)    # positive: normals point out
    assert turb.mesh.is_watertight                                 # every body of the mesh is closed
    assert turb.obstacle_mesh.is_watertight and turb.obstacle_mesh.volume > 0


def test_normals_point_out_along_the_labelled_face_direction(turb):
    spec = turb.spec
    for k in range(3):
        axis, radial, chord = blade_frame(spec, k)
        sel = turb.triangle_blade == k
        want = {0: axis, 1: -axis, 2: chord, 3: -chord}
        for face, n in want.items():
            m = sel & (turb.triangle_face == face)
            np.testing.assert_allclose(turb.blade_normals[m], np.tile(n, (m.sum(), 1)), atol=1e-12)
        # outward: the centroid lies on the normal's side of the blade's centre line
        c = turb.rotor_center + (spec.hub_radius + 25.0) * radial
        rel = turb.blade_centroids[sel] - c
        assert np.all(np.einsum("ij,ij->i", rel, turb.blade_normals[sel]) > 0)
    np.testing.assert_array_equal(turb.triangle_surface, 4 * turb.triangle_blade + turb.triangle_face)


def test_inverted_y_geometry(turb):
    spec = turb.spec
    c = turb.rotor_center
    for k in range(3):
        _, radial, _ = blade_frame(spec, k)
        v = turb.blade_vertices[turb.triangle_blade == k].reshape(-1, 3) - c
        r = v @ radial
        assert r.min() == pytest.approx(spec.hub_radius) and r.max() == pytest.approx(spec.hub_radius + 50)
    top = turb.blade_vertices[turb.triangle_blade == 0].reshape(-1, 3)
    assert top[:, 2].max() == pytest.approx(120 + 2.1 + 50)                 # blade 0 straight up
    low = turb.blade_vertices[turb.triangle_blade == 1].reshape(-1, 3)
    tip = low[np.argmax(np.linalg.norm(low - c, axis=1))] - c
    assert math.degrees(math.atan2(-tip[2], abs(tip[0]))) == pytest.approx(30.0, abs=2.0)  # 30 deg below
    # the tower stands on the ground at the position and reaches the hub
    ob = turb.obstacle_mesh.vertices
    assert ob[:, 2].min() == pytest.approx(0.0) and ob[:, 2].max() >= 120.0


def test_facing_and_position_move_the_turbine_rigidly(turb):
    other = build_turbine(TurbineSpec(facing_deg=30.0, position=(10.0, -5.0)))
    R = rotation_matrix(np.array([0, 0, 1.0]), math.radians(30.0 - 90.0))
    moved = turb.blade_vertices @ R.T + np.array([10.0, -5.0, 0.0])
    np.testing.assert_allclose(other.blade_vertices, moved, atol=1e-9)
    np.testing.assert_allclose(other.rotor_axis, [math.cos(math.radians(30)), math.sin(math.radians(30)), 0])


def test_rotation_keeps_triangle_identity(turb):
    r = turb.rotated(120.0)
    # the rotor is 3-fold symmetric: blade k turned by 120 deg lands exactly on blade k+1
    for k in range(3):
        np.testing.assert_allclose(r.blade_vertices[turb.triangle_blade == k],
                                   turb.blade_vertices[turb.triangle_blade == (k + 1) % 3], atol=1e-9)
    # triangle i is the same physical triangle: rigid rotation about the axis through the centre
    R = rotation_matrix(turb.rotor_axis, math.radians(37.0))
    r37 = turb.rotated(37.0)
    np.testing.assert_allclose(r37.blade_vertices, (turb.blade_vertices - turb.rotor_center) @ R.T
                               + turb.rotor_center, atol=1e-9)
    np.testing.assert_allclose(r37.blade_areas, turb.blade_areas)
    np.testing.assert_array_equal(r37.triangle_surface, turb.triangle_surface)
    np.testing.assert_allclose(turb.rotated(10).rotated(25).blade_vertices, turb.rotated(35).blade_vertices,
                               atol=1e-9)
    np.testing.assert_allclose(turb.rotated(360).blade_vertices, turb.blade_vertices, atol=1e-9)
    assert r37.obstacle_mesh is turb.obstacle_mesh
    assert r37.azimuth_deg == pytest.approx(37.0)
    # the whole mesh keeps the order: blade triangles first
    np.testing.assert_allclose(r37.mesh.triangles[: len(r37.blade_vertices)], r37.blade_vertices)


@pytest.mark.parametrize("suffix", [".stl", ".obj"])
def test_export_and_load_round_trip(turb, tmp_path, suffix):
    path = turb.export(tmp_path / f"t{suffix}")
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]      # no temporary left over
    m = len(turb.blade_vertices)
    loaded = load_turbine_mesh(path, blade_faces=np.arange(m))
    np.testing.assert_allclose(loaded.blade_vertices, turb.blade_vertices, atol=1e-4)
    np.testing.assert_allclose(loaded.blade_normals, turb.blade_normals, atol=1e-5)
    np.testing.assert_allclose(loaded.rotor_axis, turb.rotor_axis, atol=1e-4)
    np.testing.assert_allclose(loaded.rotor_center, turb.rotor_center, atol=1e-3)
    # blades found geometrically: the same grouping as the builder's labels
    for k in range(3):
        assert len(np.unique(loaded.triangle_blade[turb.triangle_blade == k])) == 1
    assert len(np.unique(loaded.triangle_blade)) == 3
    assert len(loaded.obstacle_mesh.faces) == len(turb.mesh.faces) - m
    same = load_turbine_mesh(path, obstacle_faces=np.arange(m, len(turb.mesh.faces)))
    np.testing.assert_allclose(same.blade_vertices, loaded.blade_vertices)


def test_load_errors(turb, tmp_path):
    path = turb.export(tmp_path / "t.stl")
    with pytest.raises(ValueError, match="path"):
        load_turbine_mesh(tmp_path / "missing.stl")
    with pytest.raises(ValueError, match="blade_faces or obstacle_faces"):
        load_turbine_mesh(path, blade_faces=[0], obstacle_faces=[1])
    with pytest.raises(ValueError, match="blade_faces"):
        load_turbine_mesh(path, blade_faces=[10 ** 7])
    with pytest.raises(ValueError, match="export path"):
        turb.export(tmp_path / "t.ply")


@pytest.mark.parametrize("field,value", [
    ("tower_height", 0.0), ("tower_height", -5.0), ("tower_height", float("nan")), ("tower_height", "tall"),
    ("blade_length", 0.0), ("blade_length", float("inf")),
    ("blade_width", -1.0), ("blade_thickness", 0.0), ("blade_thickness", 4.0),
    ("tower_radius", 0.0), ("hub_radius", 0.5), ("overhang", 1.0),
    ("mesh_step", 0.0), ("mesh_step", 0.001), ("mesh_step", float("nan")),
    ("position", (float("nan"), 0.0)), ("position", (1.0, 2.0, 3.0)),
    ("rotor_azimuth_deg", float("inf")), ("facing_deg", None),
])
def test_bad_spec_values_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        TurbineSpec(**{field: value})


def test_bad_spec_combinations():
    with pytest.raises(ValueError, match="blade_width"):
        TurbineSpec(blade_width=50.0)                      # width >= length
    with pytest.raises(ValueError, match="blade_length"):
        TurbineSpec(blade_length=130.0)                    # longer than the tower is high
    with pytest.raises(ValueError, match="blade_length"):
        TurbineSpec(tower_height=60.0, blade_length=58.0)  # hub radius + length reach the ground
    with pytest.raises(ValueError, match="mesh_step.*triangles"):
        TurbineSpec(mesh_step=0.01)
    with pytest.raises(ValueError, match="colour"):
        TurbineSpec.from_options({"colour": "white"})
    with pytest.raises(ValueError, match="colour"):
        build_turbine(colour="white")
    assert build_turbine(blade_length=40.0).spec.blade_length == 40.0


# --------------------------------------------------------------------------- loading without labels
def _write(tris: np.ndarray, path) -> None:
    import trimesh
    n = len(tris)
    trimesh.Trimesh(vertices=tris.reshape(-1, 3), faces=np.arange(3 * n).reshape(n, 3), process=False).export(
        str(path))


@pytest.mark.parametrize("suffix", [".stl", ".obj"])
def test_own_export_loads_back_without_labels(turb, tmp_path, suffix):
    """The issue's round trip: no face lists, the blades (with their caps) are recognised by shape,
    tower and hub become the obstacle, and the plan is the built turbine's."""
    from wt_inspect_env.planner import cluster_surfaces, plan_inspection
    path = turb.export(tmp_path / f"t{suffix}")
    loaded = load_turbine_mesh(path)
    m, c = len(turb.blade_vertices), len(turb.cap_vertices)
    np.testing.assert_allclose(loaded.blade_vertices, np.concatenate([turb.blade_vertices, turb.cap_vertices]),
                               atol=1e-4)
    assert len(loaded.obstacle_mesh.faces) == len(turb.obstacle_mesh.faces)
    np.testing.assert_allclose(loaded.rotor_center, turb.rotor_center, atol=1e-3)
    np.testing.assert_allclose(loaded.rotor_axis, turb.rotor_axis, atol=1e-4)
    surfaces, ignored = cluster_surfaces(loaded)
    assert len(surfaces) == 12
    np.testing.assert_array_equal(ignored, np.arange(m, m + c))           # the caps
    assert plan_inspection(loaded).tour_length == pytest.approx(plan_inspection(turb).tour_length, abs=1e-2)


def test_units_up_axis_and_ground(turb, tmp_path):
    """PLY in millimetres, GLB with glTF's +Y up (default for .glb), a z-up file whose origin is at
    the hub: each comes back as the same turbine in metres, z up, standing on the ground."""
    tris = turb.mesh.triangles
    ref = load_turbine_mesh(turb.export(tmp_path / "ref.stl"))
    _write(tris * 1000.0, tmp_path / "t.ply")
    _write(tris @ np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]).T, tmp_path / "t.glb")   # z -> y
    _write(tris - np.array([0.0, 0.0, 120.0]), tmp_path / "hub_origin.stl")
    _write(tris @ np.array([[0.0, 0, 1.0], [0, 1.0, 0], [-1.0, 0, 0]]).T, tmp_path / "x_up.obj")  # z -> x
    for path, kw in (("t.ply", {"unit": "mm"}), ("t.glb", {}), ("hub_origin.stl", {"place_on_ground": True}),
                     ("x_up.obj", {"up_axis": "x"})):
        got = load_turbine_mesh(tmp_path / path, **kw)
        np.testing.assert_allclose(got.blade_vertices, ref.blade_vertices, atol=2e-3, err_msg=path)
        np.testing.assert_allclose(got.rotor_center, ref.rotor_center, atol=2e-3, err_msg=path)
    # the same options as a dict (what gym.make's turbine_mesh accepts)
    got = load_turbine_mesh({"path": str(tmp_path / "t.ply"), "unit": 0.001})
    np.testing.assert_allclose(got.blade_vertices, ref.blade_vertices, atol=2e-3)
    with pytest.raises(ValueError, match="below the ground.*place_on_ground"):
        load_turbine_mesh(tmp_path / "hub_origin.stl")
    with pytest.raises(ValueError, match="below the ground.*up_axis"):
        load_turbine_mesh(tmp_path / "t.glb", up_axis="-z")


def test_an_implausibly_big_mesh_is_refused_before_planning_and_the_unit_suggested(turb, tmp_path):
    """Issue 33: the project's own export in millimetres, loaded without ``unit``, planned for
    minutes and then failed on a 118 km transit; a scale of 1e30 failed deep in numpy. Both are
    now one line naming the file, the unit and the size, before any work."""
    from wt_inspect_env.turbine.spec import MAX_MESH_EXTENT
    _write(turb.mesh.triangles * 1000.0, tmp_path / "mm.stl")
    with pytest.raises(ValueError, match=r"mm\.stl.*m across with unit 'm'.*unit=\"mm\""):
        load_turbine_mesh(tmp_path / "mm.stl")
    assert load_turbine_mesh(tmp_path / "mm.stl", unit="mm").n_blade_triangles > 0
    path = turb.export(tmp_path / "t.stl")
    with pytest.raises(ValueError, match=rf"unit 1e\+30, more than the {MAX_MESH_EXTENT:g} m.*unit=\"m\""):
        load_turbine_mesh(path, unit=1e30)
    import gymnasium as gym
    with pytest.raises(ValueError, match=r"mm\.stl.*unit=\"mm\""):
        gym.make("WindTurbineInspection-v0", turbine_mesh=str(tmp_path / "mm.stl"))


def test_unrecognisable_parts_say_what_was_found_and_what_to_give(turb, tmp_path):
    # blades bridged at the root into one rotor part (as a CAD export with the hub fused would be)
    roots = [turb.blade_vertices[turb.triangle_blade == k].reshape(-1, 3) for k in range(3)]
    c = turb.rotor_center
    bridge = np.stack([r[np.argmin(np.linalg.norm(r - c, axis=1))] for r in roots])[None]
    _write(np.concatenate([turb.mesh.triangles, bridge]), tmp_path / "fused.stl")
    with pytest.raises(ValueError) as err:
        load_turbine_mesh(tmp_path / "fused.stl")
    msg = str(err.value)
    assert "\n" not in msg and "found 2 connected parts" in msg and "blade_faces" in msg and "up_axis" in msg
    # with the faces given, the same file loads
    m = len(turb.blade_vertices)
    assert load_turbine_mesh(tmp_path / "fused.stl", blade_faces=np.arange(m)).n_blade_triangles == m
    # only a tower
    _write(np.asarray(turb.obstacle_mesh.triangles), tmp_path / "tower.stl")
    with pytest.raises(ValueError, match="no elongated part.*blade_faces"):
        load_turbine_mesh(tmp_path / "tower.stl")


@pytest.mark.parametrize("kw,match", [
    ({"unit": "furlong"}, "unit"), ({"unit": -1.0}, "unit"), ({"up_axis": "w"}, "up_axis"),
    ({"place_on_ground": "yes"}, "place_on_ground"), ({"scale": 2.0}, "scale"),
])
def test_bad_load_options_name_the_field(turb, tmp_path, kw, match):
    path = turb.export(tmp_path / "t.stl")
    with pytest.raises(ValueError, match=match):
        load_turbine_mesh(path, **kw)
    with pytest.raises(ValueError, match="path"):
        load_turbine_mesh({"unit": "mm"})
    (tmp_path / "t.xyz").write_text("1 2 3\n")
    with pytest.raises(ValueError, match="format 'xyz'"):
        load_turbine_mesh(tmp_path / "t.xyz")


def test_env_flies_the_exported_turbine(turb, tmp_path):
    """gym.make(..., turbine_mesh=<wt-inspect plan's turbine.stl>) with the paper's turn builds the
    same mission (a mesh file is not the paper turbine to the "auto" default, which lets the planner
    choose the turns for it)."""
    import gymnasium as gym

    import wt_inspect_env  # noqa: F401 - registers the ids
    path = turb.export(tmp_path / "turbine.stl")
    env = gym.make("WindTurbineInspection-v0", turbine_mesh=str(path), rotor_turn_deg=120.0, wind="none")
    ref = gym.make("WindTurbineInspection-v0", wind="none")
    try:
        env.reset(seed=0)
        ref.reset(seed=0)
        a, b = env.unwrapped.mission, ref.unwrapped.mission
        assert a.plan.tour_length == pytest.approx(b.plan.tour_length, abs=1e-2)
        assert len(a.inspected) == len(b.inspected) and len(a.turbines) == len(b.turbines) == 2
        assert sorted(t.surface for t in a.plan.tour) == list(range(12))
        # the mirror-symmetric rotor has tours of equal length; float noise of the file's 32-bit
        # coordinates may pick another of them, so the flown path agrees to a percent only
        assert a.plan.path_length == pytest.approx(b.plan.path_length, rel=0.01)
        assert a.plan.min_clearance() >= a.plan.config.clearance
    finally:
        env.close()
        ref.close()


@pytest.mark.parametrize("spec_kw", [
    {"rotor_azimuth_deg": 60.0, "facing_deg": -30.0},            # one blade straight down, past the tower
    {"rotor_azimuth_deg": 13.0, "facing_deg": 200.0, "position": (40.0, -7.0), "blade_length": 30.0,
     "blade_width": 2.0, "tower_height": 70.0},
    {"preset": "nrel-5mw", "rotor_azimuth_deg": 90.0, "mesh_step": 2.0},   # twisted blades, nacelle
])
def test_blades_are_recognised_in_any_pose(tmp_path, spec_kw):
    t = build_turbine(TurbineSpec(**spec_kw))
    loaded = load_turbine_mesh(t.export(tmp_path / "t.stl"))
    m, c = len(t.blade_vertices), len(t.cap_vertices)
    assert loaded.n_blade_triangles == m + c                    # exactly the blades (with their caps)
    np.testing.assert_allclose(loaded.blade_vertices, np.concatenate([t.blade_vertices, t.cap_vertices]), atol=1e-3)
    assert abs(float(loaded.rotor_axis @ t.rotor_axis)) > 1 - 1e-6
    # only the centre's offset across the axis matters for turning the rotor (a twisted, cambered
    # blade's principal axis misses the centre by ~0.1 m along the rotor axis)
    off = loaded.rotor_center - t.rotor_center
    assert np.linalg.norm(off - (off @ t.rotor_axis) * t.rotor_axis) < 1e-2
    assert abs(off @ t.rotor_axis) < 0.2
    np.testing.assert_allclose(loaded.rotated(120.0).blade_vertices[:m], t.rotated(120.0).blade_vertices,
                               atol=2e-2)
