"""The coverage rule's options (the authors' rule for the ``paper-faithful`` scenario) on
hand-computed single triangles.

Camera at the origin, level, looking along +y, no mount offset, the authors' 35 mm lens on the
23.5 x 15.7 mm sensor: at depth 7 m the image spans x in +-7 * 11.75 / 35 = +-2.35 m.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.scene.camera import CameraConfig, GimbalCamera
from wt_inspect_env.task.coverage import TriangleVisibility, TrimeshOccluder
from wt_inspect_env.task.env_config import EnvConfig

LOOK_PLUS_Y = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]
AUTHORS = {"focal_length_mm": 35.0, "incidence_reference": "optical_axis", "range_reference": "centroid",
           "mount_offset": (0.0, 0.0, 0.0)}


def _triangle(center, normal, size=0.2) -> tuple[np.ndarray, np.ndarray]:
    """A small triangle centred at ``center`` (its vertex mean) in the plane of ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    c = np.asarray(center, float)
    V = np.array([[c + size * e1, c - 0.5 * size * e1 + 0.8 * size * e2, c - 0.5 * size * e1 - 0.8 * size * e2]])
    return V, n[None, :]


def _seen(camera: CameraConfig, V, N, occluder=None, samples: str = "centroid") -> bool:
    cam = GimbalCamera(camera)
    o, R = cam.pose([0.0, 0.0, 0.0], LOOK_PLUS_Y)
    vis = TriangleVisibility(cam, V, N, occluder, occlusion_samples=samples)
    return bool(vis.visible(o, R)[0])


def _normal_at(angle_deg: float, towards_x: float = 1.0) -> list[float]:
    """A horizontal normal ``angle_deg`` away from -y (the reversed optical axis), turned towards +x."""
    a = math.radians(angle_deg)
    return [towards_x * math.sin(a), -math.cos(a), 0.0]


def test_optical_axis_incidence_79_counts_81_does_not():
    authors = CameraConfig(**AUTHORS)
    # on the optical axis the ray and the axis coincide: both rules agree, limit 80 deg
    for rule in (authors, CameraConfig(focal_length_mm=35.0, mount_offset=(0.0, 0.0, 0.0))):
        assert _seen(rule, *_triangle([0, 7, 0], _normal_at(79)))
        assert not _seen(rule, *_triangle([0, 7, 0], _normal_at(81)))
    # 2 m off the axis at 7 m depth the ray is atan(2/7) = 15.95 deg from the axis: a normal 70 deg
    # from -y, turned away from the camera, is 70 deg from the axis (authors: counts) and
    # 70 + 15.95 = 85.95 deg from the ray (ray rule: does not)
    V, N = _triangle([2, 7, 0], _normal_at(70))
    assert _seen(authors, V, N)
    assert not _seen(CameraConfig(focal_length_mm=35.0, mount_offset=(0.0, 0.0, 0.0)), V, N)
    # and the authors' limit is still 80 deg off the axis: 81 deg off it does not count there
    assert not _seen(authors, *_triangle([2, 7, 0], _normal_at(81, -1.0)))
    assert _seen(authors, *_triangle([2, 7, 0], _normal_at(79, -1.0)))


def test_one_vertex_just_outside_the_image_is_not_counted():
    authors = CameraConfig(**AUTHORS)
    N = np.array([[0.0, -1.0, 0.0]])
    inside = np.array([[[2.34, 7.0, 0.0], [1.5, 7.0, 0.5], [1.5, 7.0, -0.5]]])
    outside = np.array([[[2.36, 7.0, 0.0], [1.5, 7.0, 0.5], [1.5, 7.0, -0.5]]])   # centre still inside
    assert _seen(authors, inside, N)
    assert not _seen(authors, outside, N)
    # the 24 mm default lens (+-3.43 m at 7 m) sees both
    wide = CameraConfig(mount_offset=(0.0, 0.0, 0.0))
    assert _seen(wide, inside, N) and _seen(wide, outside, N)


def test_centroid_range_rule_counts_a_triangle_whose_vertex_is_beyond_10_m():
    N = np.array([[0.0, -1.0, 0.0]])
    # centre (1.4, 9.8, 0) at 9.90 m; the vertex (2.2, 9.8, 0) at 10.04 m; all inside the image
    V = np.array([[[2.2, 9.8, 0.0], [1.0, 9.8, 0.3], [1.0, 9.8, -0.3]]])
    assert np.linalg.norm(V[0].mean(axis=0)) < 10.0 < np.linalg.norm(V[0, 0])
    assert _seen(CameraConfig(**AUTHORS), V, N)
    assert not _seen(CameraConfig(**{**AUTHORS, "range_reference": "vertices"}), V, N)


def test_occluded_triangle_counts_when_occlusion_is_off():
    V, N = _triangle([0, 7, 0], [0, -1, 0])
    blocker, _ = _triangle([0, 3, 0], [0, -1, 0], size=2.0)
    occ = TrimeshOccluder(np.concatenate([V, blocker]))
    authors = CameraConfig(**AUTHORS)
    assert not _seen(authors, V, N, occ)                 # hidden behind the blocker
    assert _seen(authors, V, N, occ, samples="none")     # the occlusion test off
    assert _seen(authors, V, N, None)                    # no occluder (the env's occlusion=False)


@pytest.mark.parametrize("field, value", [("incidence_reference", "normal"), ("range_reference", "center")])
def test_rule_options_are_validated(field, value):
    with pytest.raises(ValueError, match=f"camera {field} '{value}'"):
        CameraConfig(**{field: value})
    with pytest.raises(ValueError, match=field):
        EnvConfig(camera={field: value})


def test_paper_faithful_scenario_is_the_authors_setup():
    from wt_inspect.evaluation.scenarios import env_options, paper_numbers
    cfg = EnvConfig.from_kwargs(**env_options("paper-faithful", 4.0))
    assert cfg.camera.focal_length_mm == 35.0 and cfg.camera.sensor_width_mm == 23.5
    assert (cfg.camera.incidence_reference, cfg.camera.range_reference) == ("optical_axis", "centroid")
    assert cfg.camera.max_incidence_deg == 80.0 and cfg.camera.max_range == 10.0 and cfg.occlusion is False
    assert (cfg.reference_mode, cfg.reference_speed, cfg.ctrl_hz) == ("open_loop", 0.7, 200.0)
    assert (cfg.task, cfg.standoff, cfg.safety_margin) == ("full", 7.0, 1.0)
    # the paper's numbers stand beside the authors' baselines and both VT-NMPC weight sets
    assert paper_numbers("paper-faithful", 4.0, "nmpc-authors")["coverage"] == 0.916
    assert paper_numbers("paper-faithful", 4.0, "vtnmpc-later") == paper_numbers("paper", 4.0, "vtnmpc")
