"""The runner's own safety limits, checked on every state the vehicle reports (project frame).

Why on top of the environment's own terminations (collision, leaving the working volume): those
end a *simulated* episode after the fact; on a vehicle the limits must trigger the hold before the
drone gets there, with margins the operator sets for the site. Each check returns the reason as a
short string (``geofence_box``, ``geofence_clearance``, ``max_speed``) that ends up in the run
file's ``termination`` as ``hold:<reason>``.

* geofence box: the mission's working volume (turbine and planned path, grown by ``box_margin``),
  grown to hold the start position, floored at ``min_altitude`` above the ground;
* geofence clearance: distance from the drone's centre to the turbine mesh of the active rotor
  position (:class:`~wt_inspect_env.planner.proximity.TurbineProximity`, as the MPCs use it) at least
  ``min_clearance``;
* speed: world speed at most ``max_speed``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from wt_inspect_env.planner.proximity import TurbineProximity
from wt_inspect_env.util.validation import check_positive


@dataclass(frozen=True)
class SafetyConfig:
    """Limits of one flight (``None``: derived from the mission - see :meth:`resolved`).

    ``box_margin`` [m] around the mission's volume (default: the environment's working margin);
    ``min_clearance`` [m] to the mesh (default half the stand-off distance); ``max_speed`` [m/s];
    ``min_altitude`` [m] above the ground plane; ``state_timeout`` [s] without a fresh estimate and
    ``link_timeout`` [s] without a HEARTBEAT before holding; ``command_timeout`` [s] without a new
    command from the policy before the streamer holds by itself.
    """

    box_margin: float | None = None
    min_clearance: float | None = None
    max_speed: float = 5.0
    min_altitude: float = 1.0
    state_timeout: float = 0.25
    link_timeout: float = 1.5
    command_timeout: float = 0.15

    def __post_init__(self) -> None:
        for name in ("box_margin", "min_clearance"):
            if getattr(self, name) is not None:
                check_positive(f"safety {name}", getattr(self, name), allow_zero=True)
        for name in ("max_speed", "state_timeout", "link_timeout", "command_timeout"):
            check_positive(f"safety {name}", getattr(self, name))
        check_positive("safety min_altitude", self.min_altitude, allow_zero=True)

    def resolved(self, standoff: float, working_margin: float) -> "SafetyConfig":
        """The config with its defaults that depend on the task filled in (box margin, clearance [m])."""
        return SafetyConfig(working_margin if self.box_margin is None else self.box_margin,
                            0.5 * standoff if self.min_clearance is None else self.min_clearance,
                            self.max_speed, self.min_altitude, self.state_timeout, self.link_timeout,
                            self.command_timeout)


class Geofence:
    """The box, clearance and speed checks of :class:`SafetyConfig` for one mission."""

    def __init__(self, mission: Any, config: SafetyConfig, start: Any, ground_height: float = 0.0) -> None:
        assert config.box_margin is not None and config.min_clearance is not None, "resolve the config first"
        self.config = config
        lo, hi = mission.working_volume(config.box_margin)
        start = np.asarray(start, float)
        self.lo = np.minimum(lo, start - config.box_margin)
        self.hi = np.maximum(hi, start + config.box_margin)
        self.lo[2] = ground_height + config.min_altitude
        self.proximity = TurbineProximity.from_mission(mission)
        self.last_clearance = math.inf

    def reset(self) -> None:
        """Start a new flight (forget the proximity queries' warm start)."""
        self.proximity.reset()

    def check(self, position: np.ndarray, velocity_world: np.ndarray, point: np.ndarray | None = None) -> str | None:
        """The first limit the state breaks, or None. ``point``: the current inspection point
        (selects the rotor position whose mesh applies, as for the MPCs)."""
        p = np.asarray(position, float)
        if np.any(p < self.lo) or np.any(p > self.hi):
            return "geofence_box"
        if point is not None:
            self.proximity.update(point)
        _, d, _ = self.proximity.closest(p[None])
        self.last_clearance = float(d[0])
        if self.last_clearance < self.config.min_clearance:
            return "geofence_clearance"
        if float(np.linalg.norm(velocity_world)) > self.config.max_speed:
            return "max_speed"
        return None
