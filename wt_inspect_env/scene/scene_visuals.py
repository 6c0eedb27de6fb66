"""How the turbine looks in rendered images: textured, visual-only chunks that a camera view can cull.

Drawing only - collisions and camera rays use the collision shapes. TinyRenderer's cost grows
with every triangle it is handed, drawn or not, so the textured turbine is split into chunks (one
per grid cell of the triangle centroids) and a view shows only the chunks its frustum can reach
(:func:`show_chunks`). One home for both simulators' scenes.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import pybullet as p

from .pybullet_refs import call_releasing
from .texture import load_texture, vertex_normals

__all__ = ["CHUNK_M", "create_chunks", "load_texture", "show_chunks"]

CHUNK_M = 6.0          # grid cell [m] of the textured obstacle's drawn chunks


def create_chunks(cid: int, texture_id: int, texture: Any, v: np.ndarray, f: np.ndarray) -> dict[str, Any]:
    """Visual-only bodies drawing the mesh (vertices ``v``, faces ``f``) with ``texture`` (loaded
    as ``texture_id``), one per ``CHUNK_M`` grid cell of the triangle centroids (vertex normals
    from the whole mesh, so shading has no seams). Returns the chunks' bodies, bounding spheres
    (centres, radii) and shown flags."""
    normals, uvs = vertex_normals(v, f), texture.uvs(v)
    cell = np.floor(v[f].mean(axis=1) / CHUNK_M).astype(np.int64)
    _, group = np.unique(cell, axis=0, return_inverse=True)
    bodies, centers, radii = [], [], []
    for g in range(int(group.max()) + 1):
        tri = f[group.ravel() == g]
        used, local = np.unique(tri.ravel(), return_inverse=True)
        visual = call_releasing(p.createVisualShape, p.GEOM_MESH, vertices=v[used].tolist(), indices=local.tolist(),
                                uvs=uvs[used].tolist(), normals=normals[used].tolist(), physicsClientId=cid)
        body = p.createMultiBody(0.0, -1, baseVisualShapeIndex=visual, physicsClientId=cid)
        p.changeVisualShape(body, -1, textureUniqueId=texture_id, rgbaColor=(1, 1, 1, 1), physicsClientId=cid)
        lo, hi = v[used].min(axis=0), v[used].max(axis=0)
        bodies.append(body)
        centers.append(0.5 * (lo + hi))
        radii.append(0.5 * float(np.linalg.norm(hi - lo)))
    return {"bodies": bodies, "centers": np.array(centers), "radii": np.array(radii),
            "shown": np.ones(len(bodies), dtype=bool)}


def show_chunks(cid: int, chunks: dict[str, Any] | None, mask: Any) -> None:
    """Show the chunks where ``mask`` (a bool or (K,) bools) is true, hide the others; only the
    chunks whose state changes are touched."""
    if chunks is None:
        return
    want = np.broadcast_to(np.asarray(mask, dtype=bool), chunks["shown"].shape)
    for k in np.flatnonzero(want != chunks["shown"]).tolist():
        p.changeVisualShape(chunks["bodies"][k], -1, rgbaColor=(1, 1, 1, 1.0 if want[k] else 0.0),
                            physicsClientId=cid)
    chunks["shown"] = want.copy()
