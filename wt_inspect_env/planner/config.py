"""Planner configuration (validated on construction)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from ..util.validation import (
    check_array,
    check_choice,
    check_field_types,
    check_positive,
    check_range,
    check_unknown_options,
)

STANDOFF_MODES = ("horizontal", "normal")
#: d_min / d_ref: the flight's minimum distance to the structure as a share of the stand-off (3 m at the
#: paper's 7 m). The one home of that number: the planner's default clearance, the MPCs' clearance
#: constraint, the harness's clearance metrics and the reference's allowance all derive from it.
D_MIN_RATIO = 3.0 / 7.0
#: the deceleration [m/s^2] a flight near the structure counts on to stop: the MPCs' clearance
#: constraint adds the stopping distance v^2 / (2 a) at the approach speed v, and the reference's
#: approach from a far start moves no faster than sqrt(2 a (d_ref - d_min)), at which a drone on its
#: stand-off pose can stop short of d_min.
CLEARANCE_BRAKE = 3.0
#: the paper's rotor turn between its two phases [deg] (the planner's default, and the env's on the
#: paper's turbine).
PAPER_ROTOR_TURN_DEG = 120.0
#: max_end_trim / d_ref by default (see ``max_end_trim``).
END_TRIM_RATIO = 0.375


@dataclass(frozen=True)
class PlannerConfig:
    """Options of :func:`~wt_inspect_env.planner.plan_inspection` (SI units, degrees as named).

    standoff
        d_ref: distance from the inspection point to the drone (the paper's 7 m).
    standoff_mode
        ``"horizontal"`` (default): the stand-off position is ``p + d_ref n_xy / |n_xy|``, the pose
        that VT-NMPC (horizontal distance d and region of interest r = a_xy . n with n_z forced to
        0) and the baselines track, so tour lengths and clearances are those of the flight.
        ``"normal"``: ``p + d_ref n`` along the 3-D normal, the issue's literal wording; identical
        for the vertical faces of a blade, different for tilted faces.
    spacing
        Distance between consecutive path samples, measured along the stand-off (drone) path.
    start
        Take-off point; ``None``: on the ground in front of the rotor, below the front faces'
        stand-off plane.
    rotor_turn_deg
        Rotor turn between phase 1 and phase 2 (right-handed about the rotor axis; the paper's 120
        deg); ``None``: the planner chooses the rotor positions (none, one or two turns) with the
        least total flight (see :mod:`.plan`).
    rotor_turn_step_deg
        With ``rotor_turn_deg=None``: the candidate turns are the multiples of this in (-180, 180].
    max_down_deg, max_up_deg
        A level camera inspects a surface in a phase only if its normal's elevation lies in
        ``[-max_down_deg, max_up_deg]``; other surfaces are deferred to phase 2 (the inverted Y's
        two faces looking 60 deg down, whose stand-offs would lie under the rotor, inside the
        other lower blade). Surfaces still outside the band after the turn are an error.
    clearance
        Minimum distance from every stand-off position of the path to the turbine (blades, hub,
        tower); transitions detour to keep it, inspection stand-offs that violate it are trimmed at
        their ends or make the surface uninspectable in that rotor position. ``None`` (default):
        the flight's d_min, :data:`D_MIN_RATIO` x standoff (3 m at 7 m) - the distance the MPCs'
        clearance constraint keeps, so that the path never asks a drone to pass where its
        controller may not (with the check margin ``check_step / 2`` the path clears d_min + 0.125 m;
        a path planned with less leaves gaps, e.g. between a blade edge and the tower, where the
        constraint holds the drone and the closed-loop reference waits).
    check_step
        Sampling step of the clearance checks along the stand-off path (each sample must clear
        ``clearance + check_step / 2``, which makes the continuous path clear ``clearance``);
        ``None``: standoff / 28 (0.25 m at 7 m).
    cluster_angle_deg
        A blade triangle whose normal leans more than this out of the blade's cross-section plane
        faces the root or the tip (a cap) and belongs to no inspection surface (see
        :mod:`.clustering`; surfaces are the four sectors of each blade's section).
    max_end_trim
        How far [m] an end of a surface's centre line may be moved inwards when the stand-off
        at that end is not clear of the turbine (e.g. the root of a back face whose stand-off
        passes behind a large hub); ``None``: :data:`END_TRIM_RATIO` x the stand-off (2.6 m at
        7 m). The trimmed end should stay in the camera's image from the new end node: the default
        camera's image is 0.98 x 0.65 d_ref (6.9 x 4.6 m at 7 m), so 0.375 d_ref keeps the root row
        inside its half width, and inside its half height up to 0.33 d_ref. That much is needed
        since the clearance is d_min: the NREL 5-MW blade's root faces beside its 3 m hub need
        2.0-2.6 m at 3 m clearance (a quarter of d_ref, enough at the former 2 m, left no rotor
        position for some). A surface that needs more trimming, or whose stand-off is blocked
        away from its ends, is not inspectable in that rotor position. 0 disables trimming.
    """

    standoff: float = 7.0
    spacing: float = 0.1
    start: tuple[float, float, float] | None = None
    rotor_turn_deg: float | None = PAPER_ROTOR_TURN_DEG
    rotor_turn_step_deg: float = 10.0
    max_down_deg: float = 45.0
    max_up_deg: float = 75.0
    clearance: float | None = None
    check_step: float | None = None
    standoff_mode: str = "horizontal"
    cluster_angle_deg: float = 20.0
    max_end_trim: float | None = None

    def __post_init__(self) -> None:
        check_field_types(self, "planner ")
        def put(name: str, value: Any) -> None:
            object.__setattr__(self, name, value)

        put("standoff", check_positive("standoff", self.standoff))
        put("spacing", check_positive("spacing", self.spacing))
        if not 1e-3 <= self.spacing <= self.standoff:
            raise ValueError(f"spacing must lie in [0.001, standoff={self.standoff}] m, got {self.spacing!r}")
        if self.start is not None:
            s = check_array("start", self.start, (3,))
            put("start", (float(s[0]), float(s[1]), float(s[2])))
        if self.rotor_turn_deg is not None:
            put("rotor_turn_deg", check_range("rotor_turn_deg", self.rotor_turn_deg, -360.0, 360.0))
        put("rotor_turn_step_deg", check_range("rotor_turn_step_deg", self.rotor_turn_step_deg, 1.0, 60.0))
        put("max_down_deg", check_range("max_down_deg", self.max_down_deg, 0.0, 89.0))
        put("max_up_deg", check_range("max_up_deg", self.max_up_deg, 0.0, 89.0))
        if self.clearance is None:
            put("clearance", D_MIN_RATIO * self.standoff)
        put("clearance", check_positive("clearance", self.clearance))
        if self.clearance >= self.standoff:
            raise ValueError(f"clearance must be below standoff ({self.standoff}), got {self.clearance!r}")
        if self.check_step is None:
            put("check_step", self.standoff / 28.0)
        put("check_step", check_positive("check_step", self.check_step))
        if self.check_step > self.clearance:
            raise ValueError(f"check_step must not exceed clearance ({self.clearance}), got {self.check_step!r}")
        check_choice("standoff_mode", self.standoff_mode, STANDOFF_MODES)
        put("cluster_angle_deg", check_range("cluster_angle_deg", self.cluster_angle_deg, 1.0, 60.0))
        if self.max_end_trim is not None:
            put("max_end_trim", check_range("max_end_trim", self.max_end_trim, 0.0, self.standoff))

    @property
    def end_trim_limit(self) -> float:
        """``max_end_trim`` resolved (:data:`END_TRIM_RATIO` x the stand-off when ``None``)."""
        return END_TRIM_RATIO * self.standoff if self.max_end_trim is None else self.max_end_trim

    @classmethod
    def from_options(cls, options: Mapping[str, Any], base: "PlannerConfig | None" = None) -> "PlannerConfig":
        """``base`` (or the defaults) with ``options`` replaced; unknown keys raise ``ValueError``."""
        check_unknown_options("planner", options.keys(), [f.name for f in dataclasses.fields(cls)])
        return dataclasses.replace(base, **options) if base is not None else cls(**dict(options))
