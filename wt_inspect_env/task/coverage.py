"""Which blade triangles the camera sees, and the per-episode coverage tally.

A triangle counts as *seen* in a frame when all of the following hold (checked in this order, the
cheap tests first, so that the expensive ones run only on the few survivors):

1. it faces the camera and its incidence angle - between its outward normal and the ray from its
   centroid to the optical centre - is below ``max_incidence_deg``;
2. its three vertices are within ``max_range`` of the optical centre (the centroid test runs first:
   a ball is convex, so a centroid out of range means a vertex out of range);
3. its three vertices are in front of the camera and project inside the image (then so does its
   centre: the image is convex and a perspective projection maps the triangle onto a triangle);
4. it is not occluded: the segment from the optical centre to a point just in front of the
   triangle (centroid + ``occlusion_eps`` * n; optionally also its vertices, pulled 10 % towards
   the centroid so that a vertex touching another part of the mesh is not reported as hidden)
   hits nothing. The paper's code skipped this test; a blade hiding behind the hub, the tower or
   another blade must not count as inspected.

The authors' rule (the camera's ``incidence_reference="optical_axis"`` and
``range_reference="centroid"``, :class:`~wt_inspect_env.scene.camera.CameraConfig`) measures the incidence
in test 1 against the reversed optical axis instead of the ray, and in test 2 checks the centre
only; their code had no test 4 (the environment's ``occlusion=False``).

Because the target point lies in front of the triangle's own plane and the camera faces that
plane, the segment never touches the triangle itself, so the occluder can simply be the whole
turbine (blades, hub, tower).

Identity is the triangle index: :class:`TriangleVisibility` can swap in the rotated vertices after
the rotor turn (``set_mesh``) and :class:`CoverageTracker` keeps counting by index, so a triangle
seen in phase 1 stays seen in phase 2 - coverage lives in the blade-fixed frame.
"""
from __future__ import annotations

import ctypes
from typing import Protocol, runtime_checkable

import numpy as np

from ..scene.camera import GimbalCamera
from ..util.validation import check_array, check_choice, check_positive

OCCLUSION_SAMPLES = ("centroid", "vertices", "none")
_VERTEX_PULL = 0.1  # vertices sampled for occlusion are moved this share of the way to the centroid


