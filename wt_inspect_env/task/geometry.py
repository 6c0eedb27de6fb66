"""Inspection geometry: the horizontal normal, the stand-off pose, and the paper's h and d.

One home for the quantities every layer needs - the controllers (their references and parameters),
the agents (features relative to the pose), the evaluation (recorded h and d) and the tests:

* the **horizontal normal** n_xy: the surface's outward normal with n_z dropped and renormalised
  (the paper's stand-off is horizontal); a (nearly) vertical normal - a blade tip, a top face - has
  none, so a fallback is needed: :class:`HorizontalNormal` keeps the previous one, or at the first
  step points from the inspection point towards the drone;
* the **stand-off pose**: p + d_ref n_xy at the point's height, facing the point (yaw along -n_xy);
* the paper's **heading function** h = (R e_x)_xy . a_xy / |a_xy| and **distance**
  d = |a_xy| with a = p - x_drone; :func:`camera_heading` is the same with (R e_x)_xy normalised,
  the heading of the yaw-following gimbal camera (what CM averages).

:mod:`wt_inspect_env.task.metrics` evaluates the same h and d inline in its per-sample accumulator
(mirrored operation for operation by its batched path, and cheap enough per sample); the tests hold it to
:func:`heading_and_distance`.
"""
from __future__ import annotations

import math

import numpy as np

from ..physics.dynamics import NX, yaw_to_quat
from ..util.validation import check_finite

MIN_HORIZONTAL = 1e-6   # below this |n_xy| a normal has no horizontal direction


def horizontal_normal(normal, fallback: np.ndarray | None = None) -> np.ndarray | None:
    """(n_x, n_y) of ``normal`` renormalised; ``fallback`` (returned as given) when the normal is
    (nearly) vertical and has no horizontal direction."""
    nxy = np.asarray(normal, dtype=float)[:2]
    norm = float(np.hypot(nxy[0], nxy[1]))
    if norm < MIN_HORIZONTAL:
        return fallback
    return nxy / norm


def direction_to_drone(position, point) -> np.ndarray:
    """Horizontal unit vector from the inspection point towards the drone ((1, 0) if the drone
    is right above or below it): the stand-off direction when the normal gives none."""
    away = np.asarray(position, dtype=float)[:2] - np.asarray(point, dtype=float)[:2]
    out = horizontal_normal(np.append(away, 0.0), None)
    return np.array([1.0, 0.0]) if out is None else out


class HorizontalNormal:
    """The horizontal normal of a stream of observations, with the fallback of the module
    docstring: a normal without horizontal part keeps the previous horizontal normal, or - at the
    first step of an episode - points from the inspection point towards the drone. Call
    :meth:`reset` at each episode start."""

    def __init__(self) -> None:
        self.value: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the remembered normal (a new episode)."""
        self.value = None

    def update(self, normal, position, point) -> np.ndarray:
        """The horizontal normal for this observation (remembered for the next one)."""
        fallback = self.value if self.value is not None else direction_to_drone(position, point)
        self.value = horizontal_normal(normal, fallback)
        return self.value


def facing_yaw(normal_xy) -> float:
    """The yaw that looks back at the surface: along -n_xy."""
    return math.atan2(-float(normal_xy[1]), -float(normal_xy[0]))


def standoff_position(point, normal_xy, d_ref: float) -> np.ndarray:
    """p + d_ref n_xy, at the inspection point's height."""
    n = np.asarray(normal_xy, dtype=float)
    return np.asarray(point, dtype=float) + d_ref * np.array([n[0], n[1], 0.0])


def standoff_state(point, normal, d_ref: float, velocity_body=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The stand-off pose as a model state [p, v_B, q] (level, facing the point); ValueError
    when ``normal`` has no horizontal direction or ``d_ref`` is not finite."""
    n = horizontal_normal(np.asarray(normal, dtype=float), None)
    if n is None:
        raise ValueError(f"normal must have a horizontal component, got {normal!r}")
    check_finite("d_ref", d_ref)
    x = np.empty(NX)
    x[0:3] = standoff_position(point, n, d_ref)
    x[3:6] = np.asarray(velocity_body, dtype=float)
    x[6:10] = yaw_to_quat(facing_yaw(n))
    return x


def _body_x_xy(quaternion) -> tuple[float, float]:
    """Horizontal part of the body x axis (R e_x) for a (not necessarily unit) quaternion."""
    qx, qy, qz, qw = (float(v) for v in quaternion)
    qq = qx * qx + qy * qy + qz * qz + qw * qw
    return 1.0 - 2.0 * (qy * qy + qz * qz) / qq, 2.0 * (qx * qy + qw * qz) / qq


def heading_and_distance(position, quaternion, point) -> tuple[float, float]:
    """The paper's heading function h (full attitude, as printed) and horizontal distance d for
    one sample, in plain floats (usable per control step); h = 0 when d = 0."""
    ax, ay = float(point[0]) - float(position[0]), float(point[1]) - float(position[1])
    bx0, bx1 = _body_x_xy(quaternion)
    d = math.sqrt(ax * ax + ay * ay)
    return ((bx0 * ax + bx1 * ay) / d if d > 1e-9 else 0.0), d


def camera_heading(position, quaternion, point) -> float:
    """h of the yaw-following gimbal camera: the heading with (R e_x)_xy normalised, so a tilt
    into the wind does not shrink it (CM's h; 0 when d = 0 or the body x axis is vertical)."""
    h_body, d = heading_and_distance(position, quaternion, point)
    bxy = math.hypot(*_body_x_xy(quaternion))
    return h_body / bxy if d > 1e-9 and bxy > 1e-9 else 0.0
