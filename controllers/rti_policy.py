"""One policy base for every MPC on the RTI core: a controller is its OCP, weights and parameters.

:class:`RTIPolicy` owns everything that is the same for the VT-NMPC, the NMPC and the PAMPC - and
for the next MPC: building the solver (real-time iteration or IPOPT), reset, weights switched
without recompiling, the horizontal-normal fallback (:class:`~wt_inspect_env.task.geometry.HorizontalNormal`),
keyword overrides of the configuration, the quaternion sign alignment, the warm-start shift for the
control period, the preparation/feedback schedule and the statistics. A subclass provides only

* ``config_class`` - an :class:`MPCConfig` subclass (its extra fields, its weight class and sets);
* :meth:`RTIPolicy.build_ocp` - the least-squares OCP (residuals, dynamics, bounds);
* :meth:`RTIPolicy.parameters` - the OCP's online parameters for an observation;
* optionally :meth:`RTIPolicy.model_state` (an augmented state, e.g. the baselines' clock) and
  :meth:`RTIPolicy.on_measurement` (estimators fed by each measured state, e.g. VT-NMPC's
  disturbance observer).

Weights (:class:`LSQWeights`) have one shape for every controller: named blocks of the residual
vector, each a number (repeated over its rows) or a tuple, laid out by the class's ``STAGE`` and
``TERMINAL`` tables, with a ``terminal_factor``.

Preparation and feedback. With ``prepare_ahead`` off (the default, and how every published result
was made) each :meth:`~RTIPolicy.act` linearises for the new observation and then solves the QP:
the command waits for both. With ``prepare_ahead`` on, ``act`` runs only the feedback QP for the
measured state on the linearisation prepared at the end of the previous call, and then - after the
command exists - shifts the plan and prepares the next step at the *predicted* state (the plan's
next state) with the parameters predicted for it: the inspection point moved on by its velocity
over one control period, the attitude of the predicted state. This is what acados' ``rti_phase``
1/2 does: everything that depends on the measurement enters the feedback only through the initial
state constraint dx_0 = x_measured - x_0, while parameters are set before the preparation (so they
lag by one step, as in acados; estimators fed by the measurement update at the next feedback and
reach the QP one step later). ``last_stats.latency_ms`` is observation to command either way.

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

Weight scaling. Every weight set was tuned at the paper's conditions (d_ref 7 m, the Matrice-100-like
drone), and a least-squares weight is only meaningful against the size of its residual: the same
0.1 m error is 1.4 % of a 7 m stand-off but 20 % of a 0.5 m one, and the same thrust deviation in
newtons is a larger share of a light drone's weight. So the weights given (a set, a file, a tuning)
are read as weights at those *reference* conditions, and :meth:`LSQWeights.scaled` converts them
for the instance's stand-off and drone: each block declares the unit of its residual
(:attr:`LSQWeights.UNITS`) and is multiplied by (reference size / size)^2, the sizes being
(:class:`ResidualScales`)

* length: d_ref - the geometry of the inspection scales with the stand-off;
* speed: sqrt(g d_ref), and body rate: sqrt(g / d_ref) - Froude scaling. A multirotor accelerates
  horizontally by tilting its thrust, so its accelerations are fractions of g at any size; a
  manoeuvre over a stand-off L scaled by s at the same tilt angles then takes sqrt(s) the time, at
  sqrt(s) the speed and 1/sqrt(s) the body rates. With these sizes the converged answer of a
  geometrically scaled problem (stage length scaled by sqrt(s)) is exactly the scaled answer
  (tests/test_weight_scaling.py), so the paper's damping and trade-offs carry over to any size;
* thrust: the drone's hover thrust m g - thrust deviations matter relative to the weight held;
* dimensionless residuals (attitude, heading, image coordinates): unchanged.

The clearance slack is a length too, so its prices scale with it (L2 by the squared length ratio,
L1 by the ratio; :attr:`MPCConfig.clearance_prices`). At the reference conditions every factor is
exactly 1, so the weights and every result made before the rule are unchanged;
``scale_weights=False`` applies the weights as given at any stand-off and drone.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Mapping

import casadi as ca
import numpy as np

from wt_inspect_env.physics.dynamics import NX, quat_to_rotmat, quat_to_rotmat_np
from wt_inspect_env.physics.quadrotor import GRAVITY, QuadrotorParams, get_preset
from wt_inspect_env.planner.config import CLEARANCE_BRAKE
from wt_inspect_env.planner.proximity import TurbineProximity
from wt_inspect_env.policy import Policy, check_observation, state_from_observation
from wt_inspect_env.task.env_config import D_MIN_RATIO
from wt_inspect_env.task.geometry import HorizontalNormal
from wt_inspect_env.task.spaces import ActionScaling
from wt_inspect_env.util.validation import check_choice, check_field_types, check_positive

from .rti import OCP, IpoptOCPSolver, RTIOptions, RTISolver, SolveStats

BACKENDS = ("rti", "ipopt")
N_CLEARANCE_PARAMS = 4        # per stage: outward direction n (3), b = n^T c + d_min
SLACK_UPPER = 1e3             # [m] finite upper bound of the clearance slack (HPIPM bounds every input)
REFERENCE_D_REF = 7.0         # [m] the stand-off every weight set was tuned at (the paper's)
REFERENCE_DRONE = "matrice100"  # the drone they were tuned for
WEIGHT_UNITS = ("1", "length", "speed", "rate", "thrust")


# ------------------------------------------------------------------------------------------------
# validation helpers
# ------------------------------------------------------------------------------------------------

def weight_tuple(name: str, values: Any, n: int) -> tuple[float, ...]:
    """``values`` as ``n`` finite non-negative floats; ValueError naming ``name`` otherwise."""
    try:
        vals = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} numbers, got {values!r}") from None
    if len(vals) != n:
        raise ValueError(f"{name} must have {n} entries, got {len(vals)}")
    for i, v in enumerate(vals):
        check_positive(f"{name}[{i}]", v, allow_zero=True)
    return vals


def _weight_number(name: str, value: Any) -> float:
    """One weight from JSON data: a real number (not text, not a bool), finite, >= 0."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    return check_positive(name, value, allow_zero=True)


