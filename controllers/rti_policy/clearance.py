"""The clearance constraint every MPC on the base can keep (and the safety filter builds on).

Clearance. Given the turbine (``obstacles``, a :class:`~wt_inspect_env.planner.proximity.TurbineProximity`;
the registered factories pass the environment's mission geometry), every MPC on this base keeps a
minimum distance ``d_min`` to the mesh (default 3/7 d_ref: 3 m at the paper's 7 m stand-off). At
each step the nearest mesh point c_k and the outward direction n_k are found for stages of the
predicted trajectory (the warm-started plan; stage 0 the measured position) and passed as
stage-wise parameters of the half-space constraint

    n_k^T (p_k - c_k) - max(0, -n_k^T v_k)^2 / (2 a_brake) + s_k >= d_min + back-off,

with cost l2 s_k^2 / 2 (+ l1 s_k with s_k >= 0 when ``clearance_l1`` > 0) per stage. The braking
term makes the constraint see the stopping
distance at the approach speed: the 0.3 s horizons of the VT-NMPC and the NMPC are shorter than a
stop from a fast approach, so a position-only constraint would only appear once braking is too late.
A half-space through the closest point of a convex part of the mesh contains none of that part, so
p_k in it is at least d_min from that part. The slack s_k (an extra input priced in the
least-squares cost; the command is the inputs without it) keeps the QP feasible when the measured
state is already inside. The default prices it with L1 and L2 (``clearance_l1`` = ``clearance_l2``
= 1e3, the slack bounded below by 0): the L1 price makes the constraint exact whenever its
multiplier is below it, and the small L2 price keeps the QP well scaled. A pure L2 slack
(``clearance_l1=0``: unbounded, violated by multiplier / l2, so l2 must be large) needs no active
slack bound, about one interior-point iteration fewer, but with l2 = 1e6 the QPs of fast approaches
from far starts were so badly conditioned that HPIPM stopped at its iteration limit or its minimum
step (``wt-inspect campaign``; results/campaign has the counts).
``clearance=False`` or no ``obstacles`` builds the OCP without any of it, exactly
as before.
"""
from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import quat_to_rotmat
from wt_inspect_env.physics.quadrotor import GRAVITY
from wt_inspect_env.planner.proximity import TurbineProximity

from ..rti import OCP
from .config import MPCConfig

N_CLEARANCE_PARAMS = 4        # per stage: outward direction n (3), b = n^T c + d_min
SLACK_UPPER = 1e3             # [m] finite upper bound of the clearance slack (HPIPM bounds every input)
BRAKE_FLOOR = 0.25            # a disturbance leaves at least this share of clearance_brake to brake with


