"""Inspection reference: timing, closed-loop waiting, stand-off speed limit, phase change."""
from __future__ import annotations

import math

import numpy as np
import pytest

from wt_inspect_env.task.reference import InspectionReference, ReferenceConfig

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
    ({"stall_time": 0.0}, "stall_time"), ({"stall_time": float("nan")}, "stall_time"),
    ({"on_stall": "wait"}, "on_stall"), ({"approach_speed": 0.0}, "approach_speed"),
    ({"approach_speed": float("inf")}, "approach_speed"),
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


# ---------------------------------------------------------------------------- stalls and clearance
def _hold_drone(ref, drone, steps):
    out = None
    for _ in range(steps):
        out = ref.step(DT, drone)
    return out


def test_a_blocked_drone_stalls_and_the_reference_moves_on_to_the_end():
    pts, nrm, s, ph = straight_path(10.0)
    cfg = ReferenceConfig(speed=0.7, lag_threshold=1.0, stop_threshold=2.0, stall_time=5.0, on_stall="skip")
    ref = InspectionReference(pts, nrm, s, ph, cfg)
    drone = ref.reset().ideal_position.copy()           # the drone never moves
    t_wait = None
    stalled_at = None
    out = ref.reset()
    for _ in range(1, 5000):
        out = ref.step(DT, drone)
        if t_wait is None and out.speed_factor < 0.1:
            t_wait = out.time                           # the point stopped waiting ~2 m ahead
        if out.stalled:
            stalled_at = out.time
            assert ref.stalls == 1 and out.speed_factor == 1.0
        if out.done:
            break
    assert out.done and ref.stalls == 1                 # one stall, then straight on to the end
    assert stalled_at == pytest.approx(t_wait + 5.0, abs=2 * DT)
    # after the stall the point moves at the nominal speed: the rest of the path at 0.7 m/s
    assert out.time == pytest.approx(stalled_at + (10.0 - 2.0) / 0.7, abs=0.05)   # it stalled 2 m ahead
    assert ref.skipped == pytest.approx(10.0 - 2.0, abs=0.05)
    ref.reset()
    assert ref.stalls == 0 and ref.skipped == 0.0


def test_with_on_stall_end_a_stall_is_counted_once_and_the_point_stays():
    pts, nrm, s, ph = straight_path(10.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(stall_time=5.0, on_stall="end"))
    drone = ref.reset().ideal_position.copy()
    flags = [ref.step(DT, drone).stalled for _ in range(1500)]
    out = ref.step(DT, drone)
    assert sum(flags) == 1 and ref.stalls == 1 and ref.skipped == 0.0       # the env ends the episode here
    assert not out.done and out.s == pytest.approx(2.0, abs=0.01)


def test_without_stall_time_a_blocked_drone_waits_for_ever():
    pts, nrm, s, ph = straight_path(10.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(stall_time=None))
    drone = ref.reset().ideal_position.copy()
    out = _hold_drone(ref, drone, 6000)                 # 60 s
    assert not out.done and ref.stalls == 0 and out.s == pytest.approx(2.0, abs=0.01)


def test_the_stall_ends_once_the_drone_is_back_and_the_closed_loop_resumes():
    pts, nrm, s, ph = straight_path(20.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(stall_time=2.0, on_stall="skip"))
    drone = ref.reset().ideal_position.copy()
    out = _hold_drone(ref, drone, 600)                  # stalls after ~2.9 + 2 s, then moves on
    assert ref.stalls == 1 and out.speed_factor == 1.0
    out = ref.step(DT, out.ideal_position)              # the drone is back on its pose: skip over
    s_back = out.s
    held = out.ideal_position.copy()
    out = _hold_drone(ref, held, 400)                   # blocked again: the closed loop waits 2 m ahead ...
    assert out.s == pytest.approx(s_back + 2.0, abs=0.02) and out.speed_factor < 0.1 and ref.stalls == 1
    out = _hold_drone(ref, held, 300)                   # ... and stalls again after 2 s of no progress
    assert ref.stalls == 2 and out.speed_factor == 1.0


