"""Closest points of the turbine to a few query points, fast enough for every control step.

An MPC that keeps a clearance to the turbine needs, at each control step, the nearest point of the
mesh to each stage of its predicted trajectory (the online data of a half-space constraint
``n^T (p_k - c_k) >= d_min``). :class:`MeshProximity` answers that for a fixed set of triangles:
a KD-tree on the triangle centroids gives the ``candidates`` nearest triangles of each query
point, and the exact closest point on each candidate (Ericson's region test,
:func:`~wt_inspect_env.planner.clearance.closest_points_on_triangles`) picks the nearest. The few
large triangles (centroid-to-vertex radius above three times the median) are always candidates,
so a coarse loaded tower is not missed because its centroid is far away.

:class:`TurbineProximity` is the geometry of a whole mission: one :class:`MeshProximity` per rotor
position (the environment swaps the collision mesh when the rotor turns), and which one applies.
A policy does not see the phase. It sees the mission's progress, and given where each later
phase begins on that scale (``phase_starts``, from the environment's reference) the active rotor
position follows from it exactly - the environment swaps the collision mesh at the first sample of
a phase-change hold, when the progress reaches the end of the run. Without ``phase_starts`` (a
mission alone, the PX4 geofence) it falls back to the inspection point: the next rotor position
becomes active once the point lies on its mesh (within ``on_mesh``) and off the current one (by
more than ``switch_margin``). The point alone is ambiguous on transits, whose points are
interpolated between surfaces and lie on neither mesh - a transit point nearer the next
position's blades once switched an MPC to the turned rotor in mid-phase, and the blade it then
kept clear of, 1 m from the ideal pose, held the drone until the reference stalled. The choice only
moves forward (phases are flown in order) and is reset with the policy.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy.spatial import cKDTree

from ..util.validation import check_array
from .clearance import closest_points_on_triangles


class MeshProximity:
    """Closest mesh points to query points (see the module docstring).

    ``closest(points)`` returns ``(c, d, n)``: the closest points (P, 3), the distances (P,) and
    the unit directions from the mesh to the points (P, 3) - the outward normal of the half-space
    through ``c`` that the point lies in (a point on the surface takes its triangle's normal).
    ``candidates`` bounds the work per point; the exact closest point is found whenever the
    closest triangle's centroid is among the ``candidates`` nearest (always so on meshes of
    similar-sized triangles, whose centroids are at most one triangle radius from their points).
    """

    def __init__(self, triangles: Any, candidates: int = 12) -> None:
        tris = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        if len(tris) == 0 or not np.all(np.isfinite(tris)):
            raise ValueError(f"triangles must be a non-empty finite (M, 3, 3) array, got shape {tris.shape}")
        if isinstance(candidates, bool) or not isinstance(candidates, (int, np.integer)) or candidates < 1:
            raise ValueError(f"candidates must be a positive integer, got {candidates!r}")
        cent = tris.mean(axis=1)
        rho = np.linalg.norm(tris - cent[:, None], axis=2).max(axis=1)
        small = rho <= 3.0 * float(np.median(rho))
        self._small = tris[small]
        self._rho_small = float(rho[small].max()) if small.any() else 0.0
        self._big = tris[~small]
        self._k = int(min(candidates, len(self._small)))
        self._tree = cKDTree(cent[small])
        e1 = tris[:, 1] - tris[:, 0]
        e2 = tris[:, 2] - tris[:, 0]
        nrm = np.cross(e1, e2)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        self._small_n = nrm[small]
        self._big_n = nrm[~small]
        self.n_triangles = len(tris)

    def closest(self, points: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest mesh points (P, 3), distances [m] (P,) and outward normals (P, 3) for the (P, 3) ``points``."""
        pts = check_array("points", points, (None, 3))
        P = len(pts)
        _, idx = self._tree.query(pts, k=self._k)
        idx = np.asarray(idx).reshape(P, self._k)
        t = self._small[idx.reshape(-1)]
        rep = np.repeat(pts, self._k, axis=0)
        c = closest_points_on_triangles(rep, t[:, 0], t[:, 1], t[:, 2]).reshape(P, self._k, 3)
        tn = self._small_n[idx]
        if len(self._big):
            B = self._big
            repb = np.repeat(pts, len(B), axis=0)
            Bt = np.tile(B, (P, 1, 1))
            cb = closest_points_on_triangles(repb, Bt[:, 0], Bt[:, 1], Bt[:, 2]).reshape(P, len(B), 3)
            c = np.concatenate([c, cb], axis=1)
            tn = np.concatenate([tn, np.broadcast_to(self._big_n, (P, len(B), 3))], axis=1)
        diff = pts[:, None, :] - c
        dist = np.linalg.norm(diff, axis=2)
        best = np.argmin(dist, axis=1)
        rows = np.arange(P)
        cbest, dbest, vec = c[rows, best], dist[rows, best], diff[rows, best]
        n = np.where(dbest[:, None] > 1e-9, vec / np.maximum(dbest, 1e-300)[:, None], tn[rows, best])
        return cbest, dbest, n

    def distance(self, points: Any) -> np.ndarray:
        """Distances of the points to the mesh (exact under the condition of the class docstring)."""
        return self.closest(points)[1]

    def distance_within(self, points: Any, radius: float) -> np.ndarray:
        """Distances of the points to the mesh where they are below ``radius``, else ``radius``:
        exact without the class docstring's condition, so a caller can rule contacts out with it.
        Every triangle within ``radius`` of a point has its centroid within ``radius`` plus its
        own circumradius, so all of them are tested."""
        pts = check_array("points", points, (None, 3))
        out = np.full(len(pts), float(radius))
        if len(self._small):
            for j, cand in enumerate(self._tree.query_ball_point(pts, float(radius) + self._rho_small)):
                if cand:
                    t = self._small[cand]
                    c = closest_points_on_triangles(np.broadcast_to(pts[j], (len(t), 3)), t[:, 0], t[:, 1], t[:, 2])
                    out[j] = min(out[j], float(np.sqrt(((c - pts[j]) ** 2).sum(axis=1)).min()))
        if len(self._big):
            B = self._big
            repb = np.repeat(pts, len(B), axis=0)
            Bt = np.tile(B, (len(pts), 1, 1))
            cb = closest_points_on_triangles(repb, Bt[:, 0], Bt[:, 1], Bt[:, 2]).reshape(len(pts), len(B), 3)
            out = np.minimum(out, np.linalg.norm(pts[:, None, :] - cb, axis=2).min(axis=1))
        return out


