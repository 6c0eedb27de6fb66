"""What the harness measures beside the environment's metrics: clearance to the turbine, energy.

The environment's :class:`~wt_inspect_env.task.metrics.InspectionMetrics` judge the inspection: their
distances (``min_distance_m`` ...) are to the *inspection point*, the moving target on the blade
the camera should look at. That says nothing about how close the drone came to the *structure*:
passing a blade edge, the hub or the tower 2 m away while the point is 7 m off shows as "minimum
distance 6.3 m". And nothing in them prices the battery, which is why the paper plans a
distance-optimal path. The harness therefore adds, per run, from the samples it records at every
control step (row 0 = the state after ``reset``, row k = after step k):

Clearance to the turbine (``clearance_*``)
    ``clearance_k`` = Euclidean distance from the drone's centre (its position) to the nearest
    point of the turbine's collision mesh - blades, hub, nacelle, tower; not the ground - in the
    geometry the simulator collides with at that sample. The mission has one mesh per rotor
    position; the environment swaps to the next one at the first sample of a phase-change hold
    (``env._set_phase`` on the reference's ``hold_started``), so sample k uses mesh number
    ``(number of holds started at or before k)``, i.e. the count of rising edges of
    ``info["waiting_for_phase_change"]`` (:func:`geometry_index`). Distances come from the same
    :class:`~wt_inspect_env.planner.proximity.MeshProximity` the MPCs' clearance constraint uses, made
    exact (not just "exact when the nearest triangle's centroid is among the candidates") for
    every sample that can decide the minimum or the time below d_min (:func:`mesh_clearance`).

    * ``clearance_min_m``: the minimum over all samples of the flight (the approach, the
      inspection and the rotor-turn hold alike);
    * ``clearance_body_min_m``: ``clearance_min_m`` minus the radius of the sphere round the
      drone's collision box (``|collision_half_extents|``, 0.57 m for the Matrice-100-like
      drone) - a guaranteed lower bound of the box's distance to the mesh (exact only when a box
      corner points at the nearest point), cheap, and the box is what PyBullet collides;
    * ``time_below_d_min_s``: the simulated time with ``clearance < d_min``, each sample k >= 1
      counting for the step that ends at it (``t_k - t_{k-1}``);
    * ``d_min_m``: the threshold, the environment's ``d_min`` (default 3/7 d_ref, 3 m at the paper's
      7 m stand-off: :data:`~wt_inspect_env.task.env_config.D_MIN_RATIO`), which the MPCs' constraint keeps
      for the centre - so the centre's clearance is what is compared with it.

Energy (``energy_wh``, ``mean_power_w``)
    ``P_k`` = :func:`~wt_inspect_env.physics.quadrotor.electrical_power` of the four rotor thrusts at
    sample k (the simulator's lagged, saturated rotor state, times the plant's thrust factor) for
    the airframe that flies (the randomised plant, if any): momentum theory's hover induced power
    per rotor over a figure of merit and a motor + ESC efficiency, summed over the rotors.
    ``energy`` = trapezoidal integral of P over the samples' times (J -> Wh: / 3600);
    ``mean_power_w`` = energy / flight time; ``hover_power_w`` = P at m g / 4 per rotor (the
    reference a flight's mean power compares with). Path length is the environment's
    ``path_length_m`` (sum of the distances between consecutive positions).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from wt_inspect_env.physics.quadrotor import QuadrotorParams, electrical_power
from wt_inspect_env.planner.proximity import MeshProximity
from wt_inspect_env.task.env_config import D_MIN_RATIO  # noqa: F401  (re-exported: the metric's threshold ratio)

_CHUNK = 4096            # points per vectorised proximity query (bounds the temporary arrays)
_CANDIDATES = 24         # nearest triangles per point: twice the MPCs' 12, at the same cost vectorised
_STRIDE = 8              # samples between the exact queries whose values bound their neighbours'
_LIPSCHITZ_MARGIN = 1.0  # [m] beyond the radius those queries measure exactly (so they bound something)

#: keys this module adds to a run's metrics (NaN where a run file predates them)
CLEARANCE_KEYS = ("clearance_min_m", "clearance_body_min_m", "time_below_d_min_s", "d_min_m")
ENERGY_KEYS = ("energy_wh", "mean_power_w", "hover_power_w")


def geometry_index(waiting: Any, n_geometries: int) -> np.ndarray:
    """Index of the mission mesh in force at each sample: the number of phase-change holds
    started so far (rising edges of ``waiting``; a hold cannot be under way at the reset
    sample), capped at the last mesh - the rule of the environment's ``_set_phase``."""
    w = np.asarray(waiting, dtype=bool).reshape(-1)
    rising = np.concatenate([[False], w[1:] & ~w[:-1]])
    return np.minimum(np.cumsum(rising), n_geometries - 1).astype(np.int64)