def test_reach_lets_the_point_advance_where_the_clearance_keeps_the_drone_off_its_pose():
    pts, nrm, s, ph = straight_path(10.0)
    cfg = ReferenceConfig(stall_time=None)
    reach = np.full(len(pts), 1.5)                      # every ideal pose lies 1.5 m inside d_min
    ref = InspectionReference(pts, nrm, s, ph, cfg, reach=reach)
    plain = InspectionReference(pts, nrm, s, ph, cfg)
    for off, sigma in ((1.5, 1.0), (2.5, 1.0), (3.0, math.sqrt(0.5))):
        ref.reset(), plain.reset()
        a = ref.step(DT, ref.ideal_position() + [0.0, off, 0.0])   # held off the pose, outwards
        b = plain.step(DT, plain.ideal_position() + [0.0, off, 0.0])
        assert a.speed_factor == pytest.approx(sigma, abs=1e-12)
        assert b.speed_factor == pytest.approx(math.sqrt(min(1.0, max(0.0, 2.0 - off))), abs=1e-12)
    # the shortfall is interpolated between samples like the path
    reach = np.linspace(0.0, 1.0, len(pts))
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(mode="open_loop"), reach=reach)
    ref.reset()
    out = ref.step(0.5, None)
    assert ref._batch.sample.deficit[0] == pytest.approx(out.s / 10.0, abs=1e-9)
    with pytest.raises(ValueError, match="reach"):
        InspectionReference(pts, nrm, s, ph, cfg, reach=-reach - 0.1)
    with pytest.raises(ValueError, match="reach"):
        InspectionReference(pts, nrm, s, ph, cfg, reach=reach[:-1])


def test_stalls_are_per_drone_in_a_batch():
    from wt_inspect_env.task.reference import BatchedReference
    pts, nrm, s, ph = straight_path(10.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(stall_time=3.0, on_stall="skip"))
    batch = BatchedReference(ref, 3)
    for i in range(3):
        batch.reset(i)
    start = batch.sample.ideal_position[0].copy()
    for _ in range(1500):
        pos = np.stack([start, batch.sample.ideal_position[1], start])   # drone 1 keeps up
        batch.step(DT, pos)
    single = InspectionReference(pts, nrm, s, ph, ReferenceConfig(stall_time=3.0, on_stall="skip"))
    single.reset()
    _hold_drone(single, start, 1500)
    assert batch.stalls.tolist() == [1, 0, 1] and single.stalls == 1
    assert batch.skipped[0] == single.skipped and batch.sample.s[0] == single._batch.sample.s[0]


# ------------------------------------------------------------------ approach from a far start
def test_the_approach_moves_the_pose_from_the_start_to_the_path_at_its_speed():
    """A drone that tracks its ideal pose exactly: the pose runs the straight segment from the start
    to the path's first pose at approach_speed (length / speed seconds), the point d_ref from it
    along the first normal, progress 0 - then the path proper at the nominal speed."""
    pts, nrm, s, ph = straight_path(10.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(approach_speed=4.0))
    first = ref.reset()
    start = first.ideal_position + np.array([0.0, -15.0, 20.0])          # |offset| = 25 m
    smp = ref.approach(start)
    assert ref.approaching and smp.progress == 0.0
    np.testing.assert_allclose(smp.ideal_position, start, atol=1e-12)
    np.testing.assert_allclose(smp.point, start + (first.point - first.ideal_position), atol=1e-12)
    np.testing.assert_array_equal(smp.normal, first.normal)
    direction = (first.ideal_position - start) / 25.0
    x, steps = start.copy(), 0
    while ref.approaching:
        prev = x
        smp = ref.step(DT, x)
        x = smp.ideal_position.copy()
        steps += 1
        assert smp.progress == 0.0 and smp.s == 0.0
        # on the segment, moving along it at the approach speed
        np.testing.assert_allclose(np.cross(x - start, direction), 0.0, atol=1e-9)
        if ref.approaching:
            assert np.linalg.norm(x - prev) == pytest.approx(4.0 * DT, rel=1e-9)
            np.testing.assert_allclose(smp.velocity, 4.0 * direction, rtol=1e-12)
            np.testing.assert_allclose(smp.point, x + (first.point - first.ideal_position), atol=1e-9)
    assert abs(steps - 25.0 / (4.0 * DT)) <= 1          # 625 steps, up to the rounding of tau
    np.testing.assert_allclose(x, first.ideal_position, atol=1e-12)
    smp = ref.step(DT, x)                                  # the path proper: nominal speed
    assert smp.s == pytest.approx(0.7 * DT) and np.linalg.norm(smp.velocity) == pytest.approx(0.7)