def check_positive_int(name: str, value: Any) -> int:
    """``value`` as an int if it is an integer >= 1 (not a bool); else a ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


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


# ------------------------------------------------------------------------------------------------
# weights
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ResidualScales:
    """The characteristic size of each kind of residual at one stand-off and drone (the weight
    scaling rule of the module docstring): ``length`` [m], ``speed`` [m/s], ``rate`` [rad/s],
    ``thrust`` [N]."""

    length: float
    speed: float
    rate: float
    thrust: float

    @classmethod
    def of(cls, d_ref: float, params: QuadrotorParams) -> "ResidualScales":
        """Lengths by the stand-off, speeds and rates by Froude scaling of it, thrust by the
        drone's hover thrust."""
        d = check_positive("d_ref", d_ref)
        return cls(length=d, speed=math.sqrt(GRAVITY * d), rate=math.sqrt(GRAVITY / d), thrust=params.weight)

    @classmethod
    def reference(cls) -> "ResidualScales":
        """The sizes at the conditions the weight sets were tuned at (the paper's)."""
        return cls.of(REFERENCE_D_REF, get_preset(REFERENCE_DRONE))

    def factor(self, unit: str, reference: "ResidualScales") -> float:
        """The weight factor (reference size / size)^2 of a residual of ``unit``; exactly 1 for
        equal sizes."""
        check_choice("weight unit", unit, WEIGHT_UNITS)
        if unit == "1":
            return 1.0
        return (getattr(reference, unit) / getattr(self, unit)) ** 2


