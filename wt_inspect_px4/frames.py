"""PX4's frames (local NED, body FRD) <-> the project's frames (z-up world W, body FLU), and the site.

The project (:mod:`wt_inspect_env.physics.dynamics`) uses a right-handed world with z up and gravity along
-z, a body frame x forward / y left / z up, quaternions (x, y, z, w) body-to-world, velocity in
body axes. PX4 uses a local North-East-Down frame, a Forward-Right-Down body frame and MAVLink
quaternions (w, x, y, z) body-to-NED. Between them:

* body: ``v_FLU = F v_FRD`` with ``F = diag(1, -1, -1)`` (a rotation by pi about body x), for
  velocities, body rates and forces alike;
* world: NED -> ENU swaps the first two axes and flips the third (``E``); the project's world is
  ENU turned about the vertical by ``yaw`` and shifted so the turbine sits where the site says:
  ``p_W = Rz(-yaw) E (p_NED - b_NED) + b_W``;
* attitude: ``R_W_FLU = Rz(-yaw) E R_NED_FRD F``.

Why a site frame and not just "use NED": the planner, the reference and every policy work in the
project's world around a turbine whose tower stands at ``TurbineSpec.position`` facing
``facing_deg``; the site says where that turbine is on the field, so the same plan flies there.

A :class:`Site` places the tower base either in the vehicle's local NED frame (``base_ned``) or
geodetically (``base_lla``: latitude, longitude [deg], altitude AMSL [m]; then the vehicle's
local origin - MAVLink GPS_GLOBAL_ORIGIN - is needed), and gives the compass heading of the rotor
axis (``heading_deg``, clockwise from north, the direction the rotor faces, as the turbine's
``facing_deg``). Geodetic positions are projected as PX4 does (azimuthal equidistant projection
about the origin, ``MapProjection`` in PX4's geo library), so a base given in latitude and
longitude lands where PX4's own estimator puts it.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from wt_inspect_env.util.validation import check_array, check_finite, check_range, check_unknown_options

EARTH_RADIUS_M = 6371000.0          # PX4's CONSTANTS_RADIUS_OF_EARTH (geo library)
F_FRD_FLU = np.diag([1.0, -1.0, -1.0])                                   # FRD <-> FLU (its own inverse)
E_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED <-> ENU (its own inverse)


def rz(angle: float) -> np.ndarray:
    """Right-handed rotation by ``angle`` [rad] about +z."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_wxyz_to_matrix(q: Any) -> np.ndarray:
    """Rotation matrix of a MAVLink quaternion (w, x, y, z); ValueError if it is not near unit."""
    q = check_array("quaternion", q, (4,))
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-2:
        raise ValueError(f"quaternion (w, x, y, z) must have unit norm, got norm {n:.4g} ({q.tolist()})")
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) of rotation matrix ``R``, with w >= 0 (MAVLink's order)."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)


def geodetic_to_ned(lat_deg: float, lon_deg: float, alt_m: float, origin: tuple[float, float, float]
                    ) -> np.ndarray:
    """NED position [m] of a point relative to the local origin (lat, lon [deg], alt [m]) by PX4's
    azimuthal equidistant projection (``MapProjection::project``); down = origin alt - alt."""
    lat0, lon0 = math.radians(origin[0]), math.radians(origin[1])
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    cos_dlon = math.cos(lon - lon0)
    arg = min(1.0, max(-1.0, math.sin(lat0) * math.sin(lat) + math.cos(lat0) * math.cos(lat) * cos_dlon))
    c = math.acos(arg)
    k = 1.0 if abs(c) < 1e-12 else c / math.sin(c)
    north = k * (math.cos(lat0) * math.sin(lat) - math.sin(lat0) * math.cos(lat) * cos_dlon) * EARTH_RADIUS_M
    east = k * math.cos(lat) * math.sin(lon - lon0) * EARTH_RADIUS_M
    return np.array([north, east, origin[2] - alt_m])


def ned_to_geodetic(ned: Any, origin: tuple[float, float, float]) -> tuple[float, float, float]:
    """Inverse of :func:`geodetic_to_ned` (PX4's ``MapProjection::reproject``): (lat, lon [deg], alt [m])."""
    n, e, d = (float(v) for v in ned)
    lat0, lon0 = math.radians(origin[0]), math.radians(origin[1])
    xr, yr = n / EARTH_RADIUS_M, e / EARTH_RADIUS_M
    c = math.hypot(xr, yr)
    if c < 1e-15:
        return origin[0], origin[1], origin[2] - d
    sc, cc = math.sin(c), math.cos(c)
    lat = math.asin(cc * math.sin(lat0) + xr * sc * math.cos(lat0) / c)
    lon = lon0 + math.atan2(yr * sc, c * math.cos(lat0) * cc - xr * math.sin(lat0) * sc)
    return math.degrees(lat), math.degrees(lon), origin[2] - d


@dataclass(frozen=True)
class Site:
    """Where the turbine stands on the field (see the module docstring).

    Exactly one of ``base_ned`` (tower base in the vehicle's local NED frame [m]) and ``base_lla``
    (latitude [deg], longitude [deg], altitude AMSL [m] of the tower base). ``heading_deg``:
    compass heading of the rotor axis (clockwise from north, where the rotor faces).
    """

    heading_deg: float
    base_ned: tuple[float, float, float] | None = None
    base_lla: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        check_finite("site heading_deg", self.heading_deg)
        if (self.base_ned is None) == (self.base_lla is None):
            raise ValueError("site needs exactly one of base_ned [north, east, down] and base_lla "
                             f"[lat, lon, alt], got base_ned={self.base_ned!r}, base_lla={self.base_lla!r}")
        if self.base_ned is not None:
            object.__setattr__(self, "base_ned", tuple(check_array("site base_ned", self.base_ned, (3,)).tolist()))
        if self.base_lla is not None:
            lla = check_array("site base_lla", self.base_lla, (3,))
            check_range("site base_lla[0] (latitude)", lla[0], -90.0, 90.0)
            check_range("site base_lla[1] (longitude)", lla[1], -180.0, 180.0)
            object.__setattr__(self, "base_lla", tuple(lla.tolist()))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "Site":
        """The site from its JSON object (``heading_deg`` and one of ``base_ned`` / ``base_lla``)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"site must be a JSON object, got {data!r}")
        check_unknown_options("site", data.keys(), ("heading_deg", "base_ned", "base_lla"))
        if "heading_deg" not in data:
            raise ValueError("site is missing heading_deg (compass heading of the rotor axis, deg)")
        return cls(**dict(data))

    @classmethod
    def parse(cls, text: str) -> "Site":
        """A site from JSON text or from a JSON file's path (data only: nothing in it is run)."""
        src = text
        if not text.lstrip().startswith("{"):
            path = Path(text)
            try:
                src = path.read_text()
            except OSError as exc:
                raise ValueError(f"--site {text!r} is neither a JSON object nor a readable file: "
                                 f"{exc.strerror or exc}") from None
        try:
            data = json.loads(src)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--site is not valid JSON: {exc}") from None
        return cls.from_mapping(data)

    @property
    def needs_origin(self) -> bool:
        """Whether the vehicle's geodetic local origin is needed to place the turbine."""
        return self.base_lla is not None

    def frame(self, turbine_position: Any, facing_deg: float,
              origin: tuple[float, float, float] | None = None) -> "SiteFrame":
        """The transform for a turbine whose tower base is at ``turbine_position`` (x, y) in the
        project's world, facing ``facing_deg`` (``TurbineSpec.position``, ``facing_deg``)."""
        if self.base_lla is not None:
            if origin is None:
                raise ValueError("site base_lla needs the vehicle's local origin (GPS_GLOBAL_ORIGIN), none given")
            base = geodetic_to_ned(*self.base_lla, origin)
        else:
            base = np.asarray(self.base_ned, dtype=float)
        pos = check_array("turbine position", turbine_position, (None,))
        base_w = np.array([pos[0], pos[1], 0.0])
        # Angle of the rotor axis from east, counter-clockwise (ENU), minus its angle in W.
        yaw = math.radians((90.0 - self.heading_deg) - check_finite("facing_deg", facing_deg))
        return SiteFrame(yaw=math.atan2(math.sin(yaw), math.cos(yaw)), base_ned=base, base_w=base_w)


@dataclass(frozen=True)
class SiteFrame:
    """The rigid transform between PX4's local NED frame and the project's world (module docstring).

    ``yaw`` [rad]: rotation of W relative to ENU about up; ``base_ned`` / ``base_w``: the tower
    base in each frame. Every method has its inverse here, and the tests check both directions
    against rotations worked out by hand.
    """

    yaw: float
    base_ned: np.ndarray
    base_w: np.ndarray

    @property
    def R_w_ned(self) -> np.ndarray:
        """Rotation from PX4's local NED frame to the project's world frame W."""
        return rz(-self.yaw) @ E_ENU_NED

    def position_to_project(self, p_ned: Any) -> np.ndarray:
        """A position in PX4's local NED frame [m] -> the project's world frame W."""
        return self.R_w_ned @ (np.asarray(p_ned, float) - self.base_ned) + self.base_w

    def position_to_ned(self, p_w: Any) -> np.ndarray:
        """A position in the project's world frame W [m] -> PX4's local NED frame."""
        return self.R_w_ned.T @ (np.asarray(p_w, float) - self.base_w) + self.base_ned

    def vector_to_project(self, v_ned: Any) -> np.ndarray:
        """A free world vector (velocity, acceleration): NED -> W."""
        return self.R_w_ned @ np.asarray(v_ned, float)

    def vector_to_ned(self, v_w: Any) -> np.ndarray:
        """A free world vector (velocity, acceleration): W -> NED."""
        return self.R_w_ned.T @ np.asarray(v_w, float)

    def attitude_to_project(self, q_wxyz: Any) -> np.ndarray:
        """MAVLink quaternion (w, x, y, z) FRD -> NED  ->  project quaternion (x, y, z, w) FLU -> W."""
        R = self.R_w_ned @ quat_wxyz_to_matrix(q_wxyz) @ F_FRD_FLU
        return Rotation.from_matrix(R).as_quat()

    def attitude_to_ned(self, q_xyzw: Any) -> np.ndarray:
        """Project quaternion (x, y, z, w) FLU -> W  ->  MAVLink quaternion (w, x, y, z) FRD -> NED."""
        q = check_array("quaternion", q_xyzw, (4,))
        R = self.R_w_ned.T @ Rotation.from_quat(q).as_matrix() @ F_FRD_FLU
        return matrix_to_quat_wxyz(R)


def body_frd_to_flu(v: Any) -> np.ndarray:
    """A body vector (velocity, rates, force) FRD -> FLU; the same matrix maps FLU -> FRD."""
    return F_FRD_FLU @ np.asarray(v, float)


body_flu_to_frd = body_frd_to_flu
