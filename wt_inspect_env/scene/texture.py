"""A procedural texture for the turbine, so that camera images carry something to track.

The collision mesh is one uniform grey in PyBullet, and an image of a uniform blade tells a policy
nothing about where along the blade it is or how fast it passes. :class:`SpanTexture` paints bands
*along the span*: the texture coordinate ``u`` is the distance of a vertex from the rotor centre
(so the bands stay on the blades when the rotor turns, and rings run round the tower), cut into
bands of ``band_m`` metres, each band one of a few contrasting colours in an irregular sequence
(so neighbouring stretches differ, as the numbered span markings of real blades do), with a dark
line every ``major_every`` bands. It changes only what is drawn: rays (camera coverage) and
contacts use the collision shapes.
"""
from __future__ import annotations

import math
import os
import struct
import tempfile
from dataclasses import dataclass

import numpy as np

from ..util.validation import check_array, check_positive

# Light grey, orange, blue, dark grey: contrasting in colour and in grey level.
_PALETTE = np.array([[225, 225, 230], [235, 120, 40], [40, 90, 200], [70, 70, 75]], dtype=np.uint8)
_LINE = np.array([15, 15, 15], dtype=np.uint8)
_MAX_WIDTH = 2048


@dataclass(frozen=True)
class SpanTexture:
    """Bands along the distance from ``center`` [m] (see the module docstring); ``radius`` is the
    largest distance to paint (the turbine's farthest vertex)."""

    center: tuple[float, float, float]
    radius: float
    band_m: float = 1.0
    major_every: int = 5

    def __post_init__(self) -> None:
        c = check_array("texture center", self.center, (3,))
        object.__setattr__(self, "center", tuple(float(v) for v in c))
        check_positive("texture radius", self.radius)
        check_positive("texture band_m", self.band_m)
        if isinstance(self.major_every, bool) or not isinstance(self.major_every, int) or self.major_every < 1:
            raise ValueError(f"texture major_every must be a positive integer, got {self.major_every!r}")

    @classmethod
    def for_meshes(cls, center, meshes, **kwargs) -> "SpanTexture":
        """A texture reaching the farthest vertex of any of ``meshes`` from ``center``."""
        c = np.asarray(center, dtype=float)
        radius = max(float(np.linalg.norm(np.asarray(m.vertices) - c, axis=1).max()) for m in meshes)
        return cls(tuple(c), max(radius, 1e-3), **kwargs)

    @property
    def n_bands(self) -> int:
        """Number of colour bands along the span (at least one)."""
        return max(1, math.ceil(self.radius / self.band_m))

    def image(self) -> np.ndarray:
        """(8, W, 3) uint8: one column block per band along ``u`` (constant along ``v``)."""
        n = self.n_bands
        px = max(1, min(8, _MAX_WIDTH // n))
        k = np.arange(n)
        # Each band steps 1-3 colours on from the last (irregularly), so neighbours always differ.
        index = np.cumsum(1 + (k * k // 3) % 3) % len(_PALETTE)
        colour = _PALETTE[index]
        colour[k % self.major_every == 0] = _LINE
        row = np.repeat(colour, px, axis=0)
        return np.repeat(row[None], 8, axis=0)

    def uvs(self, vertices: np.ndarray) -> np.ndarray:
        """(N, 2) texture coordinates of ``vertices`` (N, 3): ``u`` = distance / painted length."""
        d = np.linalg.norm(np.asarray(vertices, dtype=float) - np.asarray(self.center), axis=1)
        u = np.clip(d / (self.n_bands * self.band_m), 0.0, 1.0)
        return np.stack([u, np.full_like(u, 0.5)], axis=1)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) unit vertex normals, the area-weighted mean of the adjacent faces' (for shading)."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])   # length = 2 x area
    n = np.zeros_like(v)
    for j in range(3):
        np.add.at(n, f[:, j], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 0, n / np.maximum(norm, 1e-300), np.array([0.0, 0.0, 1.0]))


def load_texture(client: int, image: np.ndarray) -> int:
    """Load an (H, W, 3) uint8 image as a PyBullet texture of ``client`` (through a temporary
    uncompressed TGA file, a format PyBullet's loader reads; the file is removed at once)."""
    import pybullet as p

    img = np.ascontiguousarray(np.asarray(image, dtype=np.uint8)[:, :, ::-1])   # TGA stores BGR
    h, w = img.shape[:2]
    header = struct.pack("<BBBHHBHHHHBB", 0, 0, 2, 0, 0, 0, 0, 0, w, h, 24, 0x20)  # top-left origin
    fd, path = tempfile.mkstemp(suffix=".tga", prefix="wt_inspect_texture_")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(header + img.tobytes())
        tex = p.loadTexture(path, physicsClientId=client)
    finally:
        os.remove(path)
    if tex < 0:  # pragma: no cover - PyBullet refused the file
        raise RuntimeError("PyBullet could not load the turbine texture")
    return tex
