"""Path: inspection segments and the transitions between them, resampled with arc length.

A path is a list of :class:`Piece` s, each a dense table of inspection point ``p``, outward unit
normal ``n`` and stand-off position ``q`` (``q = p + d_ref * offset_direction(n)``):

* ``surface``: the centre line of one surface from its entry end to its exit end: a straight line
  with a constant normal on a flat face, a polyline whose normals turn with the blade's twist on
  a curved one (interpolated between the nodes, renormalised).
* ``wrap``: from the end of one face round the blade edge to the same end of the adjacent face of
  the same blade. The point slides on the blade (across face A to the shared edge, then across
  face B to its centre line) while the normal turns along the great circle from ``n_A`` to
  ``n_B`` in proportion to the distance slid, as over a rounded edge: the normal turns smoothly
  and the stand-off swings round the edge at ``d_ref``.
* ``transit``: any other move (take-off climb, moves between blades or ends, the retreat before
  the rotor turn). The stand-off follows a collision-free route (see :mod:`.clearance`), the
  normal's yaw and elevation are interpolated along it (never through the vertical, so the
  horizontal stand-off direction stays defined) and the point is ``q - d_ref * offset(n)``: a
  virtual point that keeps the camera aimed ahead as the controllers expect.

Resampling is done per piece, uniformly in stand-off arc length with at most ``spacing`` between
samples; both ends of every piece, the via points of transit routes and the blade-edge corner of
wraps are samples (never cut), so each surface is inspected exactly from end node to end node and
the resampled path stays on the clearance-checked route. Surface and wrap pieces interpolate ``p``
(points stay on the blade) and derive ``q``;
transit pieces interpolate ``q`` (the route stays clear) and derive ``p``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .clearance import sample_polyline

TRANSIT = -1    # surface id of transition samples (wraps and transits)


def offset_direction(normals: np.ndarray, mode: str) -> np.ndarray:
    """Unit direction from inspection point to stand-off for each normal (``(K, 3)`` or ``(3,)``)."""
    n = np.asarray(normals, dtype=np.float64)
    if mode == "normal":
        return n
    h = n.copy()
    h[..., 2] = 0.0
    norm = np.linalg.norm(h, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError("a normal is vertical: the horizontal stand-off direction is undefined")
    return h / norm


def slerp(n0: np.ndarray, n1: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Great-circle interpolation between unit vectors (``tau`` in [0, 1], shape (K,))."""
    cos = float(np.clip(n0 @ n1, -1.0, 1.0))
    ang = math.acos(cos)
    tau = np.asarray(tau, dtype=np.float64)[:, None]
    if ang < 1e-9:
        return np.repeat(n0[None], len(tau), axis=0)
    return (np.sin((1 - tau) * ang) * n0 + np.sin(tau * ang) * n1) / math.sin(ang)


