"""The compiled per-step arithmetic of the inspection world (``world_core.c``), driven with ctypes.

Three parts of every control step of every drone: the moving inspection reference
(:class:`~wt_inspect_env.task.reference.BatchedReference`), the running metrics
(:class:`~wt_inspect_env.task.metrics.BatchedMetrics`, also used for recorded flights by
:func:`~wt_inspect_env.task.metrics.compute_metrics`) and the default task's observation, reward and
termination (:class:`~wt_inspect_env.task.hooks.TaskHooks`). The Python classes keep the state in NumPy
arrays and hand their addresses to C, which loops over the drones with scalar arithmetic in a fixed
order - a drone's numbers do not depend on the batch it is in.

Why compiled: per drone and step this is a few hundred floating-point operations, which NumPy can
only batch across drones (one dispatch per operation, microseconds each, dominates at the single
environment's N = 1). Built once per machine with the C compiler the flight core and the MPCs use,
and cached in the guarded library cache (:mod:`~wt_inspect_env.util.native_cache`).
"""
from __future__ import annotations

import ctypes
import threading
from importlib import resources
from typing import Any

import numpy as np

from ..util.native_cache import load_c_source

_ABI = 3
_LOCK = threading.Lock()
_D, _P, _I = ctypes.c_double, ctypes.c_void_p, ctypes.c_int64

OBS_LAYOUT = (("position", 0, 3), ("velocity_body", 3, 6), ("quaternion", 6, 10), ("body_rates", 10, 13),
              ("point", 13, 16), ("normal", 16, 19), ("point_velocity", 19, 22), ("coverage", 22, 23),
              ("progress", 23, 24))
OBS_WIDTH = 24


class RefPath(ctypes.Structure):
    """The reference path's arrays as ``world_core.c`` reads them (mirrors its struct, field by field)."""
    _fields_ = [("n_runs", _I), ("run_start", _P), ("run_count", _P), ("run_length", _P), ("run_offset", _P),
                ("run_phase", _P), ("tau", _P), ("dtau", _P), ("geom", _P), ("dp_dtau", _P), ("normals", _P),
                ("hdir", _P), ("total_length", _D), ("speed", _D), ("stop", _D), ("inv_band", _D),
                ("standoff", _D), ("hold_limit", _D), ("closed", _I), ("reach", _P), ("lag_threshold", _D),
                ("stall_time", _D), ("stall_skip", _I), ("approach_speed", _D), ("deadline", _D)]


class RefState(ctypes.Structure):
    """The moving references' state arrays, one entry per drone (mirrors the C struct)."""
    _fields_ = [(name, _P) for name in ("run", "tau", "time", "hold_elapsed", "holding", "done", "release",
                                        "point", "normal", "velocity", "ideal", "phase", "progress", "s_done",
                                        "waiting", "hold_started", "phase_changed", "s", "speed_factor", "lag",
                                        "s_time", "stalled_for", "skipping", "stalls", "skipped", "s_stalled",
                                        "deficit", "approach_len", "approach_pts", "approach_nv")]


class Metrics(ctypes.Structure):
    """The running metrics' accumulators, one entry per drone (mirrors the C struct)."""
    _fields_ = [(name, _P) for name in ("sums", "mins", "maxs", "counts", "t_first", "t_last", "prev", "prev_col")] \
        + [("safety_margin", _D)]


class Visibility(ctypes.Structure):
    """The blade triangles and camera limits of the visibility test (mirrors the C struct)."""
    _fields_ = [("m", _I), ("vertices", _P), ("normals", _P), ("centroids", _P), ("n_dot_c", _P), ("c_sq", _P),
                ("fov_scale", _D * 3), ("max_range", _D), ("cos_max_incidence", _D), ("incidence_from_axis", _I),
                ("range_from_vertices", _I)]


class RewardWeights(ctypes.Structure):
    """The default task's reward weights (mirrors the C struct)."""
    _fields_ = [(name, _D) for name in ("coverage", "distance", "centering", "effort", "crash", "distance_scale",
                                        "dt")] + [("n_triangles", _I)]


class WorldStep(ctypes.Structure):
    """Everything one batched world step reads and writes, as addresses (mirrors the C struct)."""
    _fields_ = [("n", _I), ("path", _P), ("ref", _P), ("metrics", _P), ("weights", _P), ("state", _P),
                ("rates", _P), ("steps", _P), ("dt", _D), ("finite", _P), ("collision", _P), ("n_new", _P),
                ("n_vis", _P), ("actions", _P), ("hover", _P), ("lo", _P), ("hi", _P), ("pose_limit", _D),
                ("done_time", _P), ("end_hold", _D), ("time_limit", _D), ("n_seen", _P), ("d_ref", _D),
                ("code", _P), ("reward", _P), ("terms", _P), ("terminated", _P), ("truncated", _P),
                ("complete", _P), ("obs", _P)]


