"""Which frames of a ``FrameBatch`` are used, and their poses: ``select_frames``, the rule
both drivers apply through flight/frame_decision.decide_frames (the daemon's per batch of
decided frames, ``pdcov evaluate``'s per chunk of a whole log).

A frame is used when it is valid (every stream brackets it) and trusted, or the mount uses
untrusted frames too (frame_policy.frames_used); its camera rotation is rebuilt from its
own quaternion (frame_policy.rebuilt_R_enu_cam); a used frame with the camera below
coverage.min_height_m (frame_policy.below_min_height: on the ground or taking off) is
marked ``low`` and added to no grid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pdcov.core.pose import CameraPose, FixedMount, known_motion
from pdcov.telemetry.frame_policy import (
    below_min_height,
    frame_cameras,
    frames_used,
    rebuilt_R_enu_cam,
    untrusted_policy,
)
from pdcov.telemetry.gimbal import GimbalMount
from pdcov.telemetry.gnss_accuracy import position_accuracies

if TYPE_CHECKING:
    from pdcov.core.camera import CameraModel
    from pdcov.core.geolocate import PositionAccuracy
    from pdcov.core.zoom import Zoom
    from pdcov.telemetry.pose_tracker import FrameBatch

__all__ = ["SelectedFrames", "select_frames"]


@dataclass(frozen=True, slots=True)
class SelectedFrames:
    """The used frames of a batch of N. use (N,): which; per used frame (F of them):
    poses, q_enu_cam_wxyz (F, 4) the quaternions the rotations were rebuilt from, cameras
    (the zoom report's camera, None: the configured one), accuracies (the GNSS accuracy in
    force, None: unknown), low (F,) the camera below coverage.min_height_m."""

    use: np.ndarray
    poses: tuple[CameraPose, ...]
    q_enu_cam_wxyz: np.ndarray
    cameras: tuple[CameraModel | None, ...]
    accuracies: tuple[PositionAccuracy | None, ...]
    low: np.ndarray

    @classmethod
    def concatenate(cls, parts: Sequence[SelectedFrames]) -> SelectedFrames:
        """The selections of consecutive batches as one (of their batches concatenated)."""
        return cls(np.concatenate([p.use for p in parts]),
                   tuple(x for p in parts for x in p.poses),
                   np.concatenate([p.q_enu_cam_wxyz for p in parts]),
                   tuple(x for p in parts for x in p.cameras),
                   tuple(x for p in parts for x in p.accuracies),
                   np.concatenate([p.low for p in parts]))


def select_frames(b: FrameBatch, mount: FixedMount | GimbalMount, zoom: Zoom | None,
                  min_height_m: float) -> SelectedFrames:
    """The frames of ``b`` used with ``mount`` (its untrusted policy) and ``zoom``, and
    which of them are below ``min_height_m`` (m above the origin's ground)."""
    use = frames_used(b.valid, b.trusted, untrusted_policy(mount))
    q, R_enu_cam = rebuilt_R_enu_cam(b.R_enu_cam[use])
    r_cam_enu = b.r_cam_enu[use]
    poses = tuple(CameraPose(R, r, float(t), *known_motion(v, omega))
                  for R, r, t, v, omega in zip(R_enu_cam, r_cam_enu, b.t_s[use],
                                               b.v_cam_enu_m_s[use], b.omega_enu_rad_s[use],
                                               strict=True))
    low = np.asarray(below_min_height(r_cam_enu[:, 2], min_height_m), bool)
    return SelectedFrames(use, poses, q, tuple(frame_cameras(zoom, b.lens_value[use])),
                          tuple(position_accuracies(b.gnss_h_acc_m[use], b.gnss_v_acc_m[use])),
                          low)