def _max_triangle_radius(triangles: np.ndarray) -> float:
    """Largest distance from a triangle's centroid to its vertices: a nearest-centroid search
    misses the nearest triangle by at most this much (see :func:`mesh_clearance`)."""
    t = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    return float(np.linalg.norm(t - t.mean(axis=1, keepdims=True), axis=2).max())


def mesh_clearance(positions: Any, meshes: Sequence[Any], geometry: Any | None = None, *,
                   d_min: float = 0.0) -> np.ndarray:
    """Distance [m] of each position (N, 3) to its mesh: ``meshes`` holds triangle arrays
    (M, 3, 3) or objects with ``.triangles``, ``geometry`` (N,) the index of each sample's mesh
    (default: all the first). Non-finite positions give NaN.

    Every point gets :meth:`MeshProximity.distance` (vectorised after the flight, far cheaper per
    point than a call per control step; with 24 candidate triangles instead of the MPCs' 12, which
    costs the same vectorised and was exact on every sample of a paper
    mission slice where 12 were up to 2 cm high on 0.3 % of them). That distance ``d`` is realised by a mesh
    triangle, so it is never below the exact one, and at most the largest triangle radius ``rho``
    above it (the nearest triangle's centroid is within ``d_exact + rho``, so a missed triangle
    only means a candidate at most that far was taken). The minimum is at most ``R = max(min d,
    d_min)``, so only points that may lie closer than ``R`` matter; those are measured again with
    :meth:`MeshProximity.distance_within` (exact below its radius and several times dearer, so only
    where a lower bound does not rule them out: :func:`_exact_where_it_matters`). So the minimum
    and the samples below ``d_min`` are exact, the others exact on meshes of similar-sized
    triangles (this project's: checked against a brute force in the tests) and never below the
    truth.
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    geo = np.zeros(len(pos), dtype=np.int64) if geometry is None else np.asarray(geometry, dtype=np.int64)
    if geo.shape != (len(pos),):
        raise ValueError(f"geometry must have one entry per position ({len(pos)}), got shape {geo.shape}")
    tris = [np.asarray(getattr(m, "triangles", m), dtype=np.float64).reshape(-1, 3, 3) for m in meshes]
    if len(pos) and (geo.min() < 0 or geo.max() >= len(tris)):
        raise ValueError(f"geometry indices must lie in [0, {len(tris) - 1}], got {geo.min()}..{geo.max()}")
    out = np.full(len(pos), np.nan)
    finite = np.isfinite(pos).all(axis=1)
    for g in np.unique(geo[finite]).tolist():
        sel = np.flatnonzero(finite & (geo == g))
        prox = MeshProximity(tris[g], candidates=_CANDIDATES)
        d = np.concatenate([prox.distance(pos[sel[i:i + _CHUNK]]) for i in range(0, len(sel), _CHUNK)])
        rho = _max_triangle_radius(tris[g])
        out[sel] = _exact_where_it_matters(prox, pos[sel], d, rho, max(float(d.min()), float(d_min)) + 1e-9)
    return out


def _exact_where_it_matters(prox: MeshProximity, pos: np.ndarray, d: np.ndarray, rho: float,
                            radius: float) -> np.ndarray:
    """``d`` (upper bounds, at most ``rho`` above the truth) made exact wherever the truth can be
    below ``radius``. A lower bound of each point's distance decides which points need the exact
    (slow) query: ``d - rho``, and - the distance being 1-Lipschitz in the position - ``e_j -
    |p_i - p_j|`` from an exact value ``e_j`` at a nearby sample j. Exact values are taken at
    every :data:`_STRIDE`-th candidate first (with a wider radius, so that they bound their
    neighbours), then at the candidates those bounds do not clear; a flight that keeps several
    metres of clearance then costs about one exact query per stride instead of one per sample."""
    d = d.copy()
    cand = np.flatnonzero(d - rho < radius)
    if not len(cand):
        return d
    coarse = cand[::_STRIDE]
    wide = radius + _LIPSCHITZ_MARGIN
    e = prox.distance_within(pos[coarse], wide)             # exact below wide, else a lower bound (= wide)
    d[coarse] = np.where(e < wide, e, d[coarse])
    lower = d[cand] - rho
    k = np.searchsorted(coarse, cand)                        # coarse neighbours before and after each candidate
    for j in (np.maximum(k - 1, 0), np.minimum(k, len(coarse) - 1)):
        gap = np.linalg.norm(pos[cand] - pos[coarse[j]], axis=1)
        lower = np.maximum(lower, e[j] - gap)
    need = cand[(lower < radius) & ~np.isin(cand, coarse)]
    if len(need):
        exact = prox.distance_within(pos[need], radius)      # exact below radius, else radius
        d[need] = np.where(exact < radius, exact, d[need])
    return d


def clearance_metrics(t: Any, clearance: Any, d_min: float, body_radius: float) -> dict[str, float]:
    """``clearance_min_m``, ``clearance_body_min_m``, ``time_below_d_min_s`` and ``d_min_m`` of
    a flight's samples (see the module docstring); NaN clearances (non-finite states) are left
    out of the minimum and the time."""
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    c = np.asarray(clearance, dtype=np.float64).reshape(-1)
    if c.shape != t.shape:
        raise ValueError(f"clearance must have one entry per time ({len(t)}), got shape {c.shape}")
    ok = np.isfinite(c)
    cmin = float(c[ok].min()) if ok.any() else math.nan
    below = (c[1:] < d_min) & ok[1:]
    return {"clearance_min_m": cmin, "clearance_body_min_m": cmin - float(body_radius),
            "time_below_d_min_s": float(np.diff(t)[below].sum()) if len(t) > 1 else 0.0,
            "d_min_m": float(d_min)}


def energy_metrics(t: Any, power: Any, params: QuadrotorParams) -> dict[str, float]:
    """``energy_wh`` (trapezoidal integral of the per-sample electrical power over time),
    ``mean_power_w`` (energy / flight time) and ``hover_power_w`` of ``params``."""
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    P = np.asarray(power, dtype=np.float64).reshape(-1)
    if P.shape != t.shape:
        raise ValueError(f"power must have one entry per time ({len(t)}), got shape {P.shape}")
    ok = np.isfinite(P)
    if len(t) > 1 and ok.all():
        joules = float(np.sum(0.5 * (P[1:] + P[:-1]) * np.diff(t)))
    elif len(t) > 1:   # a non-finite last state: integrate up to the last finite sample
        last = int(np.flatnonzero(~ok)[0])
        joules = float(np.sum(0.5 * (P[1:last] + P[:last - 1]) * np.diff(t[:last]))) if last > 1 else 0.0
    else:
        joules = 0.0
    duration = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    return {"energy_wh": joules / 3600.0, "mean_power_w": joules / duration if duration > 0 else math.nan,
            "hover_power_w": float(params.hover_power)}


def rotor_power(params: QuadrotorParams, rotor_thrusts: Any) -> np.ndarray:
    """Per-sample electrical power [W] of rotor thrusts (N, 4) (:func:`electrical_power`)."""
    return np.asarray(electrical_power(params, rotor_thrusts), dtype=np.float64)
