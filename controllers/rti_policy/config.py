"""The MPCs' shared configuration (:class:`MPCConfig`), their solver defaults and the OCP built from it."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Mapping

import numpy as np

from wt_inspect_env.physics.quadrotor import GRAVITY, QuadrotorParams, get_preset
from wt_inspect_env.planner.config import CLEARANCE_BRAKE
from wt_inspect_env.task.env_config import D_MIN_RATIO
from wt_inspect_env.task.spaces import ActionScaling
from wt_inspect_env.util.validation import check_choice, check_field_types, check_positive, check_positive_int

from ..rti import OCP, RTIOptions
from .weights import LSQWeights, ResidualScales

BACKENDS = ("rti", "ipopt")


def warm_start_shifts(control_dt: float, dt: float) -> int:
    """How many stages to shift the plan after each control step.

    A control period equal to (or a multiple of) the shooting interval shifts by that many stages.
    A control period *shorter* than the stage (PAMPC: 0.01 s control, 0.1 s stages) keeps the plan
    where it is: its first stage starts "now" either way, and shifting by a whole stage would
    start the warm start 0.1 s in the future. Periods that are not a multiple are refused.
    """
    ratio = control_dt / dt
    if ratio < 1.0 - 1e-9:
        return 0
    n = int(round(ratio))
    if abs(ratio - n) > 1e-6:
        raise ValueError(f"control_dt must be shorter than dt or a multiple of it, got "
                         f"control_dt={control_dt!r}, dt={dt!r}")
    return n



def default_solver(regularization: float = 0.0) -> RTIOptions:
    """The MPCs' solver options: the fastest verified QP path, HPIPM called directly (clearance
    constraint included) from acados' initial barrier parameter (``RTIOptions(qp_solver="casadi")``
    keeps CasADi's plugin); ``regularization`` damps the real-time iteration (none by default)."""
    return RTIOptions(qp_mode="speed_abs", qp_solver="hpipm", qp_mu0=1.0, regularization=regularization)


def _default_params() -> QuadrotorParams:
    return get_preset("matrice100")


#: what the disturbance observer compares a measured velocity with (MPCConfig.observer_model)
OBSERVER_MODELS = ("prediction", "attitude")


