"""The paper's 10-state quadrotor model, written once in CasADi.

State  x = [px, py, pz, u, v, w, qx, qy, qz, qw]  (world position, body velocity, unit quaternion
           body-to-world in PyBullet's (x, y, z, w) order)
Input  u = [p, q, r, T]                            (body rates [rad/s], collective thrust [N])

Derived from first principles (the paper's printed equations have sign and index typos, see the
authors' code notes):

    p_dot = R(q) v_B
    v_B_dot = -omega x v_B + R(q)^T (g_W + a_ext_W) + [0, 0, T / m]
    q_dot = 1/2 q (x) (omega, 0)

where g_W = [0, 0, -g] and ``a_ext_W`` an optional world-frame disturbance acceleration (e.g. a drag
estimate). An optional linear drag per unit mass ``drag`` [1/s] per body axis adds ``- drag * v_B``
to v_B_dot (the rotor drag's ground-relative part; the wind's part, ``drag * R^T w``, is a
world-frame push an observer can estimate as a_ext). The quaternion algebra is written with small
helpers (product, rotation matrix) rather than expanded by hand. Every MPC uses
:class:`QuadrotorModel`; a NumPy evaluation and an RK4 discretisation come from the same
expressions.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import casadi as ca
import numpy as np

from ..util.validation import check_positive
from .quadrotor import GRAVITY, QuadrotorParams

NX = 10
NU = 4
STATE_NAMES = ("px", "py", "pz", "u", "v", "w", "qx", "qy", "qz", "qw")
INPUT_NAMES = ("p", "q", "r", "T")


def quat_product(a, b):
    """Hamilton product a (x) b of quaternions in (x, y, z, w) order (CasADi or NumPy)."""
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    return ca.vertcat(
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_to_rotmat(q):
    """Body-to-world rotation matrix of a unit quaternion (x, y, z, w), symbolic."""
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (qy**2 + qz**2), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)),
        ca.horzcat(2 * (qx * qy + qw * qz), 1 - 2 * (qx**2 + qz**2), 2 * (qy * qz - qw * qx)),
        ca.horzcat(2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx**2 + qy**2)),
    )


def quat_to_rotmat_np(q: np.ndarray) -> np.ndarray:
    """NumPy version of :func:`quat_to_rotmat` (accepts (4,) or (..., 4))."""
    q = np.asarray(q, dtype=float)
    if q.shape == (4,):   # one quaternion (every control step): the same arithmetic on Python floats
        qx, qy, qz, qw = q.tolist()
        xx, yy, zz = qx * qx, qy * qy, qz * qz      # as NumPy squares arrays (x * x)
        return np.array([[1 - 2 * (yy + zz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)],
                         [2 * (qx * qy + qw * qz), 1 - 2 * (xx + zz), 2 * (qy * qz - qw * qx)],
                         [2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (xx + yy)]])
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (qy**2 + qz**2)
    R[..., 0, 1] = 2 * (qx * qy - qw * qz)
    R[..., 0, 2] = 2 * (qx * qz + qw * qy)
    R[..., 1, 0] = 2 * (qx * qy + qw * qz)
    R[..., 1, 1] = 1 - 2 * (qx**2 + qz**2)
    R[..., 1, 2] = 2 * (qy * qz - qw * qx)
    R[..., 2, 0] = 2 * (qx * qz - qw * qy)
    R[..., 2, 1] = 2 * (qy * qz + qw * qx)
    R[..., 2, 2] = 1 - 2 * (qx**2 + qy**2)
    return R


def yaw_to_quat(yaw: float) -> np.ndarray:
    """Level attitude with the given yaw, as (qx, qy, qz, qw)."""
    return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


def hover_state(position, yaw: float = 0.0) -> np.ndarray:
    """A resting state at ``position`` with the given yaw."""
    x = np.zeros(NX)
    x[0:3] = position
    x[6:10] = yaw_to_quat(yaw)
    return x


@dataclass(frozen=True)
class QuadrotorModel:
    """Continuous and discrete dynamics of the 10-state model for given parameters."""

    params: QuadrotorParams = field(default_factory=QuadrotorParams)

    def continuous_expr(self, x, u, a_ext=None, drag=None):
        """Symbolic x_dot for symbolic (or numeric) x, u, optional world accel ``a_ext`` and
        optional linear body drag per unit mass ``drag`` (3,) [1/s] (module docstring)."""
        vel_b = x[3:6]
        q = x[6:10]
        omega = u[0:3]
        thrust = u[3]
        R = quat_to_rotmat(q)
        g_w = ca.vertcat(0, 0, -GRAVITY)
        if a_ext is not None:
            g_w = g_w + a_ext
        p_dot = R @ vel_b
        v_dot = -ca.cross(omega, vel_b) + R.T @ g_w + ca.vertcat(0, 0, thrust / self.params.mass)
        if drag is not None:
            v_dot = v_dot - ca.DM(drag) * vel_b
        q_dot = 0.5 * quat_product(q, ca.vertcat(omega, 0))
        return ca.vertcat(p_dot, v_dot, q_dot)

    @cached_property
    def f(self) -> ca.Function:
        """CasADi function f(x, u) -> x_dot (no disturbance)."""
        x = ca.SX.sym("x", NX)
        u = ca.SX.sym("u", NU)
        return ca.Function("quad_f", [x, u], [self.continuous_expr(x, u)], ["x", "u"], ["xdot"])

    @cached_property
    def f_ext(self) -> ca.Function:
        """CasADi function f(x, u, a_ext) -> x_dot with a world-frame disturbance acceleration."""
        x = ca.SX.sym("x", NX)
        u = ca.SX.sym("u", NU)
        a = ca.SX.sym("a_ext", 3)
        return ca.Function("quad_f_ext", [x, u, a], [self.continuous_expr(x, u, a)],
                           ["x", "u", "a_ext"], ["xdot"])

    def rk4_expr(self, x, u, dt: float, a_ext=None, steps: int = 1, drag=None):
        """Symbolic RK4 step(s) of length ``dt`` (split into ``steps`` sub-steps)."""
        h = dt / steps
        for _ in range(steps):
            k1 = self.continuous_expr(x, u, a_ext, drag)
            k2 = self.continuous_expr(x + h / 2 * k1, u, a_ext, drag)
            k3 = self.continuous_expr(x + h / 2 * k2, u, a_ext, drag)
            k4 = self.continuous_expr(x + h * k3, u, a_ext, drag)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    def discrete(self, dt: float, steps: int = 1) -> ca.Function:
        """CasADi function F(x, u) -> x_next, RK4 with step ``dt``."""
        check_positive("dt", dt)
        x = ca.SX.sym("x", NX)
        u = ca.SX.sym("u", NU)
        return ca.Function("quad_rk4", [x, u], [self.rk4_expr(x, u, dt, steps=steps)],
                           ["x", "u"], ["x_next"])

    def xdot(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """NumPy evaluation of the continuous dynamics."""
        return np.asarray(self.f(np.asarray(x, float), np.asarray(u, float))).ravel()

    def rollout(self, x0: np.ndarray, us: np.ndarray, dt: float, substeps: int = 4) -> np.ndarray:
        """Integrate a sequence of inputs (K, 4) held for ``dt`` each; returns (K+1, 10) states."""
        F = self.discrete(dt, steps=substeps)
        xs = [np.asarray(x0, float)]
        for u in np.asarray(us, float):
            xn = np.asarray(F(xs[-1], u)).ravel()
            xn[6:10] /= np.linalg.norm(xn[6:10])
            xs.append(xn)
        return np.array(xs)