def interp_yaw_elevation(n0: np.ndarray, n1: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Unit normals with yaw (shortest way round) and elevation interpolated linearly in ``tau``."""
    def yaw_el(n: np.ndarray) -> tuple[float | None, float]:
        el = math.asin(float(np.clip(n[2], -1.0, 1.0)))
        yaw = math.atan2(n[1], n[0]) if math.hypot(n[0], n[1]) > 1e-9 else None
        return yaw, el

    y0, e0 = yaw_el(n0)
    y1, e1 = yaw_el(n1)
    y0 = y1 if y0 is None else y0
    y1 = y0 if y1 is None else y1
    y0 = 0.0 if y0 is None else y0
    y1 = 0.0 if y1 is None else y1
    dy = (y1 - y0 + math.pi) % (2 * math.pi) - math.pi
    tau = np.asarray(tau, dtype=np.float64)
    yaw = y0 + tau * dy
    el = e0 + tau * (e1 - e0)
    return np.stack([np.cos(el) * np.cos(yaw), np.cos(el) * np.sin(yaw), np.sin(el)], axis=1)


@dataclass
class Piece:
    """A dense, unresampled stretch of path (see module docstring)."""

    kind: str           # "surface" | "wrap" | "transit"
    surface: int        # surface id, or TRANSIT
    phase: int
    p: np.ndarray
    n: np.ndarray
    q: np.ndarray
    breaks: tuple[int, ...] = ()   # table rows that must be samples (route via points, edge corners)

    @property
    def standoff_length(self) -> float:
        """Length [m] of the piece's stand-off path ``q``."""
        return float(np.linalg.norm(np.diff(self.q, axis=0), axis=1).sum())


def surface_piece(surface_id: int, nodes: np.ndarray, normals: np.ndarray, phase: int,
                  standoff: float, mode: str) -> Piece:
    """Inspection of a centre line through ``nodes`` (in flight order) with the normal given at
    each node (constant on a flat face; turning with the twist on a parametric blade)."""
    p = np.asarray(nodes, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    return Piece("surface", surface_id, phase, p, n, p + standoff * offset_direction(n, mode))


def wrap_corner(pa: np.ndarray, na: np.ndarray, pb: np.ndarray, nb: np.ndarray) -> np.ndarray | None:
    """The point on the edge shared by face A (through ``pa``) and face B (through ``pb``) reached
    from ``pa`` by sliding within face A straight towards face B; ``None`` if there is none."""
    u = nb - (nb @ na) * na                 # direction within plane A towards plane B
    nu = np.linalg.norm(u)
    if nu < 0.5:                             # faces nearly parallel or opposite: no edge to wrap
        return None
    u /= nu
    lam = (nb @ pb - nb @ pa) / (nb @ u)
    if lam < 0:
        return None
    return pa + lam * u


def wrap_piece(pa: np.ndarray, na: np.ndarray, pb: np.ndarray, nb: np.ndarray, corner: np.ndarray,
               phase: int, standoff: float, mode: str, step: float) -> Piece:
    """Slide from ``pa`` over ``corner`` to ``pb`` with the normal turning from ``na`` to ``nb``."""
    l1, l2 = float(np.linalg.norm(corner - pa)), float(np.linalg.norm(pb - corner))
    total = l1 + l2
    ang = math.acos(float(np.clip(na @ nb, -1.0, 1.0)))
    n_samples = max(8, math.ceil((total + standoff * ang) / step))
    n1 = min(n_samples - 1, max(1, round(n_samples * l1 / total))) if total > 0 else 1
    n2 = max(1, n_samples - n1)
    leg1 = pa + np.linspace(0.0, 1.0, n1 + 1)[:, None] * (corner - pa)
    leg2 = corner + np.linspace(0.0, 1.0, n2 + 1)[1:, None] * (pb - corner)
    p = np.concatenate([leg1, leg2])
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    n = slerp(na, nb, s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(p)))
    return Piece("wrap", TRANSIT, phase, p, n, p + standoff * offset_direction(n, mode), breaks=(n1,))


def transit_piece(route: np.ndarray, n0: np.ndarray, n1: np.ndarray, phase: int, standoff: float,
                  mode: str, step: float) -> Piece:
    """Fly the stand-off along ``route`` while the normal's yaw/elevation go from ``n0`` to ``n1``."""
    parts = [sample_polyline(route[i:i + 2], step) for i in range(len(route) - 1)]
    q = np.concatenate([parts[0]] + [part[1:] for part in parts[1:]])
    breaks = tuple(np.cumsum([len(part) - 1 for part in parts])[:-1])      # the via points
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))]
    tau = s / s[-1] if s[-1] > 0 else np.zeros(len(q))
    n = interp_yaw_elevation(n0, n1, tau)
    return Piece("transit", TRANSIT, phase, q - standoff * offset_direction(n, mode), n, q,
                 breaks=tuple(int(b) for b in breaks))


@dataclass
class SampledPath:
    """The planned path resampled for flight: per sample the blade point, its normal, the stand-off
    point, the surface, the phase and the kind of piece."""
    points: np.ndarray
    normals: np.ndarray
    standoff_points: np.ndarray
    surface: np.ndarray
    phase: np.ndarray
    kind: np.ndarray          # 0 surface, 1 wrap, 2 transit