class TurbineProximity:
    """The turbine geometry of a mission for a clearance constraint: one :class:`MeshProximity`
    per rotor position, and the active one (see the module docstring).

    ``meshes``: one triangle array (M, 3, 3) or ``trimesh.Trimesh`` per rotor position, in the
    order they are flown. :meth:`update` with the current inspection point advances to the next
    position once the point lies on its mesh and off the current one (by more than
    ``switch_margin`` m); :meth:`reset` returns to the first.
    """

    def __init__(self, meshes: Sequence[Any], candidates: int = 12, switch_margin: float = 0.5,
                 phase_starts: Sequence[float] | None = None, on_mesh: float = 0.05) -> None:
        if isinstance(meshes, (str, bytes)) or not isinstance(meshes, Sequence) or not meshes:
            raise ValueError(f"meshes must be a non-empty sequence of triangle meshes, got {meshes!r}")
        self.phases = tuple(MeshProximity(getattr(m, "triangles", m), candidates) for m in meshes)
        self.switch_margin = float(switch_margin)
        self.on_mesh = float(on_mesh)
        self._starts: np.ndarray | None = None
        if phase_starts is not None:
            starts = np.asarray(phase_starts, dtype=np.float64).reshape(-1)
            if len(starts) != len(self.phases) - 1 or not np.all(np.isfinite(starts)) or np.any(np.diff(starts) < 0):
                raise ValueError(f"phase_starts must hold {len(self.phases) - 1} non-decreasing progress values "
                                 f"(one per later rotor position), got {starts.tolist()}")
            # the observation's progress is float32: compare on that grid, a hair early
            self._starts = starts.astype(np.float32).astype(np.float64) - 1e-6
        self.index = 0
        self._checked: np.ndarray | None = None   # the point of the last look-up (the point moves slowly)

    @classmethod
    def from_mission(cls, mission: Any, **options: Any) -> "TurbineProximity":
        """The collision meshes of an environment's mission (``env.mission.turbines``), i.e. the
        geometry the simulator collides the drone with in each phase."""
        return cls([t.mesh for t in mission.turbines], **options)

    @classmethod
    def from_env(cls, env: Any, **options: Any) -> "TurbineProximity":
        """:meth:`from_mission` of an environment (single or vector), with the progress at which
        each of its later phases begins, so that the active rotor position follows the progress."""
        u = getattr(env, "unwrapped", env)
        return cls.from_mission(u.mission, phase_starts=u.world.reference.phase_starts, **options)

    def reset(self) -> None:
        """Back to the first rotor position."""
        self.index = 0
        self._checked = None

    @property
    def active(self) -> MeshProximity:
        """The mesh of the active rotor position."""
        return self.phases[self.index]

    def update(self, point: Any, progress: float | None = None) -> int:
        """Advance to the rotor position of ``progress`` (with ``phase_starts``), else to the next
        one when ``point`` lies on its mesh rather than on the current one; returns the active
        index."""
        if self._starts is not None and progress is not None and math.isfinite(float(progress)):
            target = int(np.searchsorted(self._starts, float(progress), side="right"))
            self.index = max(self.index, min(target, len(self.phases) - 1))
            return self.index
        if self.index + 1 < len(self.phases):
            p = np.asarray(point, dtype=np.float64).reshape(1, 3)
            if self._checked is not None and float(np.abs(p - self._checked).max()) < 0.25 * self.switch_margin:
                return self.index          # re-checked once the point has moved a quarter of the margin
            self._checked = p
            here = self.phases[self.index].distance(p)[0]
            nxt = self.phases[self.index + 1].distance(p)[0]
            if nxt <= self.on_mesh and nxt + self.switch_margin < here:
                self.index += 1
        return self.index

    def closest(self, points: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`MeshProximity.closest` on the active rotor position's mesh."""
        return self.active.closest(points)