@dataclass(frozen=True)
class MPCConfig:
    """What every MPC instance has (clearance fields: see the module docstring - ``d_min`` [m],
    None for 3/7 d_ref, below d_ref; ``clearance_brake`` the deceleration [m/s^2] of the braking
    term; ``clearance_reaction`` [s] the time before that braking starts, during which the drone
    keeps its present acceleration (0 for the MPCs, which never tilt hard towards the structure;
    the safety filter's policies may, and turning a tilted drone round takes time); ``clearance_l1`` /
    ``clearance_l2`` the slack's L1 / L2 prices (L1 > 0 bounds it below by 0); ``clearance_queries`` how many
    stages of the predicted trajectory are looked up per step, evenly spread, each stage taking
    the half-space of the nearest looked-up stage; ``clearance_refresh`` [m], default d_ref / 70:
    the half-spaces are looked up again once a looked-up position has moved this far; nearer to the
    turbine than halfway between d_min and d_ref they are looked up at every step - a supporting
    plane of a convex part stays valid wherever the drone is, so reuse is safe, but at edges and
    close in a fresh look-up is tighter); ``clearance_backoff`` [m], default d_ref / 70: the OCP
    keeps d_min plus this, which absorbs the L2 slack's violation (multiplier / l2), the single
    Gauss-Newton linearisation and the model-plant mismatch, so the flown distance stays >= d_min).
    ``weights`` may be a weight object of ``WEIGHTS``, the name
    of one of ``WEIGHT_SETS`` (set by each subclass), a weights file ``PATH.json`` or a mapping
    (:meth:`LSQWeights.load` / :meth:`LSQWeights.from_mapping`; missing fields keep the class's
    default set). ``control_dt`` is the period at which
    :meth:`RTIPolicy.act` is called (default ``dt``; the warm start is shifted accordingly, see
    :func:`warm_start_shifts`). ``scaling`` defaults to the environment's action scaling of
    ``params``. ``solver`` defaults to HPIPM's ``speed_abs`` preset: these QPs have input bounds
    only and a Gauss-Newton Hessian with positive input weights, so they are strictly convex and
    always feasible (failed or non-finite QPs are still caught by the RTI fallback). ``backend``
    ``"rti"`` is the real-time iteration, ``"ipopt"`` solves every step to convergence (the slow
    reference). ``prepare_ahead``: see the module docstring. ``scale_weights`` (default on): the
    weights are the reference conditions' and the solver gets them scaled for ``d_ref`` and
    ``params`` (:meth:`solver_weights`, the module docstring's weight scaling), the clearance prices
    likewise (:attr:`clearance_prices`); off, both apply as given. ``disturbance_observer`` (off by
    default) estimates a world-frame disturbance acceleration from the gap between measured and
    predicted velocity (first-order filter, ``observer_time_constant`` [s], bounded by
    ``observer_max_accel`` [m/s^2], below g) for a subclass's model (VT-NMPC, the safety filter:
    :meth:`RTIPolicy.on_measurement`); ``observer_model`` says what the measurement is compared
    with: ``"prediction"`` the plan's predicted velocity, ``"attitude"`` the acceleration the model
    gives for the *measured* attitudes and the applied thrust (see :meth:`RTIPolicy.on_measurement`)."""

    WEIGHTS: ClassVar[type] = LSQWeights
    WEIGHT_SETS: ClassVar[Mapping[str, Any]] = {}

    params: QuadrotorParams = field(default_factory=_default_params)
    weights: Any = "paper"
    horizon: int = 30
    dt: float = 0.01
    d_ref: float = 7.0
    rk4_steps: int = 1
    control_dt: float | None = None
    scaling: ActionScaling | None = None
    solver: RTIOptions = field(default_factory=default_solver)
    backend: str = "rti"
    prepare_ahead: bool = False
    clearance: bool = True
    d_min: float | None = None
    clearance_brake: float = CLEARANCE_BRAKE
    clearance_reaction: float = 0.0
    clearance_l1: float = 1e3
    clearance_l2: float = 1e3
    clearance_queries: int = 4
    clearance_refresh: float | None = None
    clearance_backoff: float | None = None
    scale_weights: bool = True
    disturbance_observer: bool = False
    observer_time_constant: float = 0.3
    observer_max_accel: float = 0.8 * GRAVITY
    observer_model: str = "prediction"

    def __post_init__(self) -> None:
        check_field_types(self, "")
        put = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 - frozen dataclass setter
        if not isinstance(self.params, QuadrotorParams):
            raise ValueError(f"params must be QuadrotorParams, got {type(self.params).__name__}")
        if isinstance(self.weights, str) and self.weights not in self.WEIGHT_SETS and self.weights.endswith(".json"):
            put("weights", self.WEIGHTS.load(self.weights, base=self._default_weights()))
        elif isinstance(self.weights, Mapping):
            put("weights", self.WEIGHTS.from_mapping(self.weights, base=self._default_weights()))
        if isinstance(self.weights, str):
            if self.weights not in self.WEIGHT_SETS:
                raise ValueError(f"unknown weights {self.weights!r}; valid: {', '.join(self.WEIGHT_SETS)} "
                                 "or a weights file PATH.json")
            put("weights", self.WEIGHT_SETS[self.weights])
        elif not isinstance(self.weights, self.WEIGHTS):
            raise ValueError(f"weights must be {self.WEIGHTS.__name__} or a set name, got {self.weights!r}")
        put("horizon", check_positive_int("horizon", self.horizon))
        put("rk4_steps", check_positive_int("rk4_steps", self.rk4_steps))
        put("dt", check_positive("dt", self.dt))
        put("d_ref", check_positive("d_ref", self.d_ref))
        put("control_dt", check_positive("control_dt", self.dt if self.control_dt is None else self.control_dt))
        warm_start_shifts(self.control_dt, self.dt)
        if self.scaling is None:
            put("scaling", ActionScaling.from_params(self.params))
        elif not isinstance(self.scaling, ActionScaling):
            raise ValueError(f"scaling must be an ActionScaling, got {self.scaling!r}")
        if not isinstance(self.solver, RTIOptions):
            raise ValueError(f"solver must be RTIOptions, got {self.solver!r}")
        check_choice("backend", self.backend, BACKENDS)
        if not isinstance(self.prepare_ahead, bool):
            raise ValueError(f"prepare_ahead must be a bool, got {self.prepare_ahead!r}")
        if not isinstance(self.clearance, bool):
            raise ValueError(f"clearance must be a bool, got {self.clearance!r}")
        if self.d_min is None:
            put("d_min", D_MIN_RATIO * self.d_ref)
        put("d_min", check_positive("d_min", self.d_min))
        if self.d_min >= self.d_ref:
            raise ValueError(f"d_min must be below d_ref ({self.d_ref!r} m), got {self.d_min!r}")
        put("clearance_brake", check_positive("clearance_brake", self.clearance_brake))
        put("clearance_reaction", check_positive("clearance_reaction", self.clearance_reaction, allow_zero=True))
        put("clearance_l1", check_positive("clearance_l1", self.clearance_l1, allow_zero=True))
        put("clearance_l2", check_positive("clearance_l2", self.clearance_l2))
        put("clearance_queries", check_positive_int("clearance_queries", self.clearance_queries))
        if self.clearance_refresh is None:
            put("clearance_refresh", self.d_ref / 70.0)
        put("clearance_refresh", check_positive("clearance_refresh", self.clearance_refresh, allow_zero=True))
        if self.clearance_backoff is None:
            put("clearance_backoff", self.d_ref / 70.0)
        put("clearance_backoff", check_positive("clearance_backoff", self.clearance_backoff, allow_zero=True))
        if self.d_min + self.clearance_backoff >= self.d_ref:
            raise ValueError(f"d_min + clearance_backoff must be below d_ref ({self.d_ref!r} m), got "
                             f"{self.d_min!r} + {self.clearance_backoff!r}")
        if not isinstance(self.disturbance_observer, bool):
            raise ValueError(f"disturbance_observer must be a bool, got {self.disturbance_observer!r}")
        if self.disturbance_observer and self.control_dt < self.dt:
            raise ValueError(f"disturbance_observer needs control_dt >= dt (it compares the measurement "
                             f"with the plan's next stage), got control_dt={self.control_dt!r}, dt={self.dt!r}")
        check_positive("observer_time_constant", self.observer_time_constant)
        if self.observer_model not in OBSERVER_MODELS:
            raise ValueError(f"observer_model must be one of {list(OBSERVER_MODELS)}, got {self.observer_model!r}")
        check_positive("observer_max_accel", self.observer_max_accel)
        if self.observer_max_accel >= GRAVITY:
            raise ValueError(f"observer_max_accel must be below g = {GRAVITY} m/s^2 (the tilted hover "
                             f"attitude needs thrust with an upward part), got {self.observer_max_accel!r}")

    @classmethod
    def _default_weights(cls) -> Any:
        """The class's default weight set (what a weights file's missing fields keep)."""
        default = next(f.default for f in fields(cls) if f.name == "weights")
        return cls.WEIGHT_SETS[default] if isinstance(default, str) and default in cls.WEIGHT_SETS else cls.WEIGHTS()

    @property
    def residual_scales(self) -> ResidualScales:
        """The residual sizes of this stand-off and drone."""
        return ResidualScales.of(self.d_ref, self.params)

    def solver_weights(self, weights: Any = None) -> Any:
        """The weights the solver gets: ``weights`` (default this config's) scaled for ``d_ref``
        and ``params`` when ``scale_weights`` is on, as given otherwise."""
        w = self.weights if weights is None else weights
        return w.scaled(self.residual_scales) if self.scale_weights else w

    @property
    def clearance_prices(self) -> tuple[float, float]:
        """(L1, L2) prices of the clearance slack, a length: with ``scale_weights`` times k and k^2
        for k = reference length / d_ref (the slack measured in the reference's metres), else as
        given."""
        if not self.scale_weights:
            return self.clearance_l1, self.clearance_l2
        k = ResidualScales.reference().length / self.residual_scales.length
        return self.clearance_l1 * k, self.clearance_l2 * k * k

    @property
    def hover_input(self) -> np.ndarray:
        """[0, 0, 0, m g]: the input reference and the fallback command."""
        return np.array([0.0, 0.0, 0.0, self.params.weight])


def config_ocp(name: str, config: MPCConfig, dynamics: Any, stage_residual: Any, terminal_residual: Any) -> OCP:
    """The least-squares OCP of a controller: its dynamics and residuals with the configuration's
    horizon, stage length, the action bounds as input bounds and hover as the fallback input."""
    return OCP(name=name, dynamics=dynamics, stage_residual=stage_residual, terminal_residual=terminal_residual,
               horizon=int(config.horizon), dt=config.dt, u_lower=config.scaling.lower,
               u_upper=config.scaling.upper, fallback_input=config.hover_input)


def resolve_config(config_cls: type, config: Any, overrides: Mapping[str, Any]) -> Any:
    """A config from ``config`` and/or keyword overrides (unknown options named in the error)."""
    if config is not None and not isinstance(config, config_cls):
        raise ValueError(f"config must be a {config_cls.__name__}, got {type(config).__name__}")
    known = {f.name for f in fields(config_cls)}
    bad = sorted(set(overrides) - known)
    if bad:
        raise ValueError(f"unknown {config_cls.__name__} option(s) {bad}; valid: {sorted(known)}")
    if config is None:
        return config_cls(**overrides)
    return dataclasses.replace(config, **overrides) if overrides else config
