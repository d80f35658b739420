"""One input of ``pdcov evaluate`` evaluated: a flight log (through ``flight/log_frames.py``,
the one flight engine) or a pose CSV, into the mission's grids, with what the summary and
metrics.json say of it. The same code runs a single log, each of several logs in a worker
process, and each on a Dask worker (commands/many_logs.py); only the outputs and the merge
are the caller's.

Positions are ENU metres about the input's origin (``InputRun.origin``); times are the
autopilot's (a log) or the CSV's seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.core.blur import describe_blur
from pdcov.core.combine_cameras import combine_cameras
from pdcov.core.geodesy import Origin, distance_from_origin_m
from pdcov.core.grid_store import (
    StoreUpdate,
    read_store_like,
    restore_update,
    store_update,
    write_store,
)
from pdcov.core.mount import GimbalMount
from pdcov.core.sweep_width import FlightSample
from pdcov.core.utc_clock import UtcClock
from pdcov.errors import ConfigError, InputFileError, PdcovError
from pdcov.flight.frame_decision import framing_of
from pdcov.flight.log_frames import poses_of_log
from pdcov.report.output_extent import check_prior_fits
from pdcov.report.outputs import evaluate_poses, finite_track, read_prior
from pdcov.telemetry.frame_policy import below_min_height
from pdcov.telemetry.logs import FlightLog, for_gimbal, read_flight_log
from pdcov.telemetry.pose_csv import read_pose_csv, write_pose_csv

if TYPE_CHECKING:
    from pdcov.config.mission import Mission
    from pdcov.core.geodesy import Origin
    from pdcov.core.grid import CoverageGrid
    from pdcov.core.pose import CameraPose
    from pdcov.report.outputs import Prior


class InputKind(Enum):
    """What an input file holds: a flight log (.tlog, .bin, .ulg) or a pose CSV."""

    LOG = "log"
    POSES = "poses"


@dataclass(frozen=True, slots=True)
class InputJob:
    """One input to evaluate: ``path`` of ``kind`` with ``frame_source`` (resolved:
    Mission.cameras_frame_source); ``prior``: the --prior file (for the detections' prior
    and the outputs); ``export_poses``: where to write the camera poses used (a log only);
    ``progress``: bars for the frames (in process only). The mission is handed beside it:
    a worker receives it once, not with every log (with a DEM it holds grid-sized arrays)."""

    path: Path
    kind: InputKind
    frame_source: str | None
    prior: Path | None = None
    export_poses: Path | None = None
    progress: bool = False


@dataclass(frozen=True, slots=True)
class InputGrids:
    """An input's grids: ``grid`` the mission's (its cameras combined), ``cameras`` each
    camera's by name with several cameras (empty with one: ``grid`` is that camera's)."""

    grid: CoverageGrid
    cameras: Mapping[str, CoverageGrid]

    def packed(self) -> PackedGrids:
        """Their tiles (core.grid_store.store_update: the cells seen), to send to another
        process."""
        return PackedGrids(store_update(self.grid),
                           {n: store_update(g) for n, g in self.cameras.items()})


@dataclass(frozen=True, slots=True)
class PackedGrids:
    """``InputGrids`` as their tiles (core.grid_store.StoreUpdate: the cells seen, not the
    domain): what a worker process or a Dask worker sends back."""

    grid: StoreUpdate
    cameras: Mapping[str, StoreUpdate]

    def unpacked(self, mission: Mission, source: Path) -> InputGrids:
        """The grids restored (grid_store.restore_update) with ``mission``'s cameras,
        detectors and rules; ``source`` names them in messages."""
        grid = mission.new_mission_grid()
        restore_update(self.grid, grid, source)
        cameras = {}
        for cam in mission.cameras if self.cameras else ():
            cameras[cam.name] = g = mission.new_grid(cam)
            restore_update(self.cameras[cam.name], g, source)
        return InputGrids(grid, cameras)


@dataclass(frozen=True, slots=True)
class StoredGrids:
    """``InputGrids`` written into grid stores in ``folder`` (core/grid_store.py:
    grid.zarr, and cameras/<name>.zarr for ``cameras``): what a Dask worker leaves on the
    shared disk, the meeting place of the logs' grids."""

    folder: Path
    cameras: tuple[str, ...]

    @classmethod
    def write(cls, grids: InputGrids, folder: Path) -> StoredGrids:
        write_store(folder / "grid.zarr", grids.grid)
        for name, g in grids.cameras.items():
            write_store(folder / "cameras" / f"{name}.zarr", g)
        return cls(folder, tuple(grids.cameras))

    def unpacked(self, mission: Mission, source: Path) -> InputGrids:
        """The grids read back (grid_store.read_store_like) with ``mission``'s cameras,
        detectors and rules; ``source``: the log they are of."""
        del source  # the stores name themselves in messages
        grid = read_store_like(self.folder / "grid.zarr", mission.new_mission_grid())
        cams = {c.name: c for c in mission.cameras}
        return InputGrids(grid, {n: read_store_like(self.folder / "cameras" / f"{n}.zarr",
                                                    mission.new_grid(cams[n]))
                                 for n in self.cameras})


