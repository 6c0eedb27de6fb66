"""The paper's conventional NMPC baseline: least-squares trajectory tracking on the RTI core.

The reference (section "Simulations" of the paper) is the stand-off waypoint p + d_ref n_xy at the
inspection point's height, moving with the point, its velocity, the yaw that faces the surface
(along -n_xy, "precomputed from the surface normal"), level attitude, zero rates and hover thrust.
Residuals and the clock state that moves the waypoint over the horizon are in
:mod:`controllers.tracking`:

=============  ============================================  ===========================  =========
residual       definition                                    authors' weight               default
=============  ============================================  ===========================  =========
position       p - (p_wp + v_pt tau)      (world)            W_x, W_y, W_z = 40, 40, 50    same
velocity       R v_B - v_pt               (world)            W_u, W_v, W_w = 3, 3, 5       same
tilt           (q_x, q_y)                                    W_qx, W_qy = 60, 60            same
heading        (R e_x)_xy - (cos psi, sin psi)  (2 rows)     W_qz = W_qw = 30 on q - q_ref  30/4
inputs         [p, q, r, T] - [0, 0, 0, m g]                 0.5, 0.5, 0.5, 0.025          same
terminal       position, velocity, tilt, heading             W_N = 1.5 W                   same
=============  ============================================  ===========================  =========

The authors' weights are those of their rate-command quaternion NMPC
(``posaware_ratecommand_quaternion_nmpc_pc_learning``, Matrice 100 Gazebo airframe file; its
perception-like term "s" had weight 0, so it is left out). The notes list what the baseline tracked
(position, body velocity, quaternion from a reference yaw, rates, thrust) but not these numbers;
they are taken from that file. Two changes, both documented in :mod:`controllers.tracking`:

* the quaternion-from-yaw residual is replaced by the sign-safe heading residual, weighted
  w_qz / 4 = 7.5 so that it has the same curvature at zero yaw error (the authors' q_z and q_w
  weights were equal, 30);
* the velocity is tracked in the world frame (for the point's constant world velocity the norm is
  the same as the authors' body-frame error when the body reference is the point's velocity
  rotated by the current attitude, and it stays right along the horizon).

The thrust reference is the hover thrust m g of the one parameter set (the authors used a constant
that did not match their model mass). Horizon N = 30 at 0.01 s, RK4 multiple shooting, the
environment's input bounds (|p|, |q|, |r| <= 100 deg/s, 0.3 m g <= T <= 2 m g) - all as the
authors' NMPC. Online parameters: ``[p_wp (3), v_pt (3), cos psi_ref, sin psi_ref]``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from wt_inspect_env.dynamics import NU
from wt_inspect_env.quadrotor import QuadrotorParams, get_preset
from wt_inspect_env.spaces import ActionScaling
from wt_inspect_env.validation import check_positive

from .rti import OCP, RTIOptions
from .tracking import (N_TRACKING_PARAMS, NX_AUG, TrackingMPCPolicy, augmented_dynamics,
                       check_input_weights, hover_input, tracking_terms, validate_tracking_config,
                       weight_tuple)

N_PARAMS = N_TRACKING_PARAMS
STAGE_RESIDUAL_NAMES = ("px", "py", "pz", "vx", "vy", "vz", "qx", "qy", "hx", "hy",
                        "p", "q", "r", "T")
TERMINAL_RESIDUAL_NAMES = STAGE_RESIDUAL_NAMES[:10]


@dataclass(frozen=True)
class NMPCWeights:
    """Diagonal least-squares weights of the NMPC baseline (defaults: the authors' file, see the
    module docstring). ``heading`` weighs both rows of the heading residual."""

    position: tuple[float, ...] = (40.0, 40.0, 50.0)
    velocity: tuple[float, ...] = (3.0, 3.0, 5.0)
    tilt: tuple[float, ...] = (60.0, 60.0)
    heading: float = 7.5
    inputs: tuple[float, ...] = (0.5, 0.5, 0.5, 0.025)
    terminal_factor: float = 1.5

    def __post_init__(self) -> None:
        for name, n in (("position", 3), ("velocity", 3), ("tilt", 2), ("inputs", 4)):
            object.__setattr__(self, name, weight_tuple(f"weights.{name}", getattr(self, name), n))
        check_input_weights("weights.inputs", self.inputs)
        for name in ("heading", "terminal_factor"):
            object.__setattr__(self, name, check_positive(f"weights.{name}", getattr(self, name),
                                                          allow_zero=True))

    @classmethod
    def authors(cls) -> "NMPCWeights":
        return cls()

    def _state_part(self) -> np.ndarray:
        return np.array([*self.position, *self.velocity, *self.tilt, self.heading, self.heading])

    def stage_vector(self) -> np.ndarray:
        return np.concatenate([self._state_part(), self.inputs])

    def terminal_vector(self) -> np.ndarray:
        return self.terminal_factor * self._state_part()


WEIGHT_SETS: dict[str, NMPCWeights] = {"authors": NMPCWeights.authors()}


def _default_params() -> QuadrotorParams:
    return get_preset("matrice100")


@dataclass(frozen=True)
class NMPCConfig:
    """Everything that defines an NMPC instance (fields as :class:`~controllers.vtnmpc.VTNMPCConfig`).

    ``control_dt`` is the period at which :meth:`NMPCPolicy.act` is called (default: ``dt``); the
    warm start is shifted accordingly (:func:`~controllers.tracking.warm_start_shifts`).
    ``solver`` defaults to HPIPM's ``speed_abs`` preset like the VT-NMPC: the QP has input bounds
    only and a Gauss-Newton Hessian with positive input weights, so it is strictly convex and
    always feasible (failed or non-finite QPs are still caught by the RTI fallback).
    """

    params: QuadrotorParams = field(default_factory=_default_params)
    weights: NMPCWeights | str = "authors"
    horizon: int = 30
    dt: float = 0.01
    d_ref: float = 7.0
    rk4_steps: int = 1
    control_dt: float | None = None
    scaling: ActionScaling | None = None
    solver: RTIOptions = field(default_factory=lambda: RTIOptions(qp_mode="speed_abs"))
    backend: str = "rti"

    def __post_init__(self) -> None:
        validate_tracking_config(self, NMPCWeights, WEIGHT_SETS)

    @property
    def hover_input(self) -> np.ndarray:
        return hover_input(self.params)


def residual_functions(config: NMPCConfig) -> tuple[ca.Function, ca.Function]:
    """(stage_residual(x_aug, u, p), terminal_residual(x_aug, p)), zero at the reference."""
    x = ca.SX.sym("x", NX_AUG)
    u = ca.SX.sym("u", NU)
    p = ca.SX.sym("p", N_PARAMS)
    t = tracking_terms(x, p)
    state_res = ca.vertcat(t["position"], t["velocity"], t["tilt"], t["heading"])
    stage = ca.Function("nmpc_r", [x, u, p], [ca.vertcat(state_res, u - ca.DM(config.hover_input))],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function("nmpc_rN", [x, p], [state_res], ["x", "p"], ["rN"])
    return stage, terminal


def build_ocp(config: NMPCConfig) -> OCP:
    """The NMPC as a generic least-squares OCP (RK4 of the shared model plus the clock state)."""
    F = augmented_dynamics("nmpc", config.params, config.dt, config.rk4_steps, N_PARAMS)
    stage, terminal = residual_functions(config)
    return OCP(name="nmpc", dynamics=F, stage_residual=stage, terminal_residual=terminal,
               horizon=int(config.horizon), dt=config.dt, u_lower=config.scaling.lower,
               u_upper=config.scaling.upper,
               fallback_input=config.hover_input)


class NMPCPolicy(TrackingMPCPolicy):
    """The NMPC baseline as a policy: observation in, normalised (p, q, r, T) action out.

    ``NMPCPolicy(config=None, **overrides)``; :meth:`reset`, :meth:`act`, :meth:`predict`,
    :meth:`set_weights`, :attr:`last_stats` as for ``VTNMPCPolicy``. :meth:`command_for` takes a
    model state and :meth:`TrackingReference.parameters` directly (used to check yaw wrapping).
    """

    config_class = NMPCConfig
    weight_sets = WEIGHT_SETS

    def __init__(self, config: NMPCConfig | None = None, **overrides: Any) -> None:
        super().__init__(config, **overrides)

    def build_ocp(self, config: NMPCConfig) -> OCP:
        return build_ocp(config)
