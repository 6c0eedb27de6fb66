"""Inspection reference: timing, closed-loop waiting, stand-off speed limit, phase change."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.reference import InspectionReference, ReferenceConfig

DT = 0.01


def straight_path(length=10.0, spacing=0.05, z=100.0, normal=(0.0, -1.0, 0.0), phase=1, x0=0.0):
    x = np.arange(0.0, length + 1e-9, spacing)
    pts = np.column_stack([x0 + x, np.zeros_like(x), np.full_like(x, z)])
    nrm = np.tile(normal, (len(x), 1)).astype(float)
    return pts, nrm, x.copy(), np.full(len(x), phase)


def corner_path(spacing=0.05):
    """Along x on a face looking -y, then round a vertical edge (normal turns -y -> +x at a fixed
    point) and up along y on the face looking +x."""
    p1, n1, s1, _ = straight_path(5.0, spacing)
    angles = np.linspace(0.0, math.pi / 2, 91)[1:]
    n_turn = np.column_stack([np.sin(angles), -np.cos(angles), np.zeros_like(angles)])
    p_turn = np.tile(p1[-1], (len(angles), 1))
    y = np.arange(spacing, 5.0 + 1e-9, spacing)
    p2 = np.column_stack([np.full_like(y, p1[-1, 0]), y, np.full_like(y, p1[-1, 2])])
    n2 = np.tile([1.0, 0.0, 0.0], (len(y), 1))
    pts = np.concatenate([p1, p_turn, p2])
    nrm = np.concatenate([n1, n_turn, n2])
    s = np.concatenate([s1, np.full(len(angles), s1[-1]), s1[-1] + y])
    return pts, nrm, s, np.ones(len(pts), int)


def test_open_loop_reaches_s_equals_v_t_and_finishes():
    pts, nrm, s, ph = straight_path()
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(speed=0.7, mode="open_loop"))
    first = ref.reset()
    np.testing.assert_allclose(first.point, pts[0])
    for k in range(1, 1001):
        out = ref.step(DT)                  # no drone position needed in open loop
        assert out.s == pytest.approx(0.7 * k * DT, abs=1e-9)
        np.testing.assert_allclose(out.point, [0.7 * k * DT, 0, 100], atol=1e-9)
        np.testing.assert_allclose(out.velocity, [0.7, 0, 0], atol=1e-12)
        np.testing.assert_allclose(out.ideal_position, [0.7 * k * DT, -7.0, 100], atol=1e-9)
    assert not out.done and out.progress == pytest.approx(0.7)
    n_more = 0
    while not out.done:
        out = ref.step(DT)
        n_more += 1
    assert (1000 + n_more) * DT == pytest.approx(10 / 0.7, abs=DT)
    assert out.progress == 1.0 and out.s == pytest.approx(10.0)
    np.testing.assert_allclose(ref.step(DT).velocity, 0.0)        # stays at the end
    assert ref.nominal_duration == pytest.approx(10 / 0.7)


def test_closed_loop_with_perfect_drone_equals_open_loop():
    pts, nrm, s, ph = straight_path()
    ref_o = InspectionReference(pts, nrm, s, ph, ReferenceConfig(mode="open_loop"))
    ref_c = InspectionReference(pts, nrm, s, ph, ReferenceConfig(mode="closed_loop"))
    out_c = ref_c.reset()
    ref_o.reset()
    for _ in range(500):
        out_c = ref_c.step(DT, out_c.ideal_position)   # the drone sits exactly at the stand-off pose
        out_o = ref_o.step(DT)
        assert out_c.s == pytest.approx(out_o.s, abs=1e-12) and out_c.speed_factor == 1.0 and out_c.lag < 1e-9


def test_closed_loop_slows_waits_and_resumes():
    pts, nrm, s, ph = straight_path()
    cfg = ReferenceConfig(speed=0.7, lag_threshold=1.0, stop_threshold=2.0)
    ref = InspectionReference(pts, nrm, s, ph, cfg)
    out = ref.reset()
    drone = out.ideal_position.copy()                  # the drone hovers at the start pose
    lags, sigmas, ss = [], [], []
    for _ in range(600):
        out = ref.step(DT, drone)
        lags.append(out.lag), sigmas.append(out.speed_factor), ss.append(out.s)
    lags, sigmas, ss = map(np.array, (lags, sigmas, ss))
    # full speed until 1 m behind, then a square-root slow-down, stopped at 2 m (in finite time)
    np.testing.assert_allclose(sigmas[lags <= 1.0], 1.0)
    mid = (lags > 1.0) & (lags < 2.0)
    assert mid.any()
    np.testing.assert_allclose(sigmas[mid], np.sqrt(2.0 - lags[mid]), atol=1e-12)
    assert sigmas[-1] == 0.0 and ss[-1] == ss[-100]    # waiting
    assert ss[-1] == pytest.approx(2.0, abs=0.01)      # it can never get further than 2 m ahead
    np.testing.assert_allclose(out.velocity, 0.0)
    # the drone catches up: the point moves again
    out = ref.step(DT, out.ideal_position)
    assert out.speed_factor == 1.0 and out.s > ss[-1]
    # a drone blown sideways (not behind) also makes it wait
    sideways = out.ideal_position + np.array([0.0, -2.5, 0.0])
    s_before = ref.step(DT, sideways).s
    assert ref.step(DT, sideways).s == s_before


def test_standoff_pose_speed_is_limited_round_an_edge():
    pts, nrm, s, ph = corner_path()
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(mode="open_loop"))
    out = ref.reset()
    ideals, points, t = [out.ideal_position], [out.point], 0.0
    while not out.done:
        out = ref.step(DT)
        ideals.append(out.ideal_position), points.append(out.point)
        t += DT
    ideal_speed = np.linalg.norm(np.diff(ideals, axis=0), axis=1) / DT
    point_speed = np.linalg.norm(np.diff(points, axis=0), axis=1) / DT
    assert ideal_speed.max() <= 0.7 * 1.01 and point_speed.max() <= 0.7 + 1e-9
    quarter = 7.0 * math.pi / 2                        # the ideal pose swings round a 7 m quarter circle
    assert t == pytest.approx((10.0 + quarter) / 0.7, rel=0.01)
    # without the limit the turn takes no time and the pose jumps
    ref2 = InspectionReference(pts, nrm, s, ph, ReferenceConfig(mode="open_loop", limit_standoff_speed=False))
    out, prev, jump = ref2.reset(), None, 0.0
    while not out.done:
        prev, out = out, ref2.step(DT)
        jump = max(jump, np.linalg.norm(out.ideal_position - prev.ideal_position))
    assert jump > 5.0


def test_normals_are_interpolated_and_renormalised():
    pts = np.array([[0, 0, 0], [1, 0, 0.0]])
    nrm = np.array([[0, -1, 0], [0, 0, 1.0]])        # 90 degrees apart
    ref = InspectionReference(pts, nrm, [0.0, 1.0], [1, 1],
                              ReferenceConfig(mode="open_loop", speed=0.5, limit_standoff_speed=False))
    ref.reset()
    out = ref.step(1.0)                                # halfway
    np.testing.assert_allclose(out.point, [0.5, 0, 0])
    np.testing.assert_allclose(out.normal, [0, -1 / math.sqrt(2), 1 / math.sqrt(2)])
    # the horizontal stand-off direction of the vertical normal is taken from its neighbour
    np.testing.assert_allclose(out.ideal_position, [0.5, -7.0, 0])


def test_velocity_matches_finite_differences_on_a_tilted_path():
    t = np.linspace(0, 1, 201)
    direction = np.array([0.6, 0.0, -0.8])
    pts = 20 * t[:, None] * direction + np.array([1.0, 2.0, 90.0])
    nrm = np.tile([0.0, -1.0, 0.0], (len(t), 1))
    ref = InspectionReference(pts, nrm, 20 * t, np.ones(len(t)), ReferenceConfig(mode="open_loop"))
    prev = ref.reset()
    for _ in range(100):
        out = ref.step(DT)
        np.testing.assert_allclose((out.point - prev.point) / DT, out.velocity, atol=1e-9)
        prev = out
    np.testing.assert_allclose(out.velocity, 0.7 * direction)


@pytest.mark.parametrize("hold", [0.5, None])
def test_phase_change_holds_then_continues_with_phase_2(hold):
    p1 = straight_path(1.0, phase=1)
    p2 = straight_path(1.0, phase=2, x0=30.0, normal=(0.0, 1.0, 0.0))
    pts, nrm, s, ph = (np.concatenate([a, b]) for a, b in zip(p1, p2))
    s[len(p1[0]):] += 1.0 + 40.0
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(mode="open_loop", phase_hold_time=hold))
    out = ref.reset()
    assert ref.n_phases == 2
    starts = []
    while not out.waiting_for_phase_change:
        out = ref.step(DT)
        starts.append(out.hold_started)
        assert out.phase == 1
    assert starts.count(True) == 1 and starts[-1]      # flagged once, on the first hold sample
    assert out.time == pytest.approx(1.0 / 0.7, abs=DT)
    np.testing.assert_allclose(out.point, pts[len(p1[0]) - 1])
    np.testing.assert_allclose(out.velocity, 0.0)
    assert out.progress == pytest.approx(0.5)
    held = 0
    for _ in range(200 if hold is None else 10_000):
        out = ref.step(DT)
        if not out.waiting_for_phase_change:
            break
        held += 1
        np.testing.assert_allclose(out.point, pts[len(p1[0]) - 1])
        assert not out.hold_started
    if hold is None:
        assert held == 200                             # waits until released
        ref.release_hold()
        out = ref.step(DT)
    else:
        assert (held + 1) * DT == pytest.approx(hold, abs=1.01 * DT)
    assert out.phase_changed and out.phase == 2 and not out.waiting_for_phase_change
    np.testing.assert_allclose(out.point, pts[len(p1[0])])
    np.testing.assert_allclose(out.ideal_position, pts[len(p1[0])] + [0, 7, 0])
    out = ref.step(DT)
    assert not out.phase_changed and out.s == pytest.approx(s[len(p1[0])] + 0.7 * DT)


def test_from_plan_and_reset_restart():
    class Plan:
        points, normals, s, phase = straight_path(2.0)
        surface = np.zeros(len(points), int)
    ref = InspectionReference.from_plan(Plan, ReferenceConfig(mode="open_loop"))
    for _ in range(50):
        ref.step(DT)
    out = ref.reset()
    assert out.s == 0.0 and out.time == 0.0 and not out.done


@pytest.mark.parametrize("kwargs, field", [
    ({"speed": 0}, "speed"), ({"mode": "fast"}, "mode"), ({"lag_threshold": -1}, "lag_threshold"),
    ({"lag_threshold": 2.0, "stop_threshold": 1.0}, "stop_threshold"), ({"standoff": float("inf")}, "standoff"),
    ({"phase_hold_time": -1.0}, "phase_hold_time"), ({"limit_standoff_speed": "yes"}, "limit_standoff_speed"),
])
def test_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=field):
        ReferenceConfig(**kwargs)


def test_reference_rejects_bad_paths_and_steps():
    pts, nrm, s, ph = straight_path(1.0)
    with pytest.raises(ValueError, match="normals"):
        InspectionReference(pts, nrm[:-1], s, ph)
    bad = nrm.copy()
    bad[3] = 0.0
    with pytest.raises(ValueError, match="normals"):
        InspectionReference(pts, bad, s, ph)
    with pytest.raises(ValueError, match="non-decreasing"):
        InspectionReference(pts, nrm, s[::-1], ph)
    with pytest.raises(ValueError, match="phase"):
        InspectionReference(pts, nrm, s, ph[::-1] * np.arange(len(ph)))
    with pytest.raises(ValueError, match="points"):
        InspectionReference(np.zeros((0, 3)), np.zeros((0, 3)), [], [])
    ref = InspectionReference(pts, nrm, s, ph)
    with pytest.raises(ValueError, match="drone_position"):
        ref.step(DT)                                    # closed loop needs the drone
    with pytest.raises(ValueError, match="drone_position"):
        ref.step(DT, [0, np.nan, 0])
    with pytest.raises(ValueError, match="dt"):
        ref.step(0.0, [0, 0, 0])


def test_single_point_runs_and_zero_hold():
    pts = np.array([[0, 0, 50.0], [5, 0, 50.0], [6, 0, 50.0]])
    nrm = np.tile([0, -1.0, 0], (3, 1))
    ref = InspectionReference(pts, nrm, [0.0, 0.0, 1.0], [1, 2, 2],
                              ReferenceConfig(mode="open_loop", phase_hold_time=0.0))
    out = ref.reset()
    assert out.phase == 1 and not out.done
    out = ref.step(DT)                    # a one-point phase ends at once
    assert out.waiting_for_phase_change and out.hold_started
    out = ref.step(DT)                    # zero hold: phase 2 on the next step
    assert out.phase_changed and out.phase == 2
    np.testing.assert_allclose(out.point, [5, 0, 50])
    while not out.done:
        out = ref.step(DT)
    np.testing.assert_allclose(out.point, [6, 0, 50])
    assert out.progress == 1.0 and out.speed_factor == 0.0