def test_the_approach_waits_for_a_lagging_drone_and_is_skipped_when_not_needed():
    pts, nrm, s, ph = straight_path(10.0)
    cfg = ReferenceConfig(approach_speed=4.0, stall_time=None)
    ref = InspectionReference(pts, nrm, s, ph, cfg)
    first = ref.reset()
    start = first.ideal_position + np.array([0.0, -30.0, 0.0])
    ref.approach(start)
    for _ in range(500):                                   # the drone stays at its start
        smp = ref.step(DT, start)
    lead = np.linalg.norm(smp.ideal_position - start)
    assert cfg.stop_threshold - 0.05 <= lead <= cfg.stop_threshold + 4.0 * DT and smp.speed_factor == 0.0
    # within stop_threshold of the first pose, after a start part-way along, or without a speed: no approach
    ref.reset()
    assert not ref.approach(first.ideal_position + [0.0, -1.9, 0.0]).progress and not ref.approaching
    ref.reset(0.5)
    ref.approach(start)
    assert not ref.approaching
    plain = InspectionReference(pts, nrm, s, ph)
    plain.reset()
    np.testing.assert_array_equal(plain.approach(start).ideal_position, first.ideal_position)
    with pytest.raises(ValueError, match="start_position"):
        ref.approach([0.0, 1.0])


def test_drone_i_of_a_batch_approaches_like_a_single_drone():
    from wt_inspect_env.task.reference import BatchedReference
    pts, nrm, s, ph = straight_path(10.0)
    cfg = ReferenceConfig(approach_speed=3.0)
    ref = InspectionReference(pts, nrm, s, ph, cfg)
    batch = BatchedReference(ref, 3)
    starts = [np.array([5.0, -20.0, 110.0]), np.array([0.0, -7.5, 100.0]), np.array([-9.0, -3.0, 95.0])]
    singles = []
    for i, st in enumerate(starts):
        batch.reset(i)
        batch.approach(i, st)
        one = InspectionReference(pts, nrm, s, ph, cfg)
        one.reset()
        one.approach(st)
        singles.append(one)
    assert batch.approaching.tolist() == [True, False, True]
    for k in range(900):
        pos = batch.sample.ideal_position + 0.3 * np.sin(0.01 * k)   # a drone near its pose
        got = batch.step(DT, pos.copy())
        for i, one in enumerate(singles):
            want = one.step(DT, pos[i])
            np.testing.assert_array_equal(got.ideal_position[i], want.ideal_position)
            np.testing.assert_array_equal(got.velocity[i], want.velocity)