@dataclass(frozen=True)
class LSQWeights:
    """Diagonal least-squares weights in named blocks (the one shape of every controller).

    A subclass declares its blocks as fields - a float default for a block weighted by one number
    (repeated over the block's rows), a tuple default for one weight per row - and lays them out
    with ``STAGE`` and ``TERMINAL``: ``(field, rows)`` in the order of the stage and terminal
    residuals. :meth:`terminal_vector` is ``terminal_factor`` times the terminal layout. The block
    named ``INPUTS`` must be positive: Gauss-Newton needs a positive-definite input block
    (R + B^T P B > 0 in HPIPM's Riccati recursion), a zero input weight can leave the QP singular.
    ``UNITS`` names each block's residual unit (one of :data:`WEIGHT_UNITS`, or a tuple of them per
    row) for :meth:`scaled`.
    """

    terminal_factor: float = 1.5

    STAGE: ClassVar[tuple[tuple[str, int], ...]] = ()
    TERMINAL: ClassVar[tuple[tuple[str, int], ...]] = ()
    INPUTS: ClassVar[str] = "inputs"
    UNITS: ClassVar[Mapping[str, str | tuple[str, ...]]] = {}

    def __post_init__(self) -> None:
        check_field_types(self, "weights.")
        rows = dict(self.STAGE) | dict(self.TERMINAL)
        for f in fields(self):
            if f.name == "terminal_factor":
                continue
            value, name = getattr(self, f.name), f"weights.{f.name}"
            if isinstance(f.default, tuple):
                object.__setattr__(self, f.name, weight_tuple(name, value, rows[f.name]))
            else:
                object.__setattr__(self, f.name, check_positive(name, value, allow_zero=True))
        object.__setattr__(self, "terminal_factor",
                           check_positive("weights.terminal_factor", self.terminal_factor, allow_zero=True))
        for i, v in enumerate(np.atleast_1d(getattr(self, self.INPUTS))):
            if v == 0:
                raise ValueError(f"weights.{self.INPUTS}[{i}] must be positive (a zero input weight makes "
                                 f"the QP singular), got {float(v)!r}")

    @classmethod
    def from_mapping(cls, data: Any, *, base: "LSQWeights | None" = None, source: str = "weights") -> "LSQWeights":
        """Weights from plain data (a JSON object: field -> number, or list of numbers for a
        per-row block). Fields left out keep ``base``'s values (default: the class defaults), so a
        file may change one block. Checked before anything is built, one line naming the field and
        value: an unknown field, a list of the wrong length, a scalar for a block or a list for a
        scalar, text or a bool for a number, a negative or non-finite value. ``source`` prefixes
        the message (the file's name)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{source}: must be a JSON object of weight fields, got {type(data).__name__}")
        base = cls() if base is None else base
        if not isinstance(base, cls):
            raise ValueError(f"{source}: base weights must be {cls.__name__}, got {type(base).__name__}")
        valid = {f.name: f for f in fields(cls)}
        values: dict[str, Any] = {}
        for key, value in data.items():
            if key not in valid:
                raise ValueError(f"{source}: unknown field {key!r} (= {value!r}) for {cls.__name__}; "
                                 f"valid: {', '.join(valid)}")
            current = getattr(base, key)
            label = f"{source}: {key}"
            if isinstance(current, tuple):
                if not isinstance(value, (list, tuple)) or len(value) != len(current):
                    raise ValueError(f"{label} must be a list of {len(current)} numbers, got {value!r}")
                values[key] = tuple(_weight_number(f"{label}[{i}]", v) for i, v in enumerate(value))
            else:
                values[key] = _weight_number(label, value)
        try:
            return dataclasses.replace(base, **values)
        except ValueError as exc:   # the class's own checks (a zero input weight)
            raise ValueError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path: Any, *, base: "LSQWeights | None" = None) -> "LSQWeights":
        """Weights from a JSON file (never code: plain JSON, see :meth:`from_mapping`); a missing
        or malformed file is a one-line ValueError naming it."""
        import json
        from pathlib import Path
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise ValueError(f"weights file {str(p)!r}: cannot read: {exc.strerror or exc}") from None
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"weights file {str(p)!r}: not valid JSON: {exc}") from None
        return cls.from_mapping(data, base=base, source=f"weights file {str(p)!r}")

    def to_dict(self) -> dict[str, Any]:
        """Every field as plain JSON data (lists for per-row blocks): what :meth:`load` reads."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}

    def scaled(self, scales: ResidualScales, reference: ResidualScales | None = None) -> "LSQWeights":
        """These weights, read as weights at the ``reference`` conditions (default: the paper's,
        :meth:`ResidualScales.reference`), for residuals of the sizes ``scales``: each block times
        (reference size / size)^2 of its unit (module docstring). Equal sizes give these weights
        exactly (every factor is 1.0; a class without ``UNITS`` is usable there, and refused with
        the missing block named elsewhere - an unscaled block would silently change its weight
        relative to the others)."""
        ref = ResidualScales.reference() if reference is None else reference
        if scales == ref:
            return self
        changes: dict[str, Any] = {}
        for f in fields(self):
            if f.name == "terminal_factor":
                continue
            if f.name not in self.UNITS:
                raise ValueError(f"{type(self).__name__}.UNITS has no unit for weights.{f.name} (needed to "
                                 f"scale the weights away from the reference conditions)")
            unit, value = self.UNITS[f.name], getattr(self, f.name)
            if isinstance(value, tuple):
                units = (unit,) * len(value) if isinstance(unit, str) else tuple(unit)
                if len(units) != len(value):
                    raise ValueError(f"{type(self).__name__}.UNITS[{f.name!r}] must have {len(value)} "
                                     f"entries, got {unit!r}")
                changes[f.name] = tuple(v * scales.factor(u, ref) for v, u in zip(value, units))
            else:
                if not isinstance(unit, str):
                    raise ValueError(f"{type(self).__name__}.UNITS[{f.name!r}] must be one unit, got {unit!r}")
                changes[f.name] = value * scales.factor(unit, ref)
        return dataclasses.replace(self, **changes)

    def _vector(self, layout: tuple[tuple[str, int], ...]) -> np.ndarray:
        parts = []
        for name, n in layout:
            value = getattr(self, name)
            parts.append(np.asarray(value, dtype=float) if isinstance(value, tuple) else np.full(n, value))
        return np.concatenate(parts)

    def stage_vector(self) -> np.ndarray:
        """The stage residual's weights as a vector."""
        return self._vector(self.STAGE)

    def terminal_vector(self) -> np.ndarray:
        """The terminal residual's weights as a vector, times ``terminal_factor``."""
        return self.terminal_factor * self._vector(self.TERMINAL)


