"""Metric formulas on hand-made trajectories, and the incremental accumulator against the batch one."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.task.metrics import (
    InspectionMetrics,
    MetricAccumulator,
    MetricsConfig,
    compute_metrics,
    heading_and_distance,
)

CENTER = np.array([10.0, -5.0, 100.0])


def yaw_quat(yaw, pitch=0.0):
    """Body attitude with yaw (about z) then pitch (about body y; positive = nose down)."""
    cy, sy, cp, sp = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(pitch / 2), math.sin(pitch / 2)
    # q = q_yaw (x) q_pitch, (x, y, z, w)
    return np.array([-sy * sp, cy * sp, sy * cp, cy * cp])


def circle(radius, n=400, turns=1.0, yaw_offset=0.0, pitch=0.0, dz=0.0):
    """A drone circling CENTER at a horizontal ``radius``, nose towards the centre (+ offset);
    the inspection point is CENTER and its normal points at the drone (horizontally)."""
    ang = np.linspace(0, 2 * math.pi * turns, n, endpoint=False)
    radius = np.broadcast_to(radius, ang.shape)
    out = np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])
    pos = CENTER + radius[:, None] * out + np.array([0, 0, dz])
    quats = np.array([yaw_quat(a + math.pi + yaw_offset, pitch) for a in ang])
    points = np.tile(CENTER, (n, 1))
    t = np.arange(n) * 0.01
    return t, pos, quats, points, out


def test_circling_at_the_reference_distance_is_perfect():
    t, x, q, p, n = circle(7.0)
    m = compute_metrics(t, x, q, p, n)
    assert isinstance(m, InspectionMetrics)
    assert m.safety_sm == 1.0 and m.centering_cm == pytest.approx(1.0) and m.min_heading == pytest.approx(1.0)
    assert m.mean_distance_m == pytest.approx(7.0) and m.min_distance_m == pytest.approx(7.0)
    assert m.rms_distance_error_m == pytest.approx(0.0, abs=1e-12)
    assert m.mean_heading_error_deg == pytest.approx(0.0, abs=1e-9)
    assert m.mean_incidence_deg == pytest.approx(0.0, abs=1e-5)
    assert m.mean_orthogonal_offset_m == pytest.approx(0.0, abs=1e-9)
    # path = sum of chords of the polygon (open: n-1 chords)
    assert m.path_length_m == pytest.approx(399 * 2 * 7 * math.sin(math.pi / 400))
    assert m.flight_time_s == pytest.approx(3.99)
    assert m.mean_speed_mps == pytest.approx(m.path_length_m / 3.99)
    assert m.collisions == 0 and m.n_samples == 400 and m.n_inspecting == 400
    assert math.isnan(m.coverage) and math.isnan(m.mean_gsd_mm)


def test_known_safety_fraction_and_distance_errors():
    radius = np.where(np.arange(400) % 4 == 0, 8.5, 7.5)      # 25 % at 8.5 m (outside the 1 m margin)
    t, x, q, p, n = circle(radius)
    m = compute_metrics(t, x, q, p, n)
    assert m.safety_sm == pytest.approx(0.75)
    assert m.mean_distance_m == pytest.approx(0.25 * 8.5 + 0.75 * 7.5)
    assert m.rms_distance_error_m == pytest.approx(math.sqrt(0.25 * 1.5**2 + 0.75 * 0.5**2))
    assert m.max_distance_error_m == pytest.approx(1.5)
    assert m.min_distance_m == pytest.approx(7.5) and m.max_distance_m == pytest.approx(8.5)
    # the margin is sharp: 1 mm inside counts, 1 mm outside does not
    m = compute_metrics(*circle(np.where(np.arange(400) % 2 == 0, 8.001, 7.999)))
    assert m.safety_sm == pytest.approx(0.5)
    m = compute_metrics(t, x, q, p, n, config=MetricsConfig(safety_margin=2.0))
    assert m.safety_sm == 1.0
    m = compute_metrics(t, x, q, p, n, d_ref=np.full(400, 8.6))   # per-sample reference
    assert m.safety_sm == pytest.approx(0.25)


def test_heading_function_follows_the_paper():
    m = compute_metrics(*circle(7.0, yaw_offset=math.radians(60)))
    assert m.centering_cm == pytest.approx(0.5) and m.mean_heading_error_deg == pytest.approx(60.0)
    # pitching nose-down 30 deg: the paper's h uses the full attitude (cos 30); the gimbal camera
    # stays level and centred, so CM (the camera's heading) is 1
    m = compute_metrics(*circle(7.0, pitch=math.radians(30)))
    assert m.centering_body_cm == pytest.approx(math.cos(math.radians(30)))
    assert m.centering_cm == pytest.approx(1.0)
    assert m.mean_heading_error_deg == pytest.approx(0.0, abs=1e-9)
    # facing away
    m = compute_metrics(*circle(7.0, yaw_offset=math.pi))
    assert m.centering_cm == pytest.approx(-1.0) and m.max_heading_error_deg == pytest.approx(180.0)


def test_height_offset_shows_in_orthogonality_and_incidence_not_in_distance():
    t, x, q, p, n = circle(7.0, dz=2.0)
    m = compute_metrics(t, x, q, p, n, config=MetricsConfig(pixel_ifov_rad=1e-4))
    assert m.mean_distance_m == pytest.approx(7.0) and m.safety_sm == 1.0
    assert m.mean_orthogonal_offset_m == pytest.approx(2.0)
    assert m.mean_incidence_deg == pytest.approx(math.degrees(math.atan2(2.0, 7.0)))
    assert m.mean_gsd_mm == pytest.approx(math.hypot(7.0, 2.0) * 1e-4 * 1000)


def test_collisions_coverage_redundancy_and_inspecting_mask():
    t, x, q, p, n = circle(7.0, n=6)
    x[4:] = CENTER + np.array([3.0, 0, 0])                  # 3 m off in the last two samples
    m = compute_metrics(t, x, q, p, n, collisions=[0, 1, 1, 0, 1, 0], n_new=[3, 2, 0, 1, 0, 0],
                        n_visible=[3, 4, 4, 2, 0, 0], n_triangles=10, inspecting=[1, 1, 1, 1, 0, 0])
    assert m.collisions == 2 and m.collision_samples == 3
    assert m.coverage == pytest.approx(0.6) and m.n_seen == 6 and m.n_triangles == 10
    assert m.redundancy == pytest.approx(13 / 6) and m.mean_view_time_s == pytest.approx(13 / 6 * 0.01)
    assert m.n_inspecting == 4 and m.safety_sm == 1.0          # the off samples are not inspecting
    full = compute_metrics(t, x, q, p, n)
    assert full.safety_sm == pytest.approx(4 / 6)
    assert m.path_length_m == full.path_length_m               # path counts all samples


def test_degenerate_drone_above_point_counts_as_uncentred():
    m = compute_metrics([0.0], [CENTER + [0, 0, 5]], [[0, 0, 0, 1]], [CENTER], [[0, -1, 0]])
    assert m.centering_cm == 0.0 and m.mean_distance_m == 0.0 and m.flight_time_s == 0.0
    assert math.isnan(m.mean_speed_mps) and math.isnan(m.redundancy)


def _random_flight(rng, n):
    t = np.cumsum(rng.uniform(0.005, 0.015, n))
    x = CENTER + np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0) + [0, -7, 0]
    q = rng.normal(0, 1, (n, 4)) * [0.1, 0.1, 1, 1]
    p = CENTER + rng.normal(0, 0.5, (n, 3))
    nrm = rng.normal(0, 1, (n, 3)) + [0, -3, 0]
    col = rng.random(n) < 0.05
    new = rng.integers(0, 4, n)
    vis = new + rng.integers(0, 10, n)
    insp = rng.random(n) < 0.9
    d_ref = rng.uniform(6.5, 7.5, n)
    return t, x, q, p, nrm, col, new, vis, insp, d_ref


def _assert_identical(a: InspectionMetrics, b: InspectionMetrics):
    da, db = a.to_dict(), b.to_dict()
    assert da.keys() == db.keys()
    for k in da:
        same = (da[k] == db[k]) or (isinstance(da[k], float) and math.isnan(da[k]) and math.isnan(db[k]))
        assert same, (k, da[k], db[k])


def test_accumulator_gives_identical_numbers_to_batch():
    rng = np.random.default_rng(5)
    n = 2500
    t, x, q, p, nrm, col, new, vis, insp, d_ref = _random_flight(rng, n)
    acc = MetricAccumulator(n_triangles=5000, config=MetricsConfig(pixel_ifov_rad=1.6e-4))
    for k in range(n):
        acc.add(t[k], x[k], q[k], p[k], nrm[k], collision=bool(col[k]), n_new=int(new[k]), n_visible=int(vis[k]),
                d_ref=d_ref[k], inspecting=bool(insp[k]))
        if k in (0, 10, 1023, 1900):                        # mid-flight results
            ref = compute_metrics(t[:k + 1], x[:k + 1], q[:k + 1], p[:k + 1], nrm[:k + 1], collisions=col[:k + 1],
                                  n_new=new[:k + 1], n_visible=vis[:k + 1], d_ref=d_ref[:k + 1],
                                  inspecting=insp[:k + 1], n_triangles=5000, config=acc.config)
            _assert_identical(acc.result(), ref)
    batch = compute_metrics(t, x, q, p, nrm, collisions=col, n_new=new, n_visible=vis, d_ref=d_ref,
                            inspecting=insp, n_triangles=5000, config=acc.config)
    _assert_identical(acc.result(), batch)
    assert acc.n_samples == n and batch.collisions > 10 and 0 < batch.safety_sm < 1
    # per-step helper: same h and d as the metrics of a one-sample flight
    for k in (0, 7, 99):
        h, d = heading_and_distance(x[k], q[k], p[k])
        one = compute_metrics(t[k:k + 1], x[k:k + 1], q[k:k + 1], p[k:k + 1], nrm[k:k + 1])
        assert (h, d) == (one.centering_body_cm, one.mean_distance_m)
    # and the batch numbers agree with a plain per-sample re-derivation
    a = p - x
    d = np.hypot(a[:, 0], a[:, 1])
    assert batch.safety_sm == pytest.approx(np.mean(np.abs(d - d_ref)[insp] < 1.0), rel=1e-12)
    assert batch.mean_distance_m == pytest.approx(d[insp].mean(), rel=1e-12)
    assert batch.path_length_m == pytest.approx(np.linalg.norm(np.diff(x, axis=0), axis=1).sum(), rel=1e-12)
    assert batch.collisions == int(np.sum(col & ~np.concatenate([[False], col[:-1]])))
    acc.reset()
    assert acc.n_samples == 0 and acc.result().n_samples == 0 and math.isnan(acc.result().safety_sm)


def test_to_dict_has_the_headline_metrics():
    d = compute_metrics(*circle(7.0, n=10)).to_dict()
    for key in ("safety_sm", "coverage", "centering_cm", "mean_distance_m", "min_distance_m", "collisions",
                "path_length_m", "flight_time_s", "redundancy", "max_distance_error_m", "rms_distance_error_m",
                "mean_incidence_deg"):
        assert key in d


@pytest.mark.parametrize("kwargs, field", [({"d_ref": 0}, "d_ref"), ({"safety_margin": -1}, "safety_margin"),
                                           ({"pixel_ifov_rad": float("nan")}, "pixel_ifov_rad")])
def test_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MetricsConfig(**kwargs)


def test_bad_samples_raise_naming_the_field():
    acc = MetricAccumulator(n_triangles=10)
    ok = dict(position=[0, 0, 0], quaternion=[0, 0, 0, 1], point=[0, 7, 0], normal=[0, -1, 0])
    acc.add(0.0, *ok.values())
    for field, bad in [("position", [0, np.nan, 0]), ("position", 5.0), ("quaternion", [0, 0, 0]),
                       ("quaternion", [0, 0, 0, 0]), ("normal", [0, 0, 0]), ("point", [np.inf, 0, 0])]:
        args = dict(ok, **{field: bad})
        with pytest.raises(ValueError, match=field):
            acc.add(1.0, *args.values())
    with pytest.raises(ValueError, match="time"):
        acc.add(-1.0, *ok.values())
    with pytest.raises(ValueError, match="n_new"):
        acc.add(2.0, *ok.values(), n_new=-1)
    with pytest.raises(ValueError, match="d_ref"):
        acc.add(2.0, *ok.values(), d_ref=0.0)
    assert acc.n_samples == 1                                  # rejected samples are not recorded
    with pytest.raises(ValueError, match="n_triangles"):
        MetricAccumulator(n_triangles=0)
    with pytest.raises(ValueError, match="positions"):
        compute_metrics([0.0, 1.0], [[0, 0, 0]], [[0, 0, 0, 1]] * 2, [[0, 7, 0]] * 2, [[0, -1, 0]] * 2)
    with pytest.raises(ValueError, match="time"):
        compute_metrics([1.0, 0.0], [[0, 0, 0]] * 2, [[0, 0, 0, 1]] * 2, [[0, 7, 0]] * 2, [[0, -1, 0]] * 2)
    with pytest.raises(ValueError, match="n_visible"):
        compute_metrics([0.0, 1.0], [[0, 0, 0]] * 2, [[0, 0, 0, 1]] * 2, [[0, 7, 0]] * 2, [[0, -1, 0]] * 2,
                        n_visible=[1, 2, 3])
