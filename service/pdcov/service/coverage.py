"""What the daemon decides, with no I/O: ``LiveCoverage`` is fed telemetry samples, frame
times and ``now_s`` (the daemon's monotonic clock, s) and says what to do.

Frames follow ``pdcov evaluate`` by the same code (one pipeline, two drivers): the same
PoseTracker interpolates the camera pose at each frame time of the autopilot clock; frames
are placed on the same ``frame_policy.FrameLattice`` (every 1/rate s from the first time all
needed streams have samples), or at capture / detector frame times; each batch is decided by
``flight.frame_decision.decide_frames`` (the use/trust policy, the quaternion rebuild, the
min-height filter, the frames not used counted) and the ground altitude found by
``flight.ground_altitude.GroundAltitude``, which the offline path calls too. What only a
stream needs is decided here: a frame is decided once every stream has a sample at or after
it (then its bracketing samples are final), or once some stream's last sample lies more than
max_gap_s (+ reorder_s) behind the newest telemetry (then it is skipped as the tracker would
call it offline, and counted; never guessed). So a live grid equals the offline grid of the
same telemetry, cell for cell.

Before the grid can run it needs the ENU origin's ground altitude (configured, else the
autopilot's home at arming, else -- after home_wait_s of autopilot time -- the latest home
or the first position's altitude minus its height above home) and, for a gimbal, the reading
of its reports (the mount parameters, gimbal.resolve_interpretation); samples wait
meanwhile.

It also says when to publish status, which tiles changed and may be sent within the
bandwidth budget, when to checkpoint, and the NAMED_VALUE_FLOAT / STATUSTEXT values; with a
DEM, every sample also goes to the mission's ``terrain_check.TerrainCheck`` (the one
``pdcov evaluate`` feeds a log), and its mismatches are logged, the first at once, then at
most one every TERRAIN_WARNING_PERIOD_S.

``LiveCoverage`` holds these decisions together and delegates: each camera's tracker,
frames and grid to ``flight.camera_frames.CameraFrames`` (one per camera of the mission;
several cameras' grids ``combine_cameras`` combines into the published one after every
frame, as ``pdcov evaluate`` combines them), where frames fall and when they can be decided to
``flight.frame_schedule.FrameSchedule``, the ground altitude to
``ground_altitude.GroundAltitude``, the tiles to ``tile_sender.TileSender``, the status fields to
``status``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.bus.faults import Fault
from pdcov.bus.grid_state import grid_hash
from pdcov.bus.tile_metrics import TileMetrics
from pdcov.core.combine_cameras import combine_cameras
from pdcov.core.geodesy import Origin
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.flight.camera_frames import CameraFrames, TrackedSample
from pdcov.flight.frame_decision import framing_of
from pdcov.flight.frame_schedule import FrameSchedule
from pdcov.flight.ground_altitude import GroundAltitude
from pdcov.service import status
from pdcov.service.checkpoint_meta import CameraResume, finite_or_none
from pdcov.service.detections import LiveDetections
from pdcov.service.tile_sender import TileSender
from pdcov.telemetry import samples as smp
from pdcov.telemetry.frame_policy import FrameLattice, FrameSource
from pdcov.telemetry.gimbal import GimbalInterpretation
from pdcov.telemetry.pose_tracker import PoseTracker
from pdcov.telemetry.sample_gate import SampleGate
from pdcov.telemetry.terrain_check import TerrainCheck, terrain_check_for

if TYPE_CHECKING:  # a value handed in: the decisions never load a config
    from pdcov.core.camera import CameraModel
    from pdcov.core.geolocate import PositionAccuracy
    from pdcov.service.settings import ServeConfig

MILESTONES = (0.25, 0.5, 0.75, 0.9, 1.0)
NAMED_VALUE_PERIOD_S = 1.0
TERRAIN_WARNING_PERIOD_S = 60.0
"""A terrain check mismatch is logged at most once in this long (the first at once; the
count is always in the status)."""


@dataclass(slots=True)
class Due:
    """What the shell should do now: publish status, send these tiles bytes, checkpoint,
    send NAMED_VALUE_FLOAT with this value and/or STATUSTEXT with this text, log these
    notes (warnings, each said once)."""

    status: bool = False
    tiles: bytes | None = None
    checkpoint: bool = False
    named_value: float | None = None
    statustext: str | None = None
    notes: list[str] = field(default_factory=list)


@dataclass(slots=True)
class Counters:
    used: int = 0
    skipped: Counter = field(default_factory=Counter)
    faults: Counter = field(default_factory=Counter)


class LiveCoverage:
    """The daemon's decisions (module docstring). ``grid``: a new or resumed grid of the
    mission (``Mission.new_mission_grid``; with several cameras their combination);
    ``camera_grids``: several cameras' resumed grids by name (None: new ones);
    ``uid_prefix``: the candidates'
    (ids.candidate_uid_prefix; ``c``: tests of the grid alone)."""

    def __init__(self, cfg: ServeConfig, grid: CoverageGrid, now_s: float, *,
                 uid_prefix: str = "c", tiles_seq: int = 0,
                 camera_grids: dict[str, CoverageGrid] | None = None) -> None:
        m = cfg.mission
        self.cfg = cfg
        self.grid = grid
        self.grid_hash = grid_hash(grid.geometry, grid.free)  # they never change
        self.frame_source = FrameSource(cfg.frame_source)
        self.max_gap_s = m.max_gap_s
        self.counters = Counters()
        self.detections = LiveDetections(m, grid, self.counters.faults, uid_prefix)
        self.origin: Origin | None = None
        self.origin_how = ""
        self._ground = GroundAltitude(m.ground_alt_msl_m, cfg.service.home_wait_s,
                                      m.ground_alt_how)
        self.gate = SampleGate(self.counters.faults)
        self._estimator_seen = False  # an estimator status came over the link
        self._note: str | None = None  # said once by poll (Due.note)
        self._noted_no_estimator = False
        self.terrain_check = terrain_check_for(m)  # the DEM against the aircraft, or None
        self._dem_statustext: str | None = None  # told the pilot once by poll
        self._terrain_said = 0  # mismatches counted when the last warning was logged
        self._next_terrain_warning_s = -math.inf
        # Each camera its own grid; the published one is their combination
        # (core.combine_cameras, as evaluate), or the one camera's own (Mission.camera_grids).
        grids = m.camera_grids(grid, camera_grids)
        self.cameras = [
            CameraFrames(cam, grids[cam.name], framing=framing_of(cam, m, self.frame_source),
                         reorder_s=cfg.service.reorder_s, skipped=self.counters.skipped,
                         faults=self.counters.faults, took=self._took)
            for cam in m.cameras]
        self.first = self.cameras[0]  # Mission.first_camera's: frame times, detections, pose
        self._zoom_followers = {cam.cam.zoom.camera_id: cam for cam in self.cameras
                                if cam.cam.zoom is not None}
        combine_cameras(grid, self.camera_grids)
        ts = cfg.bus.tile_size
        self.tile_size = ts
        self.tile_sender = TileSender(grid, self.grid_hash, ts,
                                      cfg.bus.tiles_max_bytes_per_s, now_s, tiles_seq)
        self._next_status_s = now_s
        self._next_tiles_s = now_s
        self._next_checkpoint_s = now_s + cfg.service.checkpoint_period_s
        self._next_value_s = now_s
        self._frames_at_checkpoint = grid.frames
        self.target_pd = cfg.target_pd
        self.metrics = TileMetrics(grid, ts, (*m.thresholds, self.target_pd))
        share = self.share_at_target()
        self._milestones = [x for x in MILESTONES if share < x - 1e-12]

    # --- telemetry in ---------------------------------------------------------------------

    def add_sample(self, sample: smp.Sample) -> None:
        """A sample from the link, stamped in the autopilot clock (s)."""
        check = self.terrain_check
        if check is not None:  # every sample, as offline: it refuses its own
            check.add(sample)
            if check.home_refused is not None and not self.first.dem_refused:
                self._refuse_dem(check)
        if not self.gate.admit(sample):  # sample_gate: the tlog reader's rule too
            return
        if isinstance(sample, smp.HomeSample):
            self._ground.add_home(sample)
            return
        if isinstance(sample, smp.HeartbeatSample):
            self._ground.add_heartbeat(sample)
            return
        if isinstance(sample, smp.CaptureSample):
            if self.frame_source == FrameSource.CAPTURE:
                self.add_frame_times([sample.t_s])
            return
        if isinstance(sample, smp.UtcSample):
            self.detections.utc.add(sample.t_s, sample.boot_s, sample.unix_s)
            return
        if isinstance(sample, smp.PositionSample):
            self._ground.add_position(sample)
        if isinstance(sample, smp.EstimatorSample):
            self._estimator_seen = True
        if isinstance(sample, smp.LensSample) and self.cfg.mission.several_cameras:
            # Each report to the camera that follows its camera component; a report of a
            # camera none follows is counted, not used. (One camera follows the first heard
            # when zoom_lens.component_id is not set, and counts the others itself.)
            follower = self._zoom_followers.get(sample.camera_id)
            if follower is None:
                self.counters.faults[Fault.ZOOM_REPORTS_OTHER_CAMERA] += 1
            else:
                follower.add(sample)
            return
        if isinstance(sample, TrackedSample):
            for cam in self.cameras:
                cam.add(sample)

    def _refuse_dem(self, check: TerrainCheck) -> None:
        """A home beyond terrain.max_home_offset_m from the DEM: no frame is counted over it
        from now on (the frames skipped as HOME_OFF_DEM), the log and the pilot are told."""
        for cam in self.cameras:
            cam.dem_refused = True
        self.counters.faults[Fault.HOME_OFF_DEM] += 1
        self._note = check.home_refusal()
        refused = check.home_refused
        if refused is not None and self.cfg.service.statustext:
            self._dem_statustext = (f"pdcov: home {-refused.difference_m:+.0f}m off DEM, "
                                    "no coverage")

    @property
    def camera_grids(self) -> list[CoverageGrid]:
        """Each camera's own grid, the mission's order (one camera: the published grid)."""
        return [cam.grid for cam in self.cameras]

    @property
    def checkpoint_cameras(self) -> dict[str, CoverageGrid] | None:
        """With several cameras, each camera's own grid by name (a checkpoint holds them: the
        published grid is their combination); None with one camera."""
        if not self.cfg.mission.several_cameras:
            return None
        return {cam.cam.name: cam.grid for cam in self.cameras}

    @property
    def schedule(self) -> FrameSchedule:
        """The first camera's frame schedule (capture and detector frame times go there:
        several cameras have rate frames only)."""
        return self.first.schedule

    @property
    def interpretation(self) -> GimbalInterpretation | None:
        """The first camera's gimbal reading, once resolved."""
        return self.first.interpretation

    @property
    def tracker(self) -> PoseTracker | None:
        """The first camera's pose tracker, once started."""
        return self.first.tracker

    @property
    def last_pose(self) -> CameraPose | None:
        """The first camera's last frame (the status's pose and footprint)."""
        return self.first.last_pose

    @property
    def last_R_ned_body(self) -> np.ndarray:
        return self.first.last_R_ned_body

    def add_frame_times(self, t_s: list[float] | tuple[float, ...]) -> list[float]:
        """Frame times (autopilot clock, s) from capture events or the detector; returns
        those taken, in order (not: a duplicate, or one at or before a decided frame)."""
        return self.schedule.add_frame_times(t_s)

    def is_late(self, t_s: float) -> bool:
        """A frame time before the last decided frame: never taken (the frames after it are
        in the grid already)."""
        return self.schedule.is_late(t_s)

    @property
    def last_frame_t_s(self) -> float:
        """The last decided frame (autopilot clock, s; -inf before the first)."""
        return self.schedule.last_frame_t_s

    @property
    def lattice(self) -> FrameLattice | None:
        """The rate frames' lattice, once the streams started."""
        return self.schedule.lattice

    @property
    def tiles_seq(self) -> int:
        """The next tiles message's sequence number."""
        return self.tile_sender.seq

    def set_params(self, params: dict[str, float], done: bool) -> None:
        """The mount parameters read so far; ``done`` when no more will come."""
        for cam in self.cameras:
            cam.set_params(params, done)

    # --- frames ---------------------------------------------------------------------------

    @property
    def ready(self) -> bool:
        return all(cam.tracker is not None for cam in self.cameras)

    def _try_start(self) -> None:
        m = self.cfg.mission
        if self.origin is None:
            alt, how = self._ground_alt()
            if alt is not None:
                self.origin, self.origin_how = m.origin(alt), how
        if self.origin is None:
            return
        for cam in self.cameras:
            cam.start(self.origin)

    def _ground_alt(self) -> tuple[float | None, str]:
        """The ground altitude (m MSL) and how it was found, or None while waiting
        (ground_altitude.GroundAltitude)."""
        w = self.first.waiting
        return self._ground.ground_alt(w[-1].t_s if w else -math.inf)

    @property
    def t0_s(self) -> float | None:
        """The rate lattice's first frame (autopilot clock, s), once it started."""
        return self.schedule.t0_s

    def process(self) -> int:
        """Decide every frame that can be decided, camera by camera; returns how many were
        added. The boxes of the frames used are geolocated with their poses
        (``detections``)."""
        if not self.ready:
            self._try_start()
        added = sum(cam.process() for cam in self.cameras)
        other = self.first.zoom_reports_other_camera
        if other and not self.cfg.mission.several_cameras:  # else counted in add_sample
            self.counters.faults[Fault.ZOOM_REPORTS_OTHER_CAMERA] = other
        self.counters.used += added
        if (self.counters.faults[Fault.FRAMES_WITHOUT_ESTIMATOR_STATUS]
                and not self._estimator_seen and not self._noted_no_estimator):
            self._noted_no_estimator = True
            self._note = ("no estimator status (EKF_STATUS_REPORT / ESTIMATOR_STATUS) on "
                          "the link: frames are not checked against the autopilot's "
                          "position estimate (counted in faults."
                          "frames_without_estimator_status)")
        self.detections.decided(self.last_frame_t_s)
        return added

    def resume_lattice(self, t0_s: float | None, last_frame_t_s: float) -> None:
        """Continue a checkpointed run: the frame lattice anchored at ``t0_s`` (rate mode),
        the frames after ``last_frame_t_s`` (autopilot clock, s, continued by the link)."""
        self.schedule.resume_lattice(t0_s, last_frame_t_s)

    def camera_resume(self) -> dict[str, CameraResume] | None:
        """With several cameras, what a checkpoint keeps of each camera to continue it."""
        if not self.cfg.mission.several_cameras:
            return None
        return {c.cam.name: CameraResume(c.schedule.t0_s,
                                         finite_or_none(c.schedule.last_frame_t_s), c.used)
                for c in self.cameras}

    def resume_cameras(self, cameras: dict[str, CameraResume]) -> None:
        """Continue every camera (several) from its checkpointed lattice, last
        frame and count (a camera the checkpoint lacks starts anew)."""
        for cam in self.cameras:
            r = cameras.get(cam.cam.name)
            if r is None:
                continue
            if r.last_frame_t_s is not None:
                cam.schedule.resume_lattice(r.t0_s, r.last_frame_t_s)
            cam.used = r.frames_used

    def _took(self, cam: CameraFrames, pose: CameraPose, camera: CameraModel | None,
              accuracy: PositionAccuracy | None) -> None:
        """A camera's grid took a frame: the published grid's cells it may have changed
        (the combination, with several cameras), their tiles and status metrics marked; the
        first camera's boxes geolocated (with the GNSS ``accuracy`` in force at the frame)."""
        window = cam.grid.touched
        # no window: nothing changed but the frame counts
        combine_cameras(self.grid, self.camera_grids, window or (0, 0, 0, 0))
        if window is not None:
            self.tile_sender.touch(window)
            self.metrics.mark(window)
        if cam is self.first:
            self.detections.frame(pose, camera, accuracy, grid=cam.grid)

    @property
    def frames_pending(self) -> int:
        """Frames waiting for telemetry, every camera's."""
        return sum(cam.schedule.frames_pending for cam in self.cameras)

    # --- output ---------------------------------------------------------------------------

    def share_at_target(self) -> float:
        return self.metrics.summary().proportion_at_or_above(self.target_pd)

    def poll(self, now_s: float) -> Due:
        """What is due at ``now_s`` (the daemon's monotonic clock, s)."""
        # With correlated or viewpoint looks the P_D of the cells frames changed since the
        # last poll is derived now: the status, tiles and checkpoint below read it.
        self.grid.refresh()
        bus, svc = self.cfg.bus, self.cfg.service
        due = Due(notes=[] if self._note is None else [self._note])
        self._note = None
        check = self.terrain_check
        warning = (None if check is None or check.mismatches == self._terrain_said
                   else check.warning())
        if warning is not None and check is not None \
                and now_s >= self._next_terrain_warning_s:
            self._terrain_said = check.mismatches
            self._next_terrain_warning_s = now_s + TERRAIN_WARNING_PERIOD_S
            due.notes.append(warning)
        if now_s >= self._next_status_s:
            due.status = True
            self._next_status_s = max(self._next_status_s + bus.status_period_s, now_s)
        if now_s >= self._next_tiles_s:
            self._next_tiles_s = max(self._next_tiles_s + bus.tiles_period_s, now_s)
            due.tiles = self.tile_sender.send(now_s, self.last_frame_t_s)
        if now_s >= self._next_checkpoint_s:
            # Anchored on the schedule, not on this tick: a kill loses at most one period
            # plus one tick and one write.
            self._next_checkpoint_s = max(self._next_checkpoint_s + svc.checkpoint_period_s,
                                          now_s)
            due.checkpoint = self.grid.frames != self._frames_at_checkpoint
        if self._dem_statustext is not None:
            due.statustext, self._dem_statustext = self._dem_statustext, None
        if now_s >= self._next_value_s:
            self._next_value_s = max(self._next_value_s + NAMED_VALUE_PERIOD_S, now_s)
            share = self.share_at_target()
            if svc.named_value_float:
                due.named_value = share
            passed = [x for x in self._milestones if share >= x - 1e-12]
            if passed:
                self._milestones = [x for x in self._milestones if x not in passed]
                if svc.statustext:
                    due.statustext = (f"pdcov: {passed[-1]:.0%} of area at "
                                      f"P_D>={self.target_pd:g}")
        return due

    def next_timer_s(self) -> float:
        """When ``poll`` next has something due (the daemon's monotonic clock, s)."""
        return min(self._next_status_s, self._next_tiles_s, self._next_checkpoint_s,
                   self._next_value_s)

    def checkpointed(self, frames: int) -> None:
        """The shell wrote a checkpoint of the grid as it was at ``frames`` frames."""
        self._frames_at_checkpoint = frames

    def footprint_lonlat(self) -> np.ndarray | None:
        """The last frame's footprint ring (M, 2) as lon/lat degrees, or None."""
        return status.footprint_lonlat(self)

    def status_fields(self, *, uptime_s: float, seq: int, link: dict[str, Any],
                      checkpoint: dict[str, Any]) -> dict[str, Any]:
        """The status object's fields (bus.status, docs/protocol.md)."""
        return status.status_fields(self, uptime_s=uptime_s, seq=seq, link=link,
                                    checkpoint=checkpoint)