@dataclass(frozen=True, slots=True, eq=False)
class InputRun:
    """An input evaluated (``run_input``). path: the input. origin: its ENU origin as
    resolved. lines: what was done, in words (the summary's). input_warnings: the input's
    warnings (its telemetry's, the terrain check's); warnings: the evaluation's (a domain
    never seen). track_enu (M, 3): the finite vehicle (a log) or camera (a CSV) positions,
    ENU m, None without any. grids: InputGrids in process, PackedGrids from another, None
    once merged (many_logs.py).
    detections: the detections document (report/detections.py), None without boxes.
    terrain_check: its metrics object (None without a DEM); telemetry_faults /
    frames_skipped: the daemon's keys counted (None for a CSV). prior: the --prior read
    about this origin. frames: the frames the mission grid took. flight: their heights,
    speeds and track (metrics.json's sweep_width). track_unix_s: the UTC of track_enu's
    rows (s since 1970, NaN unknown), None without a real-time clock."""

    path: Path
    origin: Origin
    frames: int
    lines: tuple[str, ...]
    input_warnings: tuple[str, ...]
    warnings: tuple[str, ...]
    track_enu: np.ndarray | None
    grids: InputGrids | PackedGrids | StoredGrids | None
    detections: dict[str, Any] | None
    terrain_check: dict[str, Any] | None
    telemetry_faults: dict[str, int] | None
    frames_skipped: dict[str, int] | None
    prior: Prior | None
    flight: FlightSample | None = None
    track_unix_s: np.ndarray | None = None

    def packed(self) -> InputRun:
        """This run with its grids as bytes (PackedGrids), to cross a process boundary."""
        g = self.grids
        return replace(self, grids=g.packed() if isinstance(g, InputGrids) else g)

    def unpacked(self, mission: Mission) -> InputRun:
        """This run with its grids restored (InputGrids)."""
        g = self.grids
        return replace(self, grids=g.unpacked(mission, self.path)
                       if isinstance(g, (PackedGrids, StoredGrids)) else g)

    @property
    def loaded(self) -> InputGrids:
        """The grids of an unpacked run (TypeError if packed or merged: a caller's bug)."""
        if not isinstance(self.grids, InputGrids):
            raise TypeError(f"{self.path}: the run's grids are not loaded (InputRun.unpacked)")
        return self.grids


def run_input_packed(job: InputJob, mission: Mission) -> InputRun:
    """``run_input`` with the grids as their tiles: the function a worker process runs."""
    return run_input(job, mission).packed()


def run_input_stored(job: InputJob, mission: Mission, folder: Path) -> InputRun:
    """``run_input`` with the grids written into grid stores in ``folder`` (StoredGrids):
    the function a Dask worker runs."""
    run = run_input(job, mission)
    return replace(run, grids=StoredGrids.write(run.loaded, folder))


