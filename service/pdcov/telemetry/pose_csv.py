"""Pose CSV files: one camera pose a row (``t_s`` s, camera centre ``x_m y_m z_m`` in ENU m,
unit quaternion ``qw qx qy qz`` of R_enu_cam), written by ``pdcov evaluate --export-poses``
with extra columns (``EXPORT_EXTRA_COLUMNS``) and read back bit-identical.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.core.pose import CameraPose
from pdcov.core.rotations import R_from_quat_wxyz
from pdcov.errors import InputFileError
from pdcov.yaml_file import read_text

if TYPE_CHECKING:
    from pdcov.flight.log_frames import LogPoses

POSE_CSV_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")
EXPORT_EXTRA_COLUMNS = ("roll_deg", "pitch_deg", "yaw_deg", "gimbal_qw", "gimbal_qx",
                        "gimbal_qy", "gimbal_qz", "gimbal_flags", "interpretation", "trusted",
                        "untrusted_reason")
QUAT_NORM_TOL = 1e-3


def write_pose_csv(path: str | Path, log_poses: LogPoses) -> None:
    """Write the poses as CSV (POSE_CSV_COLUMNS + EXPORT_EXTRA_COLUMNS), atomically."""
    with atomic_write(path, "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(POSE_CSV_COLUMNS + EXPORT_EXTRA_COLUMNS)
        writer.writerows(log_poses.export_rows())


def read_pose_csv(path: str | Path) -> tuple[CameraPose, ...]:
    """Camera poses from a pose CSV: header starting ``t_s,x_m,y_m,z_m,qw,qx,qy,qz`` (more
    columns allowed and ignored), camera centre ENU m and the unit quaternion (w, x, y, z)
    of R_enu_cam. The poses come sorted by time, whatever the order of the rows. Raises
    InputFileError naming the file and line."""
    path = Path(path)
    text = read_text(path, "pose CSV", InputFileError)
    rows: list[list[float]] = []
    lines: list[int] = []
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = [h.strip() for h in next(reader, [])]
        if tuple(header[:8]) != POSE_CSV_COLUMNS:
            raise InputFileError(f"{path}:1: expected the header "
                                 f"{','.join(POSE_CSV_COLUMNS)}, got {','.join(header)!r}")
        for row in reader:
            line = reader.line_num
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) < 8:
                raise InputFileError(f"{path}:{line}: expected 8 columns, got {len(row)}")
            try:
                rows.append([float(c) for c in row[:8]])
            except ValueError:
                raise InputFileError(f"{path}:{line}: expected 8 numbers, got {row[:8]!r}"
                                     ) from None
            lines.append(line)
    except csv.Error as exc:
        raise InputFileError(f"{path}:{reader.line_num}: {exc}") from None
    values = np.array(rows, dtype=float).reshape(-1, 8)
    finite = np.isfinite(values)
    if not finite.all():
        k = int(np.flatnonzero(~finite.all(axis=1))[0])
        bad = [POSE_CSV_COLUMNS[i] for i in np.flatnonzero(~finite[k])]
        raise InputFileError(f"{path}:{lines[k]}: {', '.join(bad)} not a finite number")
    norm = np.linalg.norm(values[:, 4:], axis=1)
    off = np.abs(norm - 1.0) > QUAT_NORM_TOL
    if off.any():
        k = int(np.flatnonzero(off)[0])
        raise InputFileError(f"{path}:{lines[k]}: quaternion (qw, qx, qy, qz) has norm "
                             f"{norm[k]:.6f}; expected a unit quaternion "
                             f"(within {QUAT_NORM_TOL})")
    # Rows in time order (ties by their values): which look counts with
    # coverage.min_revisit_s depends on the order of the frames, and the grid's float sums on
    # the order of the additions, so any order of the same rows gives the same grid.
    values = values[np.lexsort(values.T[::-1])]
    # from_quat normalises, exactly as when the poses were written.
    R_enu_cam = R_from_quat_wxyz(values[:, 4:]).reshape(-1, 3, 3)
    poses = [CameraPose(R, v[1:4], float(v[0])) for R, v in zip(R_enu_cam, values, strict=True)]
    if not poses:
        raise InputFileError(f"{path}: no pose rows after the header")
    return tuple(poses)