def test_the_approach_follows_a_routed_polyline_at_its_speed():
    """With a router the ideal pose runs the router's polyline (start, via points, first pose) at
    approach_speed, turning at each via point, and the path proper starts at its end."""
    pts, nrm, s, ph = straight_path(10.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(approach_speed=4.0))
    first = ref.reset()
    start = first.ideal_position + np.array([0.0, -12.0, 0.0])
    via = [start + [0.0, 0.0, 9.0], first.ideal_position + [0.0, 0.0, 9.0]]
    route = np.stack([start, *via, first.ideal_position])           # 9 + 12 + 9 = 30 m
    ref.approach(start, lambda a, b: route)
    x, steps, seen = start.copy(), 0, []
    while ref.approaching:
        smp = ref.step(DT, x)
        x = smp.ideal_position.copy()
        seen.append(x)
        steps += 1
    assert abs(steps - 30.0 / (4.0 * DT)) <= 1
    seen = np.array(seen)
    # every pose lies on one of the three legs
    d = np.min([np.linalg.norm(np.cross(seen - a, (b - a) / np.linalg.norm(b - a)), axis=1)
                + np.maximum(0, -(seen - a) @ (b - a)) + np.maximum(0, (seen - b) @ (b - a))
                for a, b in zip(route[:-1], route[1:])], axis=0)
    assert d.max() < 1e-9
    assert seen[:, 2].max() == pytest.approx(via[0][2], abs=4.0 * DT)   # it went over, not through
    np.testing.assert_allclose(x, first.ideal_position, atol=1e-12)
    ref.reset()
    with pytest.raises(ValueError, match="approach route"):
        ref.approach(start, lambda a, b: np.stack([a, a + 1.0]))     # does not end at the first pose


def _lagging_drone_run(deadline):
    """A drone that trails its ideal pose by 1.5 m (between the lag and stop thresholds: the point
    moves at sqrt(0.5) of the nominal speed) along a 10 m path at 0.7 m/s (14.3 s nominal)."""
    pts, nrm, s, ph = straight_path(10.0)
    cfg = ReferenceConfig(speed=0.7, lag_threshold=1.0, stop_threshold=2.0, stall_time=5.0, on_stall="skip")
    ref = InspectionReference(pts, nrm, s, ph, cfg)
    ref.set_deadline(deadline)
    out = ref.reset()
    paced_at, pacing = None, False
    for _ in range(5000):
        out = ref.step(DT, out.ideal_position + np.array([0.0, 0.0, 1.5]))
        if out.stalled:
            paced_at = out.time
        pacing |= ref.pacing
        if out.done:
            break
    return ref, out, paced_at if pacing else None


def test_a_point_behind_the_deadline_keeps_the_nominal_speed_to_the_end():
    """Without a deadline the trailing drone's point takes 10 / (0.7 sqrt(0.5)) = 20.2 s and never
    stalls (it moves); with a 16 s deadline it stalls once when the rest of the path at 0.7 m/s
    just fits, then keeps that speed and reaches the end by the deadline, the path passed while
    the drone trailed counted as skipped."""
    ref, out, paced_at = _lagging_drone_run(None)
    assert out.done and ref.stalls == 0 and paced_at is None and ref.skipped == 0.0
    assert out.time == pytest.approx(10.0 / (0.7 * math.sqrt(0.5)), abs=0.2)
    ref, out, paced_at = _lagging_drone_run(16.0)
    assert out.done and ref.stalls == 1 and paced_at is not None
    assert out.time <= 16.0 + 2 * DT and out.time == pytest.approx(16.0, abs=0.05)
    # behind from the moment the rest at full speed just fits: t + (10 - s) / 0.7 = 16
    s_paced = 0.7 * math.sqrt(0.5) * paced_at
    assert paced_at + (10.0 - s_paced) / 0.7 == pytest.approx(16.0, abs=0.05)
    assert ref.skipped == pytest.approx(10.0 - s_paced, abs=0.05)
    ref.reset()
    assert ref.stalls == 0 and not ref.pacing


def test_a_deadline_must_be_positive():
    pts, nrm, s, ph = straight_path(10.0)
    ref = InspectionReference(pts, nrm, s, ph, ReferenceConfig(on_stall="skip"))
    with pytest.raises(ValueError, match="deadline"):
        ref.set_deadline(-1.0)