def run_input(job: InputJob, mission: Mission) -> InputRun:
    """Evaluate ``job`` under ``mission`` (module docstring). Raises PdcovError naming the
    input when it cannot be read or gives no camera frame."""
    frames = (_log_frames(job, mission) if job.kind is InputKind.LOG
              else _csv_frames(job, mission))
    lines = list(frames.lines)
    poses = frames.poses
    _check_near_origin(poses, job.path, mission.source, mission.origin())
    n_read = len(poses)
    top_m = max((float(p.r_cam_enu[2]) for p in poses), default=math.nan)
    # The daemon's filter: the log's frames marked by frame_selection, a CSV's poses by
    # frame_policy.below_min_height.
    high = (~frames.low if frames.low is not None else
            ~np.array([below_min_height(p.r_cam_enu[2], mission.min_height_m)
                       for p in poses], bool))
    low = int((~high).sum())
    cameras, accuracies = frames.cameras, frames.accuracies
    if low:
        poses = [p for p, h in zip(poses, high, strict=True) if h]
        cameras = tuple(c for c, h in zip(cameras, high, strict=False) if h)
        accuracies = tuple(a for a, h in zip(accuracies, high, strict=False) if h)
        lines.append(f"{low} frames with the camera below coverage.min_height_m = "
                     f"{mission.min_height_m:g} m not evaluated (on the ground or taking off)")
    if not poses:
        print("\n".join(lines))
        raise InputFileError(f"{job.path}: no camera frame to evaluate: "
                             + _why_no_frame(n_read, top_m, mission.min_height_m))
    grid = mission.new_mission_grid()
    per_camera = mission.camera_grids(grid)
    if job.prior is not None:
        check_prior_fits(grid.geometry)
    prior = (read_prior(job.prior, grid.geometry, grid.mask, frames.origin)
             if job.prior is not None else None)
    if prior is not None:
        lines.extend(prior.notes)
    own = per_camera[mission.first_camera.name]
    evaluate_poses(own, poses, progress=job.progress, total=len(poses), cameras=cameras)
    lines.append(describe_blur(own.blur_effect, own.exposure_s, own.frames_blurred,
                               own.frames))
    if frames.log is not None:
        _other_cameras(frames.log, mission, per_camera, job.frame_source, lines)
    # Each camera's looks in the same cells, by the one rule the daemon applies too.
    combine_cameras(grid, list(per_camera.values()))
    detections = None
    if frames.frame_boxes:
        from pdcov.ids import candidate_uid_prefix
        from pdcov.report.detections import flight_detections, log_epoch
        detections = flight_detections(
            mission, grid, frames.origin, poses, frames.frame_boxes, cameras, accuracies,
            uid_prefix=candidate_uid_prefix(mission.vehicle_id, log_epoch(job.path)),
            poa=None if prior is None else prior.poa, utc=frames.utc)
        lines.append(f"detections: {len(detections['detections'])} of the boxes pdcov serve "
                     f"recorded, in {len(detections['candidates'])} candidates")
        untimed = sum(d["time_utc"] is None for d in detections["detections"])
        if untimed:
            frames = replace(frames, warnings=(*frames.warnings, (
                f"{untimed} of {len(detections['detections'])} detections without "
                "time_utc: the log had no real-time clock at their frames (see the UTC "
                "line)")))
    warnings = _unseen_domain_warnings(grid, mission, poses)
    if frames.export is not None and job.export_poses is not None:
        write_pose_csv(job.export_poses, frames.export)
    return InputRun(job.path, frames.origin, grid.frames, tuple(lines), frames.warnings,
                    tuple(warnings), finite_track(frames.track_enu),
                    InputGrids(grid, per_camera if mission.several_cameras else {}),
                    detections, frames.terrain_check, frames.faults, frames.skipped, prior,
                    FlightSample.of(poses, mission.terrain), _track_unix_s(frames))


