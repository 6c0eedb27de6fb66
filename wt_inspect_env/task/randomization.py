"""Domain randomisation: per-episode draws of the airframe, the sensors and the command link.

A policy trained on one exact model meets a real drone whose mass, inertia, drag, rotor thrust,
yaw-torque coefficient and motor lag are known only to some tens of percent, whose state
estimate is noisy and whose commands arrive a few control steps late. :class:`RandomizationConfig`
gives each of these a range; with ``EnvConfig(randomization=...)`` (off by default) every
``reset`` draws one value per range from the environment's ``np_random`` - so the same seed gives
the same draws - and ``info["randomization"]`` reports them.

What a draw changes, and what it deliberately does not:

* the *plant* (what PyBullet integrates): mass, inertia, drag, thrust, torque coefficient and motor
  time constant - :meth:`~wt_inspect_env.world.sim.QuadrotorSim.set_plant`;
* not the *controller side*: the action scaling (hover command, thrust bounds), the rate loop's
  gains and inertia and the mixer's allocation keep the nominal airframe, as on a real drone whose
  autopilot was tuned for the nominal model. A heavier draw therefore sinks under the nominal
  hover command - the mismatch a robust policy has to absorb;
* observation noise is added to the drone's own state entries only (position, body velocity,
  attitude, body rates); the reference entries (point, normal, ...) and the metrics stay exact;
* command latency holds each command back by a whole number of control steps (the first ones
  are the nominal hover command).

The default ranges are meant for a ~1 kg quadrotor (the ``lab250`` preset) and as relative
factors fit the ``matrice100`` too; why each is what it is, is in the field docs below.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..physics.quadrotor import QuadrotorParams
from ..util.validation import check_finite, coerce_config

Range = tuple[float, float]
# Upper bound of ``latency_steps``: 1000 control steps are 10 s at the default 100 Hz - a command
# link slower than that is no control loop - and each step of latency is a queued command
# (10**9 would exhaust memory at the first reset).
MAX_LATENCY_STEPS = 1000

SCALE_FIELDS = ("mass", "inertia", "drag", "thrust", "torque_coeff", "motor_time_constant")
NOISE_FIELDS = ("position_noise", "velocity_noise", "attitude_noise", "rate_noise")


def _check_range(name: str, value: Any, *, positive: bool, integer: bool = False) -> tuple:
    """A validated ``(lo, hi)`` pair: finite, lo <= hi, positive scale factors or non-negative
    standard deviations / step counts; one-line ``ValueError`` naming the field otherwise."""
    label = f"randomization {name}"
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise ValueError(f"{label} must be a (low, high) pair, got {value!r}")
    if integer:
        if any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in value):
            raise ValueError(f"{label} must be a (low, high) pair of integers [control steps], got {value!r}")
        lo, hi = int(value[0]), int(value[1])
    else:
        if any(isinstance(v, (bool, np.bool_)) for v in value):
            raise ValueError(f"{label} must be a (low, high) pair of numbers, got {value!r}")
        lo, hi = check_finite(label, value[0]), check_finite(label, value[1])
    if (positive and lo <= 0) or lo < 0:
        kind = "positive" if positive else "non-negative"
        raise ValueError(f"{label} must be {kind}, got {value!r}")
    if hi < lo:
        raise ValueError(f"{label} must have low <= high, got {value!r}")
    if integer and hi > MAX_LATENCY_STEPS:
        raise ValueError(f"{label} must be at most {MAX_LATENCY_STEPS} control steps, got {value!r}")
    return (lo, hi)


@dataclass(frozen=True)
class RandomizationConfig:
    """Per-episode ranges, each a ``(low, high)`` pair drawn uniformly; ``(1, 1)`` (scales) or
    ``(0, 0)`` (noise, latency) switches one off.

    Scale factors of the nominal :class:`~wt_inspect_env.physics.quadrotor.QuadrotorParams`:

    * ``mass`` 0.9-1.1: a weighed airframe is known to grams, but payload and battery change it:
      +-10 % on the 1.09 kg lab quadrotor is about +-110 g, a battery size up or down.
    * ``inertia`` 0.8-1.2, drawn per axis: the presets' inertias are estimates from a point-mass
      and box model (see their ``source``), less certain than the mass.
    * ``drag`` 0.7-1.3, one factor for the linear rotor drag and one for the quadratic body drag:
      both are estimates (only the M100's linear drag comes from the authors' Gazebo model), the
      least known parameters.
    * ``thrust`` 0.95-1.05: thrust produced per newton the mixer commands; the autopilot's
      battery-voltage compensation leaves a few percent of propeller and battery variation.
    * ``torque_coeff`` 0.8-1.2: the propeller's yaw-torque-to-thrust ratio, from propeller tables
      rather than measured.
    * ``motor_time_constant`` 0.75-1.25: the motor lag is an estimate (20 ms on the lab drone).

    Observation noise, per-episode standard deviations of zero-mean Gaussian noise added every step:

    * ``position_noise`` 0-0.02 m: RTK-GNSS / motion-capture-grade position (centimetres);
    * ``velocity_noise`` 0-0.05 m/s: an estimator's velocity;
    * ``attitude_noise`` 0-0.01 rad (0.6 deg), a random small rotation of the attitude;
    * ``rate_noise`` 0-0.02 rad/s: filtered MEMS gyro rates.

    ``latency_steps`` 0-2 (integers, inclusive): whole control steps each command is held back
    (0-20 ms at 100 Hz: an offboard link's typical delay).
    """

    mass: Range = (0.9, 1.1)
    inertia: Range = (0.8, 1.2)
    drag: Range = (0.7, 1.3)
    thrust: Range = (0.95, 1.05)
    torque_coeff: Range = (0.8, 1.2)
    motor_time_constant: Range = (0.75, 1.25)
    position_noise: Range = (0.0, 0.02)
    velocity_noise: Range = (0.0, 0.05)
    attitude_noise: Range = (0.0, 0.01)
    rate_noise: Range = (0.0, 0.02)
    latency_steps: tuple[int, int] = (0, 2)

    def __post_init__(self) -> None:
        for name in SCALE_FIELDS:
            object.__setattr__(self, name, _check_range(name, getattr(self, name), positive=True))
        for name in NOISE_FIELDS:
            object.__setattr__(self, name, _check_range(name, getattr(self, name), positive=False))
        object.__setattr__(self, "latency_steps",
                           _check_range("latency_steps", self.latency_steps, positive=False, integer=True))

    def check_airframe(self, nominal: QuadrotorParams) -> None:
        """Refuse ranges whose extreme draw is not a valid airframe (e.g. a mass the rotors could
        not lift to 2 m g, which :class:`QuadrotorParams` requires), at construction rather than
        at some later reset."""
        try:
            plant(nominal, self.mass[1], (self.inertia[0],) * 3, self.drag[0], self.drag[0],
                  self.torque_coeff[0], self.motor_time_constant[0])
        except ValueError as exc:
            raise ValueError(f"randomization mass up to {self.mass[1]} x {nominal.mass} kg does not give a "
                             f"valid airframe: {exc}") from None


def coerce_randomization(value: Any, name: str = "randomization") -> RandomizationConfig | None:
    """``None``/``False`` (off), ``True`` (the default ranges), a dict of ranges or a
    :class:`RandomizationConfig`; a one-line ``ValueError`` naming ``name`` otherwise."""
    if value is None or value is False:
        return None
    if value is True:
        return RandomizationConfig()
    if isinstance(value, Mapping):   # JSON gives lists where the ranges are tuples
        value = {k: tuple(v) if isinstance(v, list) else v for k, v in value.items()}
    if isinstance(value, (Mapping, RandomizationConfig)):
        return coerce_config(name, value, RandomizationConfig)
    raise ValueError(f"{name} must be None/False (off), True (default ranges), a dict of ranges or a "
                     f"RandomizationConfig, got {value!r}")


def plant(nominal: QuadrotorParams, mass: float, inertia: tuple[float, float, float], rotor_drag: float,
          body_drag: float, torque_coeff: float, motor_time_constant: float) -> QuadrotorParams:
    """The nominal airframe with its physical parameters scaled by the given factors."""
    return nominal.replace(
        mass=nominal.mass * mass,
        inertia=tuple(float(j * s) for j, s in zip(nominal.inertia, inertia)),
        rotor_drag=tuple(float(d * rotor_drag) for d in nominal.rotor_drag),
        body_drag_area=tuple(float(d * body_drag) for d in nominal.body_drag_area),
        torque_coeff=nominal.torque_coeff * torque_coeff,
        motor_time_constant=nominal.motor_time_constant * motor_time_constant)


@dataclass(frozen=True)
class RandomizationDraw:
    """One episode's draw: the plant PyBullet integrates, its thrust factor, the noise levels, the
    latency and the seed of the episode's noise generator."""

    plant: QuadrotorParams
    thrust_scale: float
    position_noise: float
    velocity_noise: float
    attitude_noise: float
    rate_noise: float
    latency_steps: int
    noise_seed: int

    @property
    def has_noise(self) -> bool:
        """Whether any sensor-noise level of the draw is above zero."""
        return any(getattr(self, n) > 0 for n in NOISE_FIELDS)

    def to_info(self) -> dict[str, Any]:
        """The drawn values as plain numbers (for ``info["randomization"]``)."""
        q = self.plant
        return {"mass": q.mass, "inertia": tuple(q.inertia), "rotor_drag": tuple(q.rotor_drag),
                "body_drag_area": tuple(q.body_drag_area), "thrust_scale": self.thrust_scale,
                "torque_coeff": q.torque_coeff, "motor_time_constant": q.motor_time_constant,
                **{n: getattr(self, n) for n in NOISE_FIELDS}, "latency_steps": self.latency_steps}


def draw(config: RandomizationConfig, nominal: QuadrotorParams, rng: np.random.Generator) -> RandomizationDraw:
    """One episode's values from ``rng`` (in a fixed order, so a seed fixes them all)."""
    u = lambda r: float(rng.uniform(r[0], r[1]))  # noqa: E731
    mass = u(config.mass)
    inertia = (u(config.inertia), u(config.inertia), u(config.inertia))
    rotor_drag, body_drag = u(config.drag), u(config.drag)
    thrust, torque, tau = u(config.thrust), u(config.torque_coeff), u(config.motor_time_constant)
    noise = [u(getattr(config, n)) for n in NOISE_FIELDS]
    lo, hi = config.latency_steps
    latency = int(rng.integers(lo, hi + 1))
    seed = int(rng.integers(2**63 - 1))
    return RandomizationDraw(plant(nominal, mass, inertia, rotor_drag, body_drag, torque, tau), thrust,
                             *noise, latency, seed)


def noisy_state(obs: dict[str, np.ndarray], d: RandomizationDraw, rng: np.random.Generator) -> None:
    """Add the draw's observation noise to the drone-state entries of one observation, in place:
    Gaussian noise on position, body velocity and body rates; the attitude turned by a random
    small rotation (rotation vector ~ N(0, attitude_noise) per axis), kept a unit quaternion."""
    for key, sd in (("position", d.position_noise), ("velocity_body", d.velocity_noise),
                    ("body_rates", d.rate_noise)):
        if sd > 0:
            obs[key] = (obs[key] + rng.normal(0.0, sd, obs[key].shape)).astype(obs[key].dtype)
    if d.attitude_noise > 0:
        from scipy.spatial.transform import Rotation

        q = obs["quaternion"]
        turned = (Rotation.from_quat(np.asarray(q, float)) * Rotation.from_rotvec(rng.normal(0.0, d.attitude_noise, 3)))
        obs["quaternion"] = turned.as_quat().astype(q.dtype)