def clearance_ocp(ocp: OCP, config: MPCConfig, half_spaces: int = 1, disturbance: slice | None = None,
                  drag: np.ndarray | None = None) -> OCP:
    """``ocp`` with the soft clearance constraint of the module docstring: one slack input
    appended (within +-SLACK_UPPER, or [0, SLACK_UPPER] with an L1 price; fallback 0), its residual
    ``s + l1 / l2`` appended to the stage residual (weight ``l2``: cost l2 s^2 / 2 + l1 s + const;
    l1, l2 = :attr:`MPCConfig.clearance_prices`),
    and ``half_spaces`` path constraints (each a half-space with its stopping distance, all relaxed
    by the one slack) on stage parameters appended to the OCP's own: [n_j (3), b_j] per half-space.
    The MPCs keep one (the nearest surface); the safety filter three (see
    :mod:`controllers.safety_filter`). ``disturbance``: where the OCP's own parameters hold a
    world-frame disturbance acceleration (an observer's estimate) that the stopping distance then
    accounts for (:func:`_half_space`); None: none (the MPCs). ``drag``: the model's linear body
    drag per unit mass [1/s] per body axis, which then helps the braking (:func:`_half_space`);
    None: the model has none (the MPCs). The first 10 states must be the drone's [p, v_B, q]
    (augmented states keep them first)."""
    if ocp.nh:
        raise ValueError(f"the clearance constraint cannot be added to OCP {ocp.name!r}: it already has "
                         f"{ocp.nh} path constraints")
    if isinstance(half_spaces, bool) or not isinstance(half_spaces, int) or half_spaces < 1:
        raise ValueError(f"half_spaces must be an int >= 1, got {half_spaces!r}")
    if drag is not None:
        drag = np.asarray(drag, dtype=np.float64)
        if drag.shape != (3,) or not np.all(np.isfinite(drag)) or np.any(drag < 0.0):
            raise ValueError(f"drag must be 3 finite numbers >= 0 [1/s] (body x, y, z), got {drag!r}")
    nx, nu, npar = ocp.nx, ocp.nu, ocp.np
    x = ca.SX.sym("x", nx)
    u = ca.SX.sym("u", nu + 1)
    p = ca.SX.sym("p", npar + N_CLEARANCE_PARAMS * half_spaces)
    uc, slack, pc = u[:nu], u[nu], p[:npar]
    name = f"{ocp.name}_clr" if half_spaces == 1 else f"{ocp.name}_clr{half_spaces}"
    dyn = ca.Function(f"{name}_F", [x, u, p], [ocp.dynamics(x, uc, pc)], ["x", "u", "p"], ["x_next"])
    l1, l2 = config.clearance_prices
    offset = l1 / l2
    stage = ca.Function(f"{name}_r", [x, u, p], [ca.vertcat(ocp.stage_residual(x, uc, pc), slack + offset)],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function(f"{name}_rN", [x, p], [ocp.terminal_residual(x, pc)], ["x", "p"], ["rN"])
    R = quat_to_rotmat(x[6:10])
    a_ext = None if disturbance is None else pc[disturbance]
    rows = []
    for j in range(half_spaces):
        o = npar + N_CLEARANCE_PARAMS * j
        rows.append(_half_space(p[o:o + 3], p[o + 3], x, uc, R, config, a_ext, drag) + slack)
    path = ca.Function(f"{name}_h", [x, u, p], [ca.vertcat(*rows)], ["x", "u", "p"], ["h"])
    return OCP(name=name, dynamics=dyn, stage_residual=stage, terminal_residual=terminal, horizon=ocp.horizon,
               dt=ocp.dt, u_lower=np.append(ocp.u_lower, 0.0 if l1 > 0 else -SLACK_UPPER),
               u_upper=np.append(ocp.u_upper, SLACK_UPPER),
               fallback_input=np.append(ocp.fallback_input, 0.0), x_lower=ocp.x_lower, x_upper=ocp.x_upper,
               path_constraint=path, h_lower=np.zeros(half_spaces), h_upper=np.full(half_spaces, np.inf))


def _half_space(n: ca.SX, b: ca.SX, x: ca.SX, uc: ca.SX, R: ca.SX, config: MPCConfig,
                a_ext: ca.SX | None = None, drag: np.ndarray | None = None) -> ca.SX:
    """n^T p - b minus the distance needed to stop along -n (the module docstring's constraint,
    without the slack): >= 0 keeps the drone, and its stopping point, in the half-space. With a
    disturbance acceleration ``a_ext`` (world), the part pushing towards the half-space's boundary
    is taken off the braking deceleration (down to BRAKE_FLOOR of it: the observer is bounded,
    and the drone can always tilt further) and added to the acceleration of the reaction time.
    With the model's linear ``drag``, the drag of the drone's own speed is part of the reaction
    time's acceleration and helps the braking (:func:`drag_along`, :func:`stopping_distance`)."""
    v_n = ca.dot(n, R @ x[3:6])          # velocity along the outward direction
    approach = ca.fmax(0.0, -v_n)
    brake = config.clearance_brake
    if a_ext is not None:
        brake = brake - ca.fmin(ca.fmax(0.0, -ca.dot(n, a_ext)), (1.0 - BRAKE_FLOOR) * brake)
    k = 0.0 if drag is None else drag_along(n, config.clearance_brake, drag)
    stop = stopping_distance(approach, brake, k)
    t_r = config.clearance_reaction
    if t_r > 0.0:
        # for t_r the drone keeps its present acceleration (thrust along body z, gravity, the
        # model's drag) - a drone tilted towards the structure gains speed while it turns round
        # - then brakes
        a_n = ca.dot(n, R[:, 2]) * uc[3] / config.params.mass - GRAVITY * n[2]
        if a_ext is not None:
            a_n = a_n + ca.dot(n, a_ext)
        if drag is not None:
            a_n = a_n - ca.dot(n, R @ (ca.DM(drag) * x[3:6]))
        reach = ca.fmax(0.0, -(v_n * t_r + 0.5 * a_n * t_r ** 2))
        speed = ca.fmax(0.0, -(v_n + a_n * t_r))
        stop = reach + stopping_distance(speed, brake, k)
    return ca.dot(n, x[0:3]) - b - stop


def stopping_distance(speed: Any, brake: Any, k: Any = 0.0) -> Any:
    """An upper bound on the distance to stop from ``speed`` at the constant deceleration
    ``brake`` plus linear drag ``k`` * speed: speed^2 / (2 (brake + k speed / 2)). The exact
    distance, (a/k^2)(x - ln(1 + x)) with x = k speed / a, is at most this because
    ln(1 + x) >= 2x / (2 + x) for x >= 0: the drag counts with half its initial deceleration, as
    it fades while the drone slows. k = 0 gives speed^2 / (2 brake). Works on numbers and CasADi."""
    return speed ** 2 / (2.0 * (brake + 0.5 * k * speed))


def drag_along(n: Any, brake: float, drag: np.ndarray) -> Any:
    """The drag per unit mass [1/s] along the outward direction ``n`` of a drone braking along
    it at ``brake``: its body z axis then points along brake n + g z (thrust balances gravity and
    decelerates), and a body with drag ``drag`` = (d_xy, d_xy, d_z) per axis slows a velocity
    along n by d_xy - (d_xy - d_z) (b^T n)^2 per m/s. Braking horizontally at 3 m/s^2 the body
    tilts 17 degrees and nearly all of d_xy acts; braking vertically only d_z. (The body's two
    horizontal drags are taken as their least, so the yaw angle does not matter.)"""
    d_xy, d_z = float(min(drag[0], drag[1])), float(drag[2])
    c = (brake + GRAVITY * n[2]) / ca.sqrt(GRAVITY ** 2 + brake ** 2 + 2.0 * GRAVITY * brake * n[2])
    return d_xy - (d_xy - d_z) * c ** 2


def check_obstacles(obstacles: Any) -> TurbineProximity | None:
    """``obstacles`` as a TurbineProximity: one, a mission (``env.mission``), or None."""
    if obstacles is None or isinstance(obstacles, TurbineProximity):
        return obstacles
    if hasattr(obstacles, "turbines"):
        return TurbineProximity.from_mission(obstacles)
    raise ValueError(f"obstacles must be a TurbineProximity, a mission or None, got {type(obstacles).__name__}")