def _track_unix_s(frames: _Frames) -> np.ndarray | None:
    """The UTC (s, NaN unknown) of the finite rows of the track (``finite_track``'s), None
    without a real-time clock."""
    if frames.track_enu is None or frames.utc is None or not frames.utc.known:
        return None
    return frames.track_unix_s[np.all(np.isfinite(frames.track_enu), axis=1)]


@dataclass(frozen=True, slots=True, eq=False)
class _Frames:
    """An input's camera frames before the filter by height: poses, their cameras (zoom)
    and accuracies (GNSS), ``low`` (None for a CSV: filtered by height here), the origin,
    the track (ENU m), summary lines, warnings, and a log's read log, detector boxes,
    export rows, terrain check, faults, skipped frames, real-time clock and the UTC of
    its track's positions."""

    poses: Sequence[CameraPose]
    origin: Origin
    track_enu: np.ndarray | None
    lines: tuple[str, ...]
    warnings: tuple[str, ...] = ()
    low: np.ndarray | None = None
    cameras: tuple = ()
    accuracies: tuple = ()
    log: FlightLog | None = None
    frame_boxes: Mapping | None = None
    export: Any = None
    terrain_check: dict[str, Any] | None = None
    faults: dict[str, int] | None = None
    skipped: dict[str, int] | None = None
    utc: UtcClock | None = None
    track_unix_s: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _csv_frames(job: InputJob, mission: Mission) -> _Frames:
    """The poses of a pose CSV (``job.path``)."""
    zoom = mission.only_camera(
        job.path, f"the mission lists {len(mission.cameras)} cameras; a pose CSV holds "
        "one camera's poses: give the flight log (--log)").zoom
    if zoom is not None:
        raise PdcovError(f"{job.path}: camera.zoom {zoom.lens.quantity} follows "
                         "the camera's zoom reports, which a pose CSV does not hold: give "
                         "the flight log (--log), or set camera.zoom none")
    poses = read_pose_csv(job.path)
    lines = [f"poses: {job.path} ({len(poses)} frames)"]
    if mission.ground_alt_msl_m is None:
        lines.append("origin.ground_alt_msl_m not set: ENU heights in the CSV are taken "
                     "as heights above the ground")
    track = np.array([p.r_cam_enu for p in poses]) if poses else None
    return _Frames(poses, mission.origin(), track, tuple(lines))


def _log_frames(job: InputJob, mission: Mission) -> _Frames:
    """The camera frames of the mission's first camera in a flight log (``job.path``),
    with the daemon's terrain check over the same samples when the mission has a DEM."""
    from pdcov.telemetry.terrain_check import terrain_check_for  # looked up per call

    terrain_check = terrain_check_for(mission)
    first = mission.first_camera
    mount = first.mount
    flight_log = read_flight_log(  # once, for every camera
        job.path, system_id=mission.system_id,
        gimbal_instance=mount.instance if isinstance(mount, GimbalMount) else 1)
    log_poses = poses_of_log(
        flight_log, framing_of(first, mission, job.frame_source),
        origin_lat_deg=mission.origin_lat_deg, origin_lon_deg=mission.origin_lon_deg,
        ground_alt_msl_m=mission.ground_alt_msl_m, progress=job.progress,
        ground_alt_how=mission.ground_alt_how, terrain_check=terrain_check)
    lines = list(log_poses.summary_lines)  # its warnings among them
    warnings = log_poses.warnings
    if terrain_check is not None:  # the daemon's terrain_check, over the same samples
        refusal = terrain_check.home_refusal()
        if refusal is not None:  # the daemon counts no frame over this DEM either
            raise ConfigError(f"{job.path}: {refusal}")
        lines.append(terrain_check.summary_line())
        if terrain_check.mismatches:
            warnings += (terrain_check.summary_line(),)
    return _Frames(log_poses.poses, log_poses.origin, log_poses.track_enu, tuple(lines),
                   warnings, log_poses.low, log_poses.cameras, log_poses.accuracies,
                   flight_log, log_poses.frame_boxes, log_poses,
                   None if terrain_check is None else terrain_check.as_dict(),
                   dict(log_poses.faults), dict(log_poses.frames_skipped), log_poses.utc,
                   log_poses.track_unix_s)


