"""``wt-inspect bench coverage``: per-step cost of the camera, coverage, reference and metrics.

The drone flies the ideal stand-off sweep (7 m along each inspected face's horizontal normal, level
camera aimed back at the face) over all blade surfaces of the default turbine, with seeded noise on
position (0.2 m) and roll/pitch/yaw (3 deg) so that the frames look like a real flight. Per frame
it times ``GimbalCamera.pose`` + ``TriangleVisibility.visible_indices`` (PyBullet ray occlusion
against the whole turbine) + ``CoverageTracker.update_indices``, for each occlusion mode, and also
``InspectionReference.step`` and ``MetricAccumulator.add`` + ``result().to_dict()``. Medians over
frames are printed in microseconds. Budget for the environment: ~100 us per step in total for
~1000 triangles, so that 5000 env steps/s stay possible.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time

import numpy as np

from wt_inspect_env.scene.camera import GimbalCamera
from wt_inspect_env.task.coverage import OCCLUSION_SAMPLES, CoverageTracker, PyBulletOccluder, TriangleVisibility
from wt_inspect_env.task.geometry import facing_yaw, horizontal_normal, standoff_position
from wt_inspect_env.task.metrics import MetricAccumulator
from wt_inspect_env.task.reference import InspectionReference, ReferenceConfig


def _sweep(turbine, standoff: float, spacing: float):
    """Ideal stand-off positions, yaws, inspection points and normals along every surface."""
    pos, yaw, pts, nrm = [], [], [], []
    for surf in np.unique(turbine.triangle_surface):
        sel = turbine.triangle_surface == surf
        cen = turbine.blade_centroids[sel]
        n = turbine.blade_normals[sel][0]
        radial = cen.mean(axis=0) - turbine.rotor_center
        radial -= (radial @ turbine.rotor_axis) * turbine.rotor_axis
        radial /= np.linalg.norm(radial)
        r = (cen - turbine.rotor_center) @ radial
        base = cen.mean(axis=0) - ((cen.mean(axis=0) - turbine.rotor_center) @ radial) * radial
        n_xy = horizontal_normal(n)
        if n_xy is None:   # a face without a horizontal stand-off direction is not swept
            continue
        for rr in np.arange(r.min(), r.max() + 1e-9, spacing):
            p = base + rr * radial
            pts.append(p), nrm.append(n), pos.append(standoff_position(p, n_xy, standoff))
            yaw.append(facing_yaw(n_xy))
    return np.array(pos), np.array(yaw), np.array(pts), np.array(nrm)


def _quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])


def run_bench(spacing: float = 0.02, repeats: int = 2, seed: int = 0) -> dict:
    """Run the benchmark and return its summary (see module docstring)."""
    import pybullet as p

    from wt_inspect_env.turbine.mesh import build_turbine

    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats!r}")
    if not spacing > 0:
        raise ValueError(f"spacing must be positive, got {spacing!r}")
    turbine = build_turbine()
    rng = np.random.default_rng(seed)
    pos, yaw, pts, nrm = _sweep(turbine, 7.0, spacing)
    n = len(pos)
    pos = pos + rng.normal(0.0, 0.2, pos.shape)
    ang = np.radians(3.0) * rng.normal(size=(n, 3))
    quats = np.array([_quat(a[0], a[1], y + a[2]) for a, y in zip(ang, yaw)])
    cid = p.connect(p.DIRECT)
    out: dict = {"benchmark": "coverage", "triangles": int(turbine.n_blade_triangles), "frames": n,
                 "occluder_triangles": int(len(turbine.mesh.faces)), "python": platform.python_version()}
    try:
        m = turbine.mesh
        col = p.createCollisionShape(p.GEOM_MESH, vertices=m.vertices.tolist(), indices=m.faces.ravel().tolist(),
                                     flags=p.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=cid)
        p.createMultiBody(0, col, physicsClientId=cid)
        cam = GimbalCamera()
        occluder = PyBulletOccluder(cid)
        for mode in OCCLUSION_SAMPLES:
            vis = TriangleVisibility(cam, turbine.blade_vertices, turbine.blade_normals, occluder,
                                     occlusion_samples=mode)
            tracker = CoverageTracker(turbine.n_blade_triangles)
            times, n_vis = [], 0
            for _ in range(repeats):
                tracker.reset()
                for k in range(n):
                    t0 = time.perf_counter()
                    origin, R = cam.pose(pos[k], quats[k])
                    idx = vis.visible_indices(origin, R)
                    tracker.update_indices(idx)
                    times.append(time.perf_counter() - t0)
                    n_vis += len(idx)
            out[f"frame_us_{mode}"] = 1e6 * statistics.median(times)
            out[f"frame_us_p90_{mode}"] = 1e6 * float(np.percentile(times, 90))
            out["visible_per_frame"] = n_vis / (n * repeats)
            out[f"coverage_{mode}"] = tracker.coverage
    finally:
        p.disconnect(physicsClientId=cid)

    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    ref = InspectionReference(pts, nrm, s, np.ones(n), ReferenceConfig())
    acc = MetricAccumulator(turbine.n_blade_triangles)
    ref_t, acc_t = [], []
    sample = ref.reset()
    for k in range(min(n, 20000)):
        t0 = time.perf_counter()
        sample = ref.step(0.01, pos[k])
        t1 = time.perf_counter()
        acc.add(0.01 * k, pos[k], quats[k], sample.point, sample.normal, n_new=1, n_visible=5)
        acc.result().to_dict()
        t2 = time.perf_counter()
        ref_t.append(t1 - t0), acc_t.append(t2 - t1)
    out["reference_step_us"] = 1e6 * statistics.median(ref_t)
    out["metrics_add_result_us"] = 1e6 * statistics.median(acc_t)
    out["step_total_us_centroid"] = out["frame_us_centroid"] + out["reference_step_us"] + out["metrics_add_result_us"]
    return out


def main(argv: list[str], prog: str = "wt-inspect bench coverage") -> int:
    """``wt-inspect bench coverage``: parse ``argv``, run the benchmark and print it; returns the exit code."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=0.02, help="sweep spacing [m] (0.007 = 0.7 m/s at 100 Hz)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    try:
        res = run_bench(args.spacing, args.repeats, args.seed)
    except ValueError as exc:
        ap.error(str(exc))
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"coverage bench: {res['triangles']} blade triangles, {res['occluder_triangles']} occluder triangles, "
          f"{res['frames']} frames x {args.repeats}")
    print(f"  visible/frame {res['visible_per_frame']:.1f}")
    for mode in OCCLUSION_SAMPLES:
        print(f"  frame (pose + visibility + tracker), occlusion={mode:<9} median {res[f'frame_us_{mode}']:7.1f} us"
              f"  p90 {res[f'frame_us_p90_{mode}']:7.1f} us  coverage {res[f'coverage_{mode}']:.4f}")
    print(f"  reference step              median {res['reference_step_us']:7.1f} us")
    print(f"  metrics add + result()      median {res['metrics_add_result_us']:7.1f} us")
    print(f"  total per step (centroid occlusion, camera every step): {res['step_total_us_centroid']:.1f} us")
    return 0