# ------------------------------------------------------------------------------------------------
# configuration
# ------------------------------------------------------------------------------------------------

def default_solver(regularization: float = 0.0) -> RTIOptions:
    """The MPCs' solver options: the fastest verified QP path, HPIPM called directly (clearance
    constraint included) from acados' initial barrier parameter (``RTIOptions(qp_solver="casadi")``
    keeps CasADi's plugin); ``regularization`` damps the real-time iteration (none by default)."""
    return RTIOptions(qp_mode="speed_abs", qp_solver="hpipm", qp_mu0=1.0, regularization=regularization)


def _default_params() -> QuadrotorParams:
    return get_preset("matrice100")


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
    likewise (:attr:`clearance_prices`); off, both apply as given."""

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


def clearance_ocp(ocp: OCP, config: MPCConfig) -> OCP:
    """``ocp`` with the soft clearance constraint of the module docstring: one slack input
    appended (within +-SLACK_UPPER, or [0, SLACK_UPPER] with an L1 price; fallback 0), its residual
    ``s + l1 / l2`` appended to the stage residual (weight ``l2``: cost l2 s^2 / 2 + l1 s + const;
    l1, l2 = :attr:`MPCConfig.clearance_prices`),
    and the path constraint
    on stage parameters appended to the OCP's own [n (3), b]. The first 10 states must be the drone's
    [p, v_B, q] (augmented states keep them first)."""
    if ocp.nh:
        raise ValueError(f"the clearance constraint cannot be added to OCP {ocp.name!r}: it already has "
                         f"{ocp.nh} path constraints")
    nx, nu, npar = ocp.nx, ocp.nu, ocp.np
    x, u, p = ca.SX.sym("x", nx), ca.SX.sym("u", nu + 1), ca.SX.sym("p", npar + N_CLEARANCE_PARAMS)
    uc, slack, pc = u[:nu], u[nu], p[:npar]
    n, b = p[npar:npar + 3], p[npar + 3]
    name = f"{ocp.name}_clr"
    dyn = ca.Function(f"{name}_F", [x, u, p], [ocp.dynamics(x, uc, pc)], ["x", "u", "p"], ["x_next"])
    l1, l2 = config.clearance_prices
    offset = l1 / l2
    stage = ca.Function(f"{name}_r", [x, u, p], [ca.vertcat(ocp.stage_residual(x, uc, pc), slack + offset)],
                        ["x", "u", "p"], ["r"])
    terminal = ca.Function(f"{name}_rN", [x, p], [ocp.terminal_residual(x, pc)], ["x", "p"], ["rN"])
    R = quat_to_rotmat(x[6:10])
    v_n = ca.dot(n, R @ x[3:6])          # velocity along the outward direction
    approach = ca.fmax(0.0, -v_n)
    stop = approach ** 2 / (2.0 * config.clearance_brake)
    t_r = config.clearance_reaction
    if t_r > 0.0:
        # for t_r the drone keeps its present acceleration (thrust along body z, gravity) - a
        # drone tilted towards the structure gains speed while it turns round - then brakes
        a_n = ca.dot(n, R[:, 2]) * uc[3] / config.params.mass - GRAVITY * n[2]
        reach = ca.fmax(0.0, -(v_n * t_r + 0.5 * a_n * t_r ** 2))
        speed = ca.fmax(0.0, -(v_n + a_n * t_r))
        stop = reach + speed ** 2 / (2.0 * config.clearance_brake)
    h = ca.dot(n, x[0:3]) - b - stop + slack
    path = ca.Function(f"{name}_h", [x, u, p], [h], ["x", "u", "p"], ["h"])
    return OCP(name=name, dynamics=dyn, stage_residual=stage, terminal_residual=terminal, horizon=ocp.horizon,
               dt=ocp.dt, u_lower=np.append(ocp.u_lower, 0.0 if l1 > 0 else -SLACK_UPPER),
               u_upper=np.append(ocp.u_upper, SLACK_UPPER),
               fallback_input=np.append(ocp.fallback_input, 0.0), x_lower=ocp.x_lower, x_upper=ocp.x_upper,
               path_constraint=path, h_lower=np.zeros(1), h_upper=np.full(1, np.inf))


def _check_obstacles(obstacles: Any) -> TurbineProximity | None:
    """``obstacles`` as a TurbineProximity: one, a mission (``env.mission``), or None."""
    if obstacles is None or isinstance(obstacles, TurbineProximity):
        return obstacles
    if hasattr(obstacles, "turbines"):
        return TurbineProximity.from_mission(obstacles)
    raise ValueError(f"obstacles must be a TurbineProximity, a mission or None, got {type(obstacles).__name__}")


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


# ------------------------------------------------------------------------------------------------
# the policy base class
# ------------------------------------------------------------------------------------------------

class RTIPolicy(Policy):
    """An MPC policy on the RTI core: observation in, normalised (p, q, r, T) action out.

    ``Policy(config=None, obstacles=None, **overrides)`` (``obstacles``: the turbine to keep
    ``d_min`` from, see the module docstring); :meth:`reset`, :meth:`act`, :meth:`predict`,
    :meth:`set_weights`; :attr:`last_stats` (:class:`~controllers.rti.SolveStats`) after every
    call; :attr:`last_command` the physical command. See the module docstring for what a subclass
    provides.
    """

    config_class: ClassVar[type] = MPCConfig

    def __init__(self, config: MPCConfig | None = None, *, obstacles: Any = None, **overrides: Any) -> None:
        config = resolve_config(self.config_class, config, overrides)
        self.config = config
        self.obstacles = _check_obstacles(obstacles)
        self.base_ocp = self.build_ocp(config)
        self.clearance_active = bool(config.clearance and self.obstacles is not None)
        self.ocp = clearance_ocp(self.base_ocp, config) if self.clearance_active else self.base_ocp
        self._nu = self.base_ocp.nu
        if self.clearance_active:
            N = config.horizon
            q = min(config.clearance_queries, N + 1)
            self._query_stages = np.unique(np.round(np.linspace(0, N, q)).astype(int))
            # each stage takes the half-space of the nearest looked-up stage
            self._stage_query = np.abs(np.arange(N + 1)[:, None] - self._query_stages[None, :]).argmin(axis=1)
            self._stage_params = np.zeros((N + 1, self.base_ocp.np + N_CLEARANCE_PARAMS))
        self.last_clearance = float("nan")
        # (positions, c, n, rotor position, min distance, stage normals, stage offsets) of the last look-up
        self._lookup: tuple[Any, ...] | None = None
        self.solver: RTISolver | IpoptOCPSolver = self._make_solver(config.weights)
        self.scaling: ActionScaling = config.scaling
        self._action_map: tuple[ActionScaling, np.ndarray, np.ndarray] | None = None
        self.shifts_per_step = warm_start_shifts(config.control_dt, config.dt)
        self.normal = HorizontalNormal()
        self._last_q: np.ndarray | None = None
        self._ahead = False            # a QP for the next observation is prepared
        self.last_stats: SolveStats = SolveStats()
        self.last_command: np.ndarray | None = None
        self._last_solve: tuple[np.ndarray, np.ndarray] | None = None   # (model state, params) of the last command
        self._prepared_params: np.ndarray | None = None
        self._prediction_offset: np.ndarray | None = None   # shadow mode: see note_applied_action

    # -- what a subclass provides -----------------------------------------------------------------
    def build_ocp(self, config: Any) -> OCP:
        """The controller's least-squares OCP."""
        raise NotImplementedError(f"{type(self).__name__} must define build_ocp(config)")

    def parameters(self, obs: Mapping[str, np.ndarray], state: np.ndarray,
                   normal_xy: np.ndarray) -> np.ndarray:
        """The OCP's online parameters for a checked observation, the drone's model state and the
        horizontal normal (with its fallback already applied)."""
        raise NotImplementedError(f"{type(self).__name__} must define parameters(obs, state, normal_xy)")

    def model_state(self, state: np.ndarray) -> np.ndarray:
        """The OCP's state for a drone state [p, v_B, q] (identity unless the OCP augments it)."""
        return state

    def on_measurement(self, state: np.ndarray) -> None:
        """Called once per measured state, before its command is computed (estimators)."""

    # -- common -----------------------------------------------------------------------------------
    def _weight_vectors(self, weights: Any) -> tuple[np.ndarray, np.ndarray]:
        w = self.config.solver_weights(weights)
        W, WN = w.stage_vector(), w.terminal_vector()
        if self.clearance_active:
            W = np.append(W, self.config.clearance_prices[1])
        return W, WN

    def _make_solver(self, weights: Any) -> RTISolver | IpoptOCPSolver:
        W, WN = self._weight_vectors(weights)
        if self.config.backend == "ipopt":
            return IpoptOCPSolver(self.ocp, W, WN)
        return RTISolver(self.ocp, W, WN, self.config.solver)

    def reset(self, seed: int | None = None) -> None:
        """Drop the warm start and everything remembered from the episode (the controller is
        deterministic; ``seed`` is accepted for the common interface)."""
        self.solver.reset()
        self.normal.reset()
        if self.obstacles is not None:
            self.obstacles.reset()
        self.last_clearance = float("nan")
        self._lookup = None
        self._last_q = None
        self._ahead = False
        self.last_stats = SolveStats()
        self.last_command = None
        self._last_solve = None
        self._prepared_params = None
        self._prediction_offset = None

    def set_weights(self, weights: Any) -> None:
        """Switch weights: a weight object of the config's class or a set name. The RTI solver
        takes them without recompiling (they are runtime inputs of the QP data); IPOPT's NLP has
        them built in, so it is rebuilt."""
        sets = self.config.WEIGHT_SETS
        w = sets.get(weights) if isinstance(weights, str) else weights
        wcls = self.config.WEIGHTS
        if not isinstance(w, wcls):
            raise ValueError(f"weights must be {wcls.__name__} or one of {list(sets)}, got {weights!r}")
        if isinstance(self.solver, IpoptOCPSolver):
            self.solver = self._make_solver(w)
        else:
            self.solver.set_weights(*self._weight_vectors(w))
        self._ahead = False   # the prepared QP has the old weights

    def _align(self, state: np.ndarray) -> np.ndarray:
        """``state`` with its quaternion in the hemisphere of the previous step's: q and -q are
        the same attitude, but the warm-started plan is linearised around one of them, and a
        simulator may return the other mid-flight."""
        if self._last_q is not None and float(np.dot(state[6:10], self._last_q)) < 0.0:
            state = np.concatenate([state[0:6], -state[6:10]])
        self._last_q = state[6:10].copy()
        return state

    def _solve(self, state: np.ndarray, params: np.ndarray) -> np.ndarray:
        """One full real-time iteration (prepare, feedback, shift) or one IPOPT solve for an
        aligned drone state."""
        xm = self.model_state(state)
        self._last_solve = (xm, params)
        solver = self.solver
        if isinstance(solver, RTISolver):
            if not solver.initialized:
                solver.initialize(xm)
            solver.prepare(self._with_clearance(params, xm))
            u = solver.feedback(xm)
        else:
            u = solver.solve(xm, self._with_clearance(params, xm))
        self._ahead = False
        return self._finish_step(u)

    def _finish_step(self, u: np.ndarray) -> np.ndarray:
        self._prediction_offset = None      # a new plan: its own prediction holds until told otherwise
        for _ in range(self.shifts_per_step):
            self.solver.shift()
        self.last_stats = self.solver.last_stats
        self.last_command = u[:self._nu] if self.clearance_active else u
        return self.last_command

    def _with_clearance(self, params: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """The solver's parameters: ``params``, or with the clearance on the (N+1, np + 4)
        stage-wise array of ``params`` and each stage's half-space [n, n^T c + d_min] from the
        nearest mesh points of the plan's positions (stage 0: ``x0``'s)."""
        if not self.clearance_active:
            return params
        P = self._stage_params
        npar = self.base_ocp.np
        P[:, :npar] = params
        solver = self.solver
        if isinstance(solver, RTISolver) and solver.initialized:
            pos = solver.state_view[self._query_stages, 0:3]   # (a copy: fancy indexing)
            pos[self._query_stages == 0] = x0[0:3]
        else:
            try:
                xs = self.ocp.unpack(solver.iterate)[0]
                pos = xs[self._query_stages, 0:3]
                pos[self._query_stages == 0] = x0[0:3]
            except RuntimeError:          # no plan yet (IPOPT before its first solve)
                pos = np.tile(x0[0:3], (len(self._query_stages), 1))
        last = self._lookup
        cfg = self.config
        if (last is None or last[3] != self.obstacles.index or last[4] < 0.5 * (cfg.d_min + cfg.d_ref)
                or float(np.abs(pos - last[0]).max()) > cfg.clearance_refresh):
            c, d, n = self.obstacles.closest(pos)
            self.last_clearance = float(d[0]) if self._query_stages[0] == 0 else float("nan")
            k = self._stage_query
            # each stage's half-space [n, n^T c + d_min + back-off], kept until the next look-up
            self._lookup = last = (pos, c, n, self.obstacles.index, float(d.min()), n[k],
                                   np.einsum("ij,ij->i", n, c)[k] + (cfg.d_min + cfg.clearance_backoff))
        P[:, npar:npar + 3] = last[5]
        P[:, npar + 3] = last[6]
        return P

    @property
    def predicted_state(self) -> np.ndarray | None:
        """The plan's drone state at the next control step (its first stage after the shift);
        None before the first step and when the control period is shorter than a stage."""
        if self.last_command is None or not self.shifts_per_step:
            return None
        if self._prediction_offset is not None:
            return self.solver.iterate[:NX] + self._prediction_offset
        return self.solver.iterate[:NX]

    def note_applied_action(self, action: Any) -> None:
        """Tell the controller which normalised env action was applied after its last :meth:`act`.

        Why: in *shadow* mode (the controller labels the states another policy flies into, as in
        DAgger) the executed command is not the controller's own, but :attr:`predicted_state` - what
        the disturbance observer of :meth:`on_measurement` compares the next measurement with, and
        where ``prepare_ahead`` linearises - is the plan's, which assumes its own command. This
        shifts that prediction by the model's answer to the difference: ``F(x, applied) - F(x, own)``
        over the control period (``F`` the OCP's dynamics with the parameters of the last solve,
        ``x`` the measured model state, both commands as the env executes them, saturated at the
        bounds). So the observer keeps seeing only the unmodelled acceleration whatever flies.
        With ``action`` equal to the controller's own action the shift is exactly zero and nothing
        changes; call it after every :meth:`act` whose command may not have been applied (a
        prepared-ahead linearisation has already used the unshifted prediction)."""
        if self.last_command is None or self._last_solve is None or not self.shifts_per_step:
            return
        applied = self.scaling.to_command(np.asarray(action, dtype=np.float64))
        own = self.scaling.to_command(self.scaling.to_action(self.last_command))
        x, params = self._last_solve
        f = self.base_ocp.dynamics
        xa, xo = x, x
        for _ in range(self.shifts_per_step):
            xa = np.asarray(f(xa, applied, params), dtype=float).ravel()
            xo = np.asarray(f(xo, own, params), dtype=float).ravel()
        offset = (xa - xo)[:NX]
        self._prediction_offset = offset if np.any(offset) else None

    def command_for(self, state: np.ndarray, params: np.ndarray) -> np.ndarray:
        """Physical command [p, q, r, T] for a drone state and the OCP's parameters directly
        (one full step; for tests and callers that build their own parameters)."""
        return self._solve(self._align(np.asarray(state, dtype=float)), params)

    def command(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Physical command [p, q, r, T] for an observation (see the module docstring for the
        schedule of preparation and feedback)."""
        t0 = time.perf_counter()
        o = check_observation(obs)
        x = self._align(state_from_observation(o))
        self.on_measurement(x)
        if self.obstacles is not None:
            self.obstacles.update(o["point"], float(o["progress"][0]) if "progress" in o else None)
        if self._ahead:                      # only the feedback QP stands between obs and command
            u = self.solver.feedback(self.model_state(x))
            self._last_solve = (self.model_state(x), self._prepared_params)
            self._ahead = False
            latency = (time.perf_counter() - t0) * 1e3
            u = self._finish_step(u)
        else:
            nxy = self.normal.update(o["normal"], x[0:3], o["point"])
            u = self._solve(x, self.parameters(o, x, nxy))
            latency = (time.perf_counter() - t0) * 1e3
        self.last_stats.latency_ms = latency
        if self.config.prepare_ahead and isinstance(self.solver, RTISolver) and self.solver.initialized:
            self._prepare_next(o, x)
        return u

    def _prepare_next(self, obs: Mapping[str, np.ndarray], state: np.ndarray) -> None:
        """Linearise for the next control step at the predicted state, with the parameters
        predicted for it (the point moved on by its velocity over one control period)."""
        predicted = self.predicted_state
        if predicted is None:
            predicted = state
        nxt = {**obs, "point": obs["point"] + obs["point_velocity"] * self.config.control_dt,
               "position": predicted[0:3], "velocity_body": predicted[3:6], "quaternion": predicted[6:10]}
        nxy = self.normal.update(nxt["normal"], predicted[0:3], nxt["point"])
        self._prepared_params = self.parameters(nxt, predicted, nxy)
        self.solver.prepare(self._with_clearance(self._prepared_params, self.model_state(predicted)))
        self._ahead = True

    def act(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Normalised env action in [-1, 1]^4 for one observation."""
        return self.action_of(self.command(obs))

    def action_of(self, c: np.ndarray) -> np.ndarray:
        """The normalised env action of a physical command this policy computed."""
        # ActionScaling.to_action without its input check (the command is the solver's own finite
        # (4,) float64): the same operations on the same numbers, so the same float32 action
        scaling = self.scaling
        if self._action_map is None or self._action_map[0] is not scaling:
            lo = scaling.lower
            self._action_map = (scaling, lo, scaling.upper - lo)
        _, lo, span = self._action_map
        return np.clip(2.0 * (c - lo) / span - 1.0, -1.0, 1.0).astype(np.float32)

    @property
    def predicted_states(self) -> np.ndarray:
        """The current plan's drone states (N+1, 10) (shifted after each act; an augmented OCP
        state is cut to the drone's)."""
        return self.ocp.unpack(self.solver.iterate)[0][:, :NX]

    @staticmethod
    def world_velocity(state: np.ndarray) -> np.ndarray:
        """R(q) v_B of a drone state."""
        return quat_to_rotmat_np(state[6:10]) @ state[3:6]