_KIND = {"surface": 0, "wrap": 1, "transit": 2}


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(x, xp, fp[:, j]) for j in range(fp.shape[1])], axis=1)


def _sample_piece(kind: str, m: int, L: float, sig: np.ndarray, p: np.ndarray, n: np.ndarray, q: np.ndarray,
                  standoff: float, mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``m + 1`` samples uniform in the table's stand-off arc length ``sig``."""
    if len(sig) == 1:
        return p[:1], n[:1], q[:1]
    g = np.linspace(0.0, L, m + 1)
    N = _interp_rows(g, sig, n)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    if kind == "transit":
        Q = _interp_rows(g, sig, q)
        return Q - standoff * offset_direction(N, mode), N, Q
    P = _interp_rows(g, sig, p)
    return P, N, P + standoff * offset_direction(N, mode)


def resample(pieces: list[Piece], spacing: float, standoff: float, mode: str) -> SampledPath:
    """Resample every piece at <= ``spacing`` of stand-off arc length and join them."""
    cols: dict[str, list] = {k: [] for k in ("p", "n", "q", "surface", "phase", "kind")}
    prev_kind = None
    split: list[Piece] = []
    for piece in pieces:      # resample between breaks so that corners are samples, not cut
        cuts = [0, *sorted(b for b in piece.breaks if 0 < b < len(piece.q) - 1), len(piece.q) - 1]
        for a, b in zip(cuts[:-1], cuts[1:]):
            split.append(Piece(piece.kind, piece.surface, piece.phase, piece.p[a:b + 1], piece.n[a:b + 1],
                               piece.q[a:b + 1]))
    for piece in split:
        ds = np.linalg.norm(np.diff(piece.q, axis=0), axis=1)
        keep = np.r_[True, ds > 0]
        q, p, n = piece.q[keep], piece.p[keep], piece.n[keep]
        sig = np.r_[0.0, np.cumsum(ds[ds > 0])]
        L = sig[-1]
        if L <= 0 and piece.kind != "surface":
            continue
        m = max(1, math.ceil(L / spacing - 1e-9)) if L > 0 else 0
        for _ in range(8):
            P, N, Q = _sample_piece(piece.kind, m, L, sig, p, n, q, standoff, mode)
            # wraps derive q from interpolated p and n, so their true steps can exceed the table's
            # chords by a fraction of a percent: refine until every step is within the spacing
            worst = float(np.linalg.norm(np.diff(Q, axis=0), axis=1).max()) if len(Q) > 1 else 0.0
            if worst <= spacing:
                break
            m = math.ceil(m * worst / spacing * 1.0001)
        if cols["q"] and len(cols["q"][-1]) and np.allclose(cols["q"][-1][-1], Q[0], atol=1e-9, rtol=0) \
                and np.allclose(cols["p"][-1][-1], P[0], atol=1e-9, rtol=0):
            # joint sample: a surface keeps its end node; otherwise the earlier piece keeps it
            if piece.kind == "surface" and prev_kind not in (None, "surface"):
                for k in cols:
                    cols[k][-1] = cols[k][-1][:-1]
            else:
                P, N, Q = P[1:], N[1:], Q[1:]
        k = len(P)
        cols["p"].append(P)
        cols["n"].append(N)
        cols["q"].append(Q)
        cols["surface"].append(np.full(k, piece.surface, dtype=np.int64))
        cols["phase"].append(np.full(k, piece.phase, dtype=np.int64))
        cols["kind"].append(np.full(k, _KIND[piece.kind], dtype=np.int64))
        prev_kind = piece.kind
    return SampledPath(points=np.concatenate(cols["p"]), normals=np.concatenate(cols["n"]),
                       standoff_points=np.concatenate(cols["q"]), surface=np.concatenate(cols["surface"]),
                       phase=np.concatenate(cols["phase"]), kind=np.concatenate(cols["kind"]))