def _other_cameras(log: FlightLog, mission: Mission, grids: Mapping[str, CoverageGrid],
                   frame_source: str | None, lines: list[str]) -> None:
    """Evaluate into ``grids`` (by name) the mission's cameras after the first, each from
    the frames of the ``log`` read once (its own gimbal device's reports) at its own rate,
    with its own mount, zoom and detector (the mission's frame rules)."""
    for cam in mission.cameras:
        if cam is mission.first_camera:
            continue
        lp = poses_of_log(
            for_gimbal(log, cam.mount.instance) if isinstance(cam.mount, GimbalMount) else log,
            framing_of(cam, mission, frame_source), origin_lat_deg=mission.origin_lat_deg,
            origin_lon_deg=mission.origin_lon_deg, ground_alt_msl_m=mission.ground_alt_msl_m,
            ground_alt_how=mission.ground_alt_how)
        grid = grids[cam.name]
        evaluate_poses(grid, [p for p, low in zip(lp.poses, lp.low, strict=True) if not low],
                       cameras=[c for c, low in zip(lp.cameras, lp.low, strict=False)
                                if not low])
        lines.append(f"camera {cam.name}: {grid.frames} frames "
                     f"({next((x for x in lp.summary_lines if x.startswith('frames:')), '')})")


def _why_no_frame(n_read: int, top_m: float, min_height_m: float) -> str:
    """Why no frame is left to evaluate, in words."""
    if n_read == 0:
        return "the input gave no camera pose (see the frames line above for what was skipped)"
    return (f"all {n_read} frames below coverage.min_height_m = {min_height_m:g} m (the "
            f"highest camera was {top_m:.2f} m above the ground; check "
            "origin.ground_alt_msl_m, or lower coverage.min_height_m)")


def _unseen_domain_warnings(grid: CoverageGrid, mission: Mission,
                            poses: Sequence[CameraPose]) -> list[str]:
    """A warning when no frame saw a free cell of the domain, with the horizontal distance
    from the camera track to the domain (the usual cause: a wrong origin)."""
    if grid.metrics(()).cells_observed:  # tile by tile: a county's grid is never read whole
        return []
    import shapely

    track = shapely.MultiPoint([p.r_cam_enu[:2] for p in poses])
    dist_m = float(shapely.distance(mission.domain.free_space, track))
    if dist_m > 0:
        where_ = (f"the camera came no closer than {dist_m:,.0f} m (horizontally) to the "
                  f"domain; check origin.lat_deg / origin.lon_deg in {mission.source} and "
                  "the input's positions")
    else:
        where_ = ("the camera passed over the domain but saw none of it: check the camera "
                  "attitude (mount), the heights, and coverage.max_range_m "
                  f"({grid.max_range_m:.0f} m)")
    return [f"no frame observed any of the {grid.n_free} free cells of the domain: "
            f"{where_}"]


def _check_near_origin(poses: Sequence[CameraPose], source: Path, config: str | None,
                       origin: Origin) -> None:
    """A flight tens of km from the origin is a wrong origin, not a survey: say so, with
    its distance over the ground (the ENU plane's horizontal distance is not that far
    away)."""
    if not poses:
        return
    r_enu = np.array([p.r_cam_enu for p in poses])
    if float(np.median(np.linalg.norm(r_enu, axis=1))) <= 50e3:  # straight-line, below it
        return
    dist_km = float(np.median(distance_from_origin_m(r_enu, origin))) / 1000
    if dist_km > 50:
        raise InputFileError(
            f"{source}: the camera is {dist_km:,.0f} km from the mission origin; "
            f"check origin.lat_deg / origin.lon_deg in {config}")
