"""Camera poses in the local ENU frame, built from vehicle attitude, position and the mount.

Frames (DESIGN.md):
* ENU: local east-north-up metres about the configured origin; the ground is z = 0.
* NED: north-east-down; MAVLink attitudes rotate the body FRD frame into NED.
* body: FRD (forward, right, down).
* gimbal: MAVLink gimbal protocol v2 (x forward along the optical axis, y right, z down).
  Euler angles of a mount or gimbal are z-y-x like the vehicle's: pitch -90 deg = nadir.
* cam: OpenCV optical frame (x image right, y image down, z along the optical axis).

Hand check: level vehicle heading north (yaw 0), nadir camera: the optical axis points down,
image right points east, image up points north. Heading 90 deg (east): image up points east
and image right points south.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from pdcov.core.rotations import R_from_euler_zyx, R_from_quat_wxyz, Rz, quat_wxyz_from_R
from pdcov.errors import ConfigError

R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""Maps NED vectors into ENU (its own inverse)."""

R_GIMBAL_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""Maps OpenCV optical-frame vectors into the gimbal frame: z_cam = x_gimbal (optical axis),
x_cam = y_gimbal (right), y_cam = z_gimbal (down)."""

_ORTHO_TOL = 1e-6
_EYE3 = np.eye(3)


@dataclass(frozen=True, slots=True)
class CameraPose:
    """Where a camera was and where it looked at one instant.

    R_enu_cam: 3x3 rotation mapping OpenCV optical-frame vectors into ENU.
    r_cam_enu: camera centre in ENU metres (z = height above the flat ground).
    t_s: time of the frame in seconds (autopilot clock), NaN when unknown.
    v_cam_enu_m_s: the camera centre's velocity in ENU m/s at t_s; None when unknown.
    omega_enu_rad_s: the camera's angular rate at t_s, in ENU rad/s (dR_enu_cam/dt =
        [omega]x R_enu_cam); None when unknown. Both feed motion blur (core/blur.py).
    """

    R_enu_cam: np.ndarray
    r_cam_enu: np.ndarray
    t_s: float = float("nan")
    v_cam_enu_m_s: np.ndarray | None = None
    omega_enu_rad_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        R = np.array(self.R_enu_cam, dtype=float)
        r = np.array(self.r_cam_enu, dtype=float).reshape(-1)
        if R.shape != (3, 3) or not np.isfinite(R).all():
            raise ValueError(f"R_enu_cam must be a finite 3x3 matrix, got {R!r}")
        # Orthonormal with det +1: R^T R = I and the third column is x cross y.
        (a, b, c), (d, e, f_), (g, h, i) = R.tolist()
        if (np.abs(R.T @ R - _EYE3).max() > _ORTHO_TOL
                or abs(b * f_ - c * e - g) + abs(c * d - a * f_ - h) + abs(a * e - b * d - i)
                > 3 * _ORTHO_TOL):
            raise ValueError("R_enu_cam must be a proper rotation (orthonormal, det +1)")
        if r.shape != (3,) or not np.isfinite(r).all():
            raise ValueError(f"r_cam_enu must be 3 finite numbers, got {r!r}")
        R.setflags(write=False)
        r.setflags(write=False)
        object.__setattr__(self, "R_enu_cam", R)
        object.__setattr__(self, "r_cam_enu", r)
        for key in ("v_cam_enu_m_s", "omega_enu_rad_s"):
            value = getattr(self, key)
            if value is None:
                continue
            a = np.array(value, dtype=float).reshape(-1)
            if a.shape != (3,) or not np.isfinite(a).all():
                raise ValueError(f"{key} must be 3 finite numbers or None, got {value!r}")
            a.setflags(write=False)
            object.__setattr__(self, key, a)

    @property
    def has_motion(self) -> bool:
        """Whether the velocity and the angular rate are both known."""
        return self.v_cam_enu_m_s is not None and self.omega_enu_rad_s is not None

    @classmethod
    def from_quat(cls, q_enu_cam_wxyz: np.ndarray, r_cam_enu: np.ndarray,
                  t_s: float = float("nan")) -> CameraPose:
        """From the unit quaternion (w, x, y, z) of R_enu_cam, as in the pose CSV."""
        return cls(R_from_quat_wxyz(q_enu_cam_wxyz), r_cam_enu, t_s)

    @property
    def q_enu_cam_wxyz(self) -> np.ndarray:
        return quat_wxyz_from_R(self.R_enu_cam)

    @property
    def optical_axis_enu(self) -> np.ndarray:
        """Unit vector of the optical axis (camera +z) in ENU."""
        return self.R_enu_cam[:, 2].copy()


class GimbalFrame(enum.Enum):
    """What a gimbal quaternion is relative to.

    EARTH: NED (yaw from north). VEHICLE: NED rotated about down by the vehicle's heading
    (MAVLink's "vehicle frame": roll and pitch still relative to the horizon). BODY: the
    vehicle body FRD frame (a servo mount's demand, see docs/autopilots.md).
    """

    EARTH = "earth"
    VEHICLE = "vehicle"
    BODY = "body"


# MAVLink GIMBAL_DEVICE_FLAGS bits (common.xml).
GIMBAL_FLAG_RETRACT = 1
GIMBAL_FLAG_NEUTRAL = 2
GIMBAL_FLAG_ROLL_LOCK = 4
GIMBAL_FLAG_PITCH_LOCK = 8
GIMBAL_FLAG_YAW_LOCK = 16
GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME = 32
GIMBAL_FLAG_YAW_IN_EARTH_FRAME = 64


def gimbal_frame_from_flags(flags: int) -> GimbalFrame:
    """The frame of a GIMBAL_DEVICE_ATTITUDE_STATUS quaternion by the message's definition.

    YAW_IN_VEHICLE_FRAME or YAW_IN_EARTH_FRAME decide; with neither set, YAW_LOCK means
    earth frame, else vehicle frame (the backwards-compatible rule of common.xml).
    """
    if flags & GIMBAL_FLAG_YAW_IN_EARTH_FRAME:
        return GimbalFrame.EARTH
    if flags & GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME:
        return GimbalFrame.VEHICLE
    return GimbalFrame.EARTH if flags & GIMBAL_FLAG_YAW_LOCK else GimbalFrame.VEHICLE


def heading_rad(R_ned_body: np.ndarray) -> float:
    """Vehicle heading (yaw from north, clockwise) of a body attitude, in radians."""
    return float(np.arctan2(R_ned_body[1, 0], R_ned_body[0, 0]))


def R_ned_gimbal_from_quat(q_wxyz: np.ndarray, frame: GimbalFrame,
                           R_ned_body: np.ndarray) -> np.ndarray:
    """Gimbal attitude in NED from a gimbal quaternion given in ``frame``."""
    R_ref_gimbal = R_from_quat_wxyz(q_wxyz)
    if frame is GimbalFrame.EARTH:
        return R_ref_gimbal
    if frame is GimbalFrame.VEHICLE:
        return Rz(heading_rad(R_ned_body)) @ R_ref_gimbal
    return R_ned_body @ R_ref_gimbal


@dataclass(frozen=True, slots=True)
class FixedMount:
    """A camera rigidly mounted on the body: Euler angles relative to FRD (pitch -90 = nadir)
    and the camera centre's offset from the vehicle's reference point, in FRD metres."""

    roll_rad: float = 0.0
    pitch_rad: float = -np.pi / 2
    yaw_rad: float = 0.0
    lever_arm_frd_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        values = (self.roll_rad, self.pitch_rad, self.yaw_rad, *self.lever_arm_frd_m)
        if len(self.lever_arm_frd_m) != 3 or not np.all(np.isfinite(values)):
            raise ConfigError(f"mount: angles and lever_arm_frd_m (3 values) must be finite, "
                              f"got roll_rad={self.roll_rad}, pitch_rad={self.pitch_rad}, "
                              f"yaw_rad={self.yaw_rad}, lever_arm_frd_m={self.lever_arm_frd_m}")

    @property
    def R_body_gimbal(self) -> np.ndarray:
        return R_from_euler_zyx(self.roll_rad, self.pitch_rad, self.yaw_rad)


def camera_pose(R_ned_body: np.ndarray, r_body_enu: np.ndarray, R_ned_gimbal: np.ndarray,
                lever_arm_frd_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
                t_s: float = float("nan")) -> CameraPose:
    """Camera pose from the vehicle attitude and position and the gimbal attitude in NED.

    R_ned_body: vehicle attitude (FRD -> NED). r_body_enu: vehicle reference point in ENU m.
    R_ned_gimbal: camera mount attitude (gimbal frame -> NED). lever_arm_frd_m: camera centre
    relative to the vehicle reference point, in body FRD metres.
    """
    R_enu_cam = R_ENU_NED @ R_ned_gimbal @ R_GIMBAL_CAM
    r_cam_enu = (np.asarray(r_body_enu, float)
                 + R_ENU_NED @ R_ned_body @ np.asarray(lever_arm_frd_m, float))
    return CameraPose(R_enu_cam, r_cam_enu, t_s)


def fixed_mount_pose(R_ned_body: np.ndarray, r_body_enu: np.ndarray, mount: FixedMount,
                     t_s: float = float("nan")) -> CameraPose:
    """Camera pose of a fixed mount on a vehicle with attitude ``R_ned_body``."""
    return camera_pose(R_ned_body, r_body_enu, R_ned_body @ mount.R_body_gimbal,
                       np.asarray(mount.lever_arm_frd_m), t_s)


def camera_motion(R_enu_cam_a: np.ndarray, r_cam_enu_a: np.ndarray, R_enu_cam_b: np.ndarray,
                  r_cam_enu_b: np.ndarray, dt_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Velocity (N, 3) ENU m/s and angular rate (N, 3) ENU rad/s of cameras at poses a and,
    ``dt_s`` (N,) s later, b (R (N, 3, 3), r (N, 3)): the finite difference over a short
    step. R_b = exp([omega]x dt) R_a; omega from the skew part of R_b R_a^T, whose error,
    (omega dt)^2 relative, is negligible for steps of milliseconds. NaN where dt_s <= 0."""
    dt = np.asarray(dt_s, dtype=float).reshape(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_dt = np.where(dt > 0, 1.0 / np.where(dt > 0, dt, 1.0), np.nan)
    v = (np.asarray(r_cam_enu_b) - np.asarray(r_cam_enu_a)) * inv_dt[:, None]
    A = np.asarray(R_enu_cam_b) @ np.asarray(R_enu_cam_a).transpose(0, 2, 1)
    omega = 0.5 * np.stack([A[:, 2, 1] - A[:, 1, 2], A[:, 0, 2] - A[:, 2, 0],
                            A[:, 1, 0] - A[:, 0, 1]], axis=1) * inv_dt[:, None]
    return v, omega


def known_motion(v_cam_enu_m_s: np.ndarray, omega_enu_rad_s: np.ndarray
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A velocity and angular rate for CameraPose: (None, None) when either is not known
    (NaN)."""
    if not (np.isfinite(v_cam_enu_m_s).all() and np.isfinite(omega_enu_rad_s).all()):
        return None, None
    return v_cam_enu_m_s, omega_enu_rad_s