_LOADED: list[ctypes.CDLL] = []     # the process's loaded library (loading is idempotent)


def library() -> ctypes.CDLL:
    """The compiled world core (RuntimeError naming the cause when it cannot be built)."""
    if _LOADED:
        return _LOADED[0]
    with _LOCK:
        src = resources.files(__package__).joinpath("world_core.c").read_text()
        lib = load_c_source(src, "wt_world_core", "world core")
        if getattr(lib, "_wt_ready", False):
            return lib
        if lib.wt_world_abi_version() != _ABI:   # pragma: no cover - a source/wrapper mismatch
            raise RuntimeError("world core ABI mismatch")
        lib.wt_ref_sample.argtypes = [_P, _P, _I, _P]
        lib.wt_ref_step.argtypes = [_P, _P, _I, _D, _P]
        lib.wt_metrics_add.argtypes = [_P, _I, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _I]
        lib.wt_rewards.argtypes = [_P, _I, _P, _P, _P, _P, _P, _P, _P, _P, _P]
        lib.wt_terminations.argtypes = [_I, _P, _P, _P, _P, _P, _P, _D, _P]
        lib.wt_observations.argtypes = [_I, _P, _P, _P, _P, _P, _P, _P, _P, _P]
        lib.wt_body_frame.argtypes = [_I, _P, _P, _P, _P, _P, _P]
        lib.wt_in_view.argtypes = [_P, _I, _P, _P, _P, _P]
        lib.wt_gust_speeds.argtypes = [_I, _P, _P, _P, _P, _P, _P]
        lib.wt_world_advance.argtypes = [_P]
        lib.wt_world_finish.argtypes = [_P]
        for f in ("wt_ref_sample", "wt_ref_step", "wt_metrics_add", "wt_rewards", "wt_terminations",
                  "wt_observations", "wt_body_frame", "wt_in_view", "wt_gust_speeds", "wt_world_advance",
                  "wt_world_finish"):
            getattr(lib, f).restype = None
        lib._wt_ready = True
        _LOADED.append(lib)
        return lib


_CHAR = ctypes.c_char


def addr(a: np.ndarray) -> int:
    """The data address of a C-contiguous array (checked: C reads it with the row-major layout).
    Through the buffer protocol, a few times cheaper than ``a.ctypes.data`` (which the per-step
    calls would otherwise pay dozens of times); ``ctypes.data`` for what the buffer cannot give
    (read-only or empty arrays)."""
    if not a.flags.c_contiguous:
        raise ValueError("world core arrays must be C-contiguous")
    try:
        return ctypes.addressof(_CHAR.from_buffer(a))
    except (TypeError, ValueError):
        return a.ctypes.data


def c_array(a, dtype) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype`` (no copy when it already is one)."""
    return np.ascontiguousarray(a, dtype=dtype)


def reward_weights(w: Any, dt: float, n_triangles: int) -> RewardWeights:
    """The C view of a :class:`~wt_inspect_env.task.env_config.RewardConfig`."""
    return RewardWeights(coverage=w.coverage, distance=w.distance, centering=w.centering, effort=w.effort,
                         crash=w.crash, distance_scale=w.distance_scale, dt=dt, n_triangles=int(n_triangles))


def observation_dict(block: np.ndarray) -> dict[str, np.ndarray]:
    """The Dict observation entries as views of an (N, 24) float32 block."""
    return {name: block[:, a:b] for name, a, b in OBS_LAYOUT}


def observations(state: np.ndarray, rates: np.ndarray, point: np.ndarray, normal: np.ndarray,
                 point_velocity: np.ndarray, coverage: np.ndarray, progress: np.ndarray,
                 safe: np.ndarray) -> dict[str, np.ndarray]:
    """The Dict observation of N drones: views into one (N, 24) float32 block."""
    n = len(state)
    out = np.empty((n, OBS_WIDTH), dtype=np.float32)
    args = [c_array(state, np.float64), c_array(rates, np.float64), c_array(point, np.float64),
            c_array(normal, np.float64), c_array(point_velocity, np.float64), c_array(coverage, np.float64),
            c_array(progress, np.float64), c_array(safe, np.bool_)]
    library().wt_observations(n, *(addr(a) for a in args), addr(out))
    return observation_dict(out)