@runtime_checkable
class Occluder(Protocol):
    """Anything that can tell whether segments from one point to many targets are blocked."""

    def occluded(self, origin: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """``bool (N,)``: True where the segment ``origin -> targets[i]`` hits something."""
        ...


class PyBulletOccluder:
    """Occlusion by PyBullet's batched ray test against whatever is in the given client.

    The simulator's client holds the turbine collision mesh (concave triangle mesh) and the drone.
    Rays start at the optical centre, which lies inside (or on) the drone's own collision shape;
    Bullet does not report a hit for a ray that starts inside a convex shape, and hits on any body
    listed in ``ignore_body_ids`` (e.g. the drone, if its shape is concave) are skipped by
    re-casting the ray from just past that hit. ``collision_filter_mask`` is passed to Bullet's
    ray test: bodies whose collision group is not in the mask are invisible to the rays (the
    simulator puts the drone in its own group, so ``sim.RAY_MASK_WITHOUT_DRONE`` skips it at no
    cost - a camera inside or on the drone's box otherwise "sees" the drone first).
    """

    def __init__(self, client_id: int, *, ignore_body_ids: tuple[int, ...] | list[int] = (),
                 num_threads: int = 1, collision_filter_mask: int = -1) -> None:
        import pybullet as p

        self._p = p
        if isinstance(client_id, bool) or not isinstance(client_id, (int, np.integer)):
            raise ValueError(f"client_id must be a PyBullet client id (int), got {client_id!r}")
        if not p.isConnected(physicsClientId=int(client_id)):
            raise ValueError(f"client_id {client_id!r} is not a connected PyBullet client")
        if isinstance(num_threads, bool) or not isinstance(num_threads, (int, np.integer)) or num_threads < 0:
            raise ValueError(f"num_threads must be a non-negative integer, got {num_threads!r}")
        self.client_id = int(client_id)
        self.ignore_body_ids = frozenset(int(b) for b in ignore_body_ids)
        self.num_threads = int(num_threads)
        self.collision_filter_mask = int(collision_filter_mask)
        self.max_batch = int(getattr(p, "MAX_RAY_INTERSECTION_BATCH_SIZE", 16384)) - 1

    def occluded(self, origin: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """For each target, whether a ray from ``origin`` hits something before it (PyBullet ray test)."""
        targets = np.asarray(targets, dtype=float).reshape(-1, 3)
        n = len(targets)
        out = np.zeros(n, dtype=bool)
        if n == 0:
            return out
        origin = np.asarray(origin, dtype=float)
        froms = np.broadcast_to(origin, targets.shape)
        for start in range(0, n, self.max_batch):
            stop = min(n, start + self.max_batch)
            res = self._p.rayTestBatch(froms[start:stop], targets[start:stop], numThreads=self.num_threads,
                                       collisionFilterMask=self.collision_filter_mask,
                                       physicsClientId=self.client_id)
            if not self.ignore_body_ids:
                out[start:stop] = [r[0] != -1 for r in res]
                continue
            for i, r in enumerate(res):
                out[start + i] = self._recast_blocked(r, targets[start + i])
        return out

    def _recast_blocked(self, hit, target: np.ndarray, max_recasts: int = 8) -> bool:
        """Follow a ray past ignored bodies; True if a non-ignored body blocks it before ``target``."""
        for _ in range(max_recasts):
            body = hit[0]
            if body == -1:
                return False
            if body not in self.ignore_body_ids:
                return True
            pos = np.asarray(hit[3])
            d = target - pos
            length = float(np.linalg.norm(d))
            if length < 1e-6:
                return False
            start = pos + d * (1e-4 / length)
            hit = self._p.rayTestBatch([start], [target], collisionFilterMask=self.collision_filter_mask,
                                       physicsClientId=self.client_id)[0]
        return hit[0] != -1 and hit[0] not in self.ignore_body_ids


class TrimeshOccluder:
    """Occlusion against a triangle mesh without PyBullet (tests, offline evaluation).

    ``trimesh``'s own ray engine needs the optional ``rtree``/``embree`` packages, which this
    project does not depend on, so the segment tests are a vectorised Moller-Trumbore over the
    mesh's triangles, pre-filtered by the triangles' bounding boxes against the segments' box.
    Accepts a ``trimesh.Trimesh`` (or anything with ``vertices`` and ``faces``) or a
    ``(F, 3, 3)`` triangle array.
    """

    def __init__(self, mesh) -> None:
        if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
            tris = np.asarray(mesh.vertices, dtype=float)[np.asarray(mesh.faces, dtype=np.int64)]
        else:
            tris = np.asarray(mesh, dtype=float)
        tris = check_array("occluder triangles", tris, (None, 3, 3))
        self.triangles = tris
        self._v0 = tris[:, 0]
        self._e1 = tris[:, 1] - tris[:, 0]
        self._e2 = tris[:, 2] - tris[:, 0]
        self._lo = tris.min(axis=1)
        self._hi = tris.max(axis=1)

    def occluded(self, origin: np.ndarray, targets: np.ndarray, *, chunk: int = 200_000) -> np.ndarray:
        """For each target, whether a triangle lies between ``origin`` and it (rays in chunks of ``chunk``)."""
        targets = np.asarray(targets, dtype=float).reshape(-1, 3)
        origin = np.asarray(origin, dtype=float)
        out = np.zeros(len(targets), dtype=bool)
        if len(targets) == 0 or len(self.triangles) == 0:
            return out
        # Broad phase: only triangles whose box overlaps the box of all the segments.
        lo = np.minimum(targets.min(axis=0), origin)
        hi = np.maximum(targets.max(axis=0), origin)
        cand = np.flatnonzero(np.all((self._hi >= lo) & (self._lo <= hi), axis=1))
        if len(cand) == 0:
            return out
        v0, e1, e2 = self._v0[cand], self._e1[cand], self._e2[cand]
        step = max(1, chunk // len(cand))
        for start in range(0, len(targets), step):
            d = targets[start:start + step] - origin                      # (R, 3): t in [0, 1]
            pvec = np.cross(d[:, None, :], e2[None, :, :])                 # (R, F, 3)
            det = np.einsum("fk,rfk->rf", e1, pvec)
            tvec = origin - v0                                             # (F, 3)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                u = np.einsum("fk,rfk->rf", tvec, pvec) * inv
                qvec = np.cross(tvec, e1)                                  # (F, 3)
                v = np.einsum("rk,fk->rf", d, qvec) * inv
                t = np.einsum("fk,fk->f", e2, qvec)[None, :] * inv
            hit = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9) & (t < 1.0 - 1e-9)
            out[start:start + step] = hit.any(axis=1)
        return out


class TriangleVisibility:
    """Visibility of a fixed set of triangles from a :class:`GimbalCamera`, with the per-mesh data
    (centroids, products used by the cull) computed once, so one frame costs a few tens of
    microseconds for ~1000 triangles.

    ``vertices`` ``(M, 3, 3)`` and outward ``normals`` ``(M, 3)`` (normalised here). After the
    rotor turn call :meth:`set_mesh` with the rotated arrays (same triangle order).
    """

    def __init__(self, camera: GimbalCamera, vertices, normals, occluder: Occluder | None = None, *,
                 occlusion_eps: float = 0.05, occlusion_samples: str = "centroid") -> None:
        if not isinstance(camera, GimbalCamera):
            raise ValueError(f"camera must be a GimbalCamera, got {type(camera).__name__}")
        if occluder is not None and not isinstance(occluder, Occluder):
            raise ValueError(f"occluder must have an occluded(origin, targets) method, got {occluder!r}")
        self.camera = camera
        self.occluder = occluder
        self.occlusion_eps = check_positive("occlusion_eps", occlusion_eps)
        self.occlusion_samples = check_choice("occlusion_samples", occlusion_samples, OCCLUSION_SAMPLES)
        self._fov_scale = np.array([camera.fx / camera.cx, camera.fy / camera.cy, 1.0])
        self.set_mesh(vertices, normals)

    @property
    def n_triangles(self) -> int:
        """Number of triangles tested."""
        return len(self.vertices)

    def set_mesh(self, vertices, normals) -> None:
        """Replace the triangle geometry (e.g. by the rotated blades); indices keep their meaning."""
        v = check_array("vertices", vertices, (None, 3, 3))
        n = check_array("normals", normals, (len(v), 3))
        norm = np.linalg.norm(n, axis=1)
        if np.any(norm < 1e-9):
            bad = int(np.flatnonzero(norm < 1e-9)[0])
            raise ValueError(f"normals must be non-zero, got normals[{bad}] = {n[bad].tolist()}")
        self.vertices = v
        self.normals = n / norm[:, None]
        self.centroids = v.mean(axis=1)
        # n.c and |c|^2 are per-mesh constants of the cull.
        self._n_dot_c = np.einsum("ij,ij->i", self.normals, self.centroids)
        self._c_sq = np.einsum("ij,ij->i", self.centroids, self.centroids)
        self._vis = None          # the compiled test's view of these arrays (built on first use)

    def visible_indices(self, origin, R) -> np.ndarray:
        """Sorted indices of the triangles seen from a camera at ``origin`` with ``R_world_from_cam``."""
        o = np.asarray(origin, dtype=float)
        idx = self.in_view_batch(o.reshape(1, 3), np.asarray(R, dtype=float).reshape(1, 3, 3))[0]
        if self.occluder is None or self.occlusion_samples == "none" or len(idx) == 0:
            return idx
        return idx[~self._occluded(o, idx)]

    def in_view_batch(self, origins: np.ndarray, Rs: np.ndarray) -> list[np.ndarray]:
        """Per camera (K of them: ``origins`` (K, 3), ``Rs`` (K, 3, 3)), the sorted indices of the
        triangles that pass every test but occlusion (see the module docstring).

        In camera coordinates with x, y scaled by the half-FOV tangents, a point in front of the
        camera projects inside the image (0 <= u <= W, 0 <= v <= H, principal point at the centre)
        exactly when max(|x'|, |y'|) <= z; no division needed. Compiled (``wt_in_view`` in
        ``world_core.c``): per camera and triangle, the cheap tests (facing, centroid range,
        incidence) first, with explicit products, so one camera's answer is the same alone or in a batch.
        """
        from ..native import world_core as wc

        o = np.ascontiguousarray(origins, dtype=float).reshape(-1, 3)
        R = np.ascontiguousarray(Rs, dtype=float).reshape(-1, 3, 3)
        k = len(o)
        if self._vis is None:
            cam, v = self.camera, wc.Visibility()
            self._c_arrays = [np.ascontiguousarray(a, dtype=float) for a in
                              (self.vertices, self.normals, self.centroids, self._n_dot_c, self._c_sq)]
            v.m = len(self.vertices)
            v.vertices, v.normals, v.centroids, v.n_dot_c, v.c_sq = (wc.addr(a) for a in self._c_arrays)
            v.fov_scale[:] = tuple(float(x) for x in self._fov_scale)
            v.max_range, v.cos_max_incidence = float(cam.max_range), float(cam.cos_max_incidence)
            v.incidence_from_axis, v.range_from_vertices = int(cam.incidence_from_axis), int(cam.range_from_vertices)
            self._vis, self._vis_ptr = v, ctypes.addressof(v)
        start = np.empty(k + 1, dtype=np.int64)
        out = np.empty(max(1, k * len(self.vertices)), dtype=np.int64)
        wc.library().wt_in_view(self._vis_ptr, k, wc.addr(o), wc.addr(R), wc.addr(start), wc.addr(out))
        return [out[start[j]:start[j + 1]] for j in range(k)]

    def occlusion_targets(self, idx: np.ndarray) -> np.ndarray:
        """Ray targets of triangles ``idx``: ``(k, 3)`` (centroid samples) or ``(k, 4, 3)``."""
        lift = self.occlusion_eps * self.normals[idx]
        c = self.centroids[idx]
        if self.occlusion_samples == "centroid":
            return c + lift
        pulled = self.vertices[idx] + _VERTEX_PULL * (c[:, None, :] - self.vertices[idx])
        return np.concatenate([(c + lift)[:, None, :], pulled + lift[:, None, :]], axis=1)

    def _occluded(self, o: np.ndarray, idx: np.ndarray) -> np.ndarray:
        targets = self.occlusion_targets(idx)
        if targets.ndim == 2:
            return self.occluder.occluded(o, targets)
        return self.occluder.occluded(o, targets.reshape(-1, 3)).reshape(-1, 4).any(axis=1)

    def visible(self, origin, R) -> np.ndarray:
        """``bool (M,)`` mask of the triangles seen in this frame."""
        mask = np.zeros(len(self.vertices), dtype=bool)
        mask[self.visible_indices(origin, R)] = True
        return mask


def visible_triangles(cam: GimbalCamera, origin, R, vertices, normals, occluder: Occluder | None = None, *,
                      occlusion_eps: float = 0.05, occlusion_samples: str = "centroid") -> np.ndarray:
    """One-shot form of :class:`TriangleVisibility`: ``bool (M,)`` mask of the triangles seen.

    For per-step use build a :class:`TriangleVisibility` once; this recomputes the mesh data.
    """
    return TriangleVisibility(cam, vertices, normals, occluder, occlusion_eps=occlusion_eps,
                              occlusion_samples=occlusion_samples).visible(origin, R)


class CoverageTracker:
    """Per-episode coverage by triangle index: how many frames saw each triangle.

    ``coverage`` is the share of triangles seen at least once; with ``areas`` given, also the
    share of blade *area* seen (``area_coverage``), which is what an inspection report quotes
    when triangles differ in size.
    """

    def __init__(self, n_triangles: int, areas=None) -> None:
        if isinstance(n_triangles, bool) or not isinstance(n_triangles, (int, np.integer)) or n_triangles < 1:
            raise ValueError(f"n_triangles must be a positive integer, got {n_triangles!r}")
        self.n_triangles = int(n_triangles)
        if areas is not None:
            areas = check_array("areas", areas, (self.n_triangles,))
            if np.any(areas < 0) or areas.sum() <= 0:
                raise ValueError("areas must be non-negative with a positive sum")
        self.areas = areas
        self.counts = np.zeros(self.n_triangles, dtype=np.int64)
        self.n_seen = 0
        self._area_seen = 0.0

    def reset(self) -> None:
        """Forget what has been seen (a new episode)."""
        self.counts[:] = 0
        self.n_seen = 0
        self._area_seen = 0.0

    def update(self, visible_mask) -> int:
        """Add one frame's ``bool (M,)`` visibility; returns how many triangles were seen first now."""
        mask = np.asarray(visible_mask)
        if mask.shape != (self.n_triangles,) or mask.dtype != np.bool_:
            raise ValueError(f"visible_mask must be a bool array of shape ({self.n_triangles},), "
                             f"got {mask.dtype} array of shape {mask.shape}")
        return self.update_indices(np.flatnonzero(mask))

    def update_indices(self, indices) -> int:
        """Same as :meth:`update` for the sorted, unique indices of the visible triangles."""
        idx = np.asarray(indices)
        if idx.ndim != 1 or (idx.size and (idx.dtype.kind not in "iu" or idx[0] < 0 or idx[-1] >= self.n_triangles)):
            raise ValueError(f"indices must be sorted triangle indices in [0, {self.n_triangles}), got {indices!r}")
        if idx.size == 0:
            return 0
        if idx.size > 1 and not np.all(idx[1:] > idx[:-1]):
            raise ValueError(f"indices must be sorted and unique, got {indices!r}")
        self.counts[idx] += 1
        new = idx[self.counts[idx] == 1]
        n_new = len(new)
        self.n_seen += n_new
        if self.areas is not None and n_new:
            self._area_seen += float(self.areas[new].sum())
        return n_new

    @property
    def seen(self) -> np.ndarray:
        """Per triangle, whether it has been seen."""
        return self.counts > 0

    @property
    def coverage(self) -> float:
        """Share of the triangles seen at least once."""
        return self.n_seen / self.n_triangles

    @property
    def area_coverage(self) -> float:
        """Share of the blade area seen at least once (NaN without triangle areas)."""
        if self.areas is None:
            return float("nan")
        return self._area_seen / float(self.areas.sum())
