"""What the daemon decides, with no I/O: ``LiveCoverage`` is fed telemetry samples, frame
times and ``now_s`` (the daemon's monotonic clock, s) and says what to do.

Frames follow ``pdcov evaluate`` by the same code (one pipeline, two drivers): the same
PoseTracker interpolates the camera pose at each frame time of the autopilot clock; frames
are placed on the same ``frame_policy.FrameLattice`` (every 1/rate s from the first time
all needed streams have samples), or at capture / detector frame times; the use/trust
policy, the quaternion rebuild, the min-height filter and the ground altitude's fallbacks
are frame_policy's functions, which the offline path calls too. What only a stream needs is
decided here: a frame is decided once every stream has a sample at or after it (then its
bracketing samples are final), or once some stream's last sample lies more than max_gap_s
(+ reorder_s) behind the newest telemetry (then it is skipped as the tracker would call it
offline, and counted; never guessed). So a live grid equals the offline grid of the same
telemetry, cell for cell.

Before the grid can run it needs the ENU origin's ground altitude (configured, else the
autopilot's first HOME_POSITION, else -- after home_wait_s of autopilot time -- the first
position's altitude minus its height above home) and, for a gimbal, the reading of its
reports (the mount parameters, gimbal.resolve_interpretation); samples wait meanwhile.

It also says when to publish status, which tiles changed and may be sent within the
bandwidth budget, when to checkpoint, and the NAMED_VALUE_FLOAT / STATUSTEXT values; with a
DEM, every sample also goes to the mission's ``terrain_check.TerrainCheck`` (the one
``pdcov evaluate`` feeds a log), and its mismatches are logged, the first at once, then at
most one every TERRAIN_WARNING_PERIOD_S.

``LiveCoverage`` holds these decisions together and delegates: where frames fall and when
they can be decided to ``frame_schedule.FrameSchedule``, the ground altitude to
``origin.GroundAltitude``, the tiles to ``tile_sender.TileSender``, the status fields to
``status``.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.bus.grid_state import GridState
from pdcov.core.geodesy import Origin
from pdcov.core.grid import CoverageGrid
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import CameraPose, known_motion
from pdcov.service import status
from pdcov.service.detections import LiveDetections
from pdcov.service.frame_schedule import FrameSchedule
from pdcov.service.origin import GroundAltitude
from pdcov.service.tile_metrics import TileMetrics
from pdcov.service.tile_sender import TileSender
from pdcov.telemetry.frame_policy import (
    UNTRUSTED_PREFIX,
    FrameLattice,
    FrameSource,
    SkipReason,
    below_min_height,
    frame_cameras,
    frames_used,
    rebuilt_R_enu_cam,
    untrusted_policy,
)
from pdcov.telemetry.gimbal import GimbalInterpretation, resolve_interpretation
from pdcov.telemetry.lens_reports import LensReports
from pdcov.telemetry.pose_tracker import PoseTracker, position_jump
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    HeartbeatSample,
    HomeSample,
    LensSample,
    PositionSample,
    Sample,
    usable_quaternion,
)
from pdcov.telemetry.terrain_check import terrain_check_for

if TYPE_CHECKING:  # a value handed in: the decisions never load a config
    from pdcov.service.settings import ServeConfig

MILESTONES = (0.25, 0.5, 0.75, 0.9, 1.0)
NAMED_VALUE_PERIOD_S = 1.0
PARAMS_ORIGIN = "the autopilot's parameters over MAVLink"
TERRAIN_WARNING_PERIOD_S = 60.0
"""A terrain check mismatch is logged at most once in this long (the first at once; the
count is always in the status)."""
MAX_WAITING_SAMPLES = 2_000_000
"""Samples kept while the origin or gimbal reading is unknown (about 10 h of telemetry)."""
TrackedSample = AttitudeSample | PositionSample | GimbalSample | EstimatorSample | LensSample
"""The samples the PoseTracker takes (the others are read by LiveCoverage itself)."""


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
    """The daemon's decisions (module docstring). ``grid``: a new or resumed grid."""

    def __init__(self, cfg: ServeConfig, grid: CoverageGrid, now_s: float, *,
                 tiles_seq: int = 0) -> None:
        m = cfg.mission
        self.cfg = cfg
        self.grid = grid
        self.state = GridState(grid.geometry, grid.mask, grid.log_miss_d, grid.log_miss_fa,
                               grid.n_obs, grid.frames)  # views: always current
        self.grid_hash = self.state.hash  # the geometry and mask never change
        self.frame_source = FrameSource(cfg.frame_source)
        self.rate_hz = m.frame_rate_hz
        self.max_gap_s = m.max_gap_s
        self.history_s = max(20.0, 8.0 * m.max_gap_s)
        self.counters = Counters()
        self.detections = LiveDetections(m, grid, self.counters.faults)
        self.origin: Origin | None = None
        self.origin_how = ""
        self._ground = GroundAltitude(m.ground_alt_msl_m, cfg.service.home_wait_s,
                                      m.ground_alt_how)
        self.interpretation: GimbalInterpretation | None = None
        self.tracker: PoseTracker | None = None
        self._waiting: deque[TrackedSample] = deque()  # not yet given to the tracker
        self._last_position: PositionSample | None = None
        self._estimator_seen = False  # an estimator status came over the link
        self._note: str | None = None  # said once by poll (Due.note)
        self._noted_no_estimator = False
        self.terrain_check = terrain_check_for(m)  # the DEM against the aircraft, or None
        self._terrain_said = 0  # mismatches counted when the last warning was logged
        self._next_terrain_warning_s = -math.inf
        needed = ("attitude", "position") + (
            ("gimbal",) if isinstance(m.mount, GimbalMount) else ())
        self.schedule = FrameSchedule(self.frame_source, self.rate_hz, self.max_gap_s,
                                      cfg.service.reorder_s, needed, self._waiting,
                                      self.counters.skipped)
        self.last_pose: CameraPose | None = None
        self.last_R_ned_body = np.eye(3)  # the body attitude at last_pose (once there is one)
        ts = cfg.bus.tile_size
        self.tile_size = ts
        self.tile_sender = TileSender(grid, self.state, self.grid_hash, ts,
                                      cfg.bus.tiles_max_bytes_per_s, now_s, tiles_seq)
        self._next_status_s = now_s
        self._next_tiles_s = now_s
        self._next_checkpoint_s = now_s + cfg.service.checkpoint_period_s
        self._next_value_s = now_s
        self._frames_at_checkpoint = grid.frames
        self.target_pd = cfg.target_pd
        self.metrics = TileMetrics(self.state, ts, (*m.thresholds, self.target_pd),
                                   grid.refresh)
        share = self.share_at_target()
        self._milestones = [x for x in MILESTONES if share < x - 1e-12]

    # --- telemetry in ---------------------------------------------------------------------

    def add_sample(self, sample: Sample) -> None:
        """A sample from the link, stamped in the autopilot clock (s)."""
        if self.terrain_check is not None:  # every sample, as offline: it refuses its own
            self.terrain_check.add(sample)
        if not math.isfinite(sample.t_s):
            self.counters.faults["untimed_samples"] += 1
            return
        if isinstance(sample, HomeSample):
            if not (math.isfinite(sample.alt_msl_m) and abs(sample.lat_deg) <= 90
                    and abs(sample.lon_deg) <= 180):
                self.counters.faults["invalid_samples"] += 1
                return
            self._ground.add_home(sample)
            return
        if isinstance(sample, HeartbeatSample):
            self._ground.add_heartbeat(sample)
            return
        if isinstance(sample, CaptureSample):
            if self.frame_source == FrameSource.CAPTURE:
                self.add_frame_times([sample.t_s])
            return
        if isinstance(sample, AttitudeSample) and not usable_quaternion(
                sample.q_ned_body_wxyz):
            self.counters.faults["nan_samples"] += 1
            return
        if isinstance(sample, PositionSample):
            if not (math.isfinite(sample.lat_deg) and math.isfinite(sample.lon_deg)
                    and math.isfinite(sample.alt_msl_m)):
                self.counters.faults["nan_samples"] += 1
                return
            if abs(sample.lat_deg) > 90 or abs(sample.lon_deg) > 180:
                self.counters.faults["invalid_samples"] += 1
                return
            self._ground.add_position(sample)
            last = self._last_position
            if last is not None and position_jump(last, sample):
                self.counters.faults["position_jumps"] += 1
            if last is None or sample.t_s > last.t_s:
                self._last_position = sample
        if isinstance(sample, GimbalSample):
            if sample.failure_flags:
                self.counters.faults["gimbal_failure_reports"] += 1
            norm = math.sqrt(sum(v * v for v in sample.q_wxyz))
            if not (math.isfinite(norm) and norm > 0.5):
                self.counters.faults["nan_samples"] += 1
                return
        if isinstance(sample, EstimatorSample):
            self._estimator_seen = True
        if isinstance(sample, (AttitudeSample, PositionSample, GimbalSample, EstimatorSample,
                               LensSample)):
            if len(self._waiting) >= MAX_WAITING_SAMPLES:
                self._waiting.popleft()
                self.counters.faults["samples_dropped_waiting"] += 1
            self._waiting.append(sample)

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
        mount = self.cfg.mission.mount
        if self.interpretation is None and isinstance(mount, GimbalMount) and done:
            self.interpretation = resolve_interpretation(mount, params, PARAMS_ORIGIN)

    # --- frames ---------------------------------------------------------------------------

    @property
    def ready(self) -> bool:
        return self.tracker is not None

    def _try_start(self) -> None:
        m = self.cfg.mission
        if self.origin is None:
            alt, how = self._ground_alt()
            if alt is not None:
                self.origin, self.origin_how = m.origin(alt), how
        if self.origin is None:
            return
        if isinstance(m.mount, GimbalMount) and self.interpretation is None:
            return
        self.tracker = PoseTracker(self.origin, m.mount, interpretation=self.interpretation,
                                   max_gap_s=self.max_gap_s, history_s=self.history_s,
                                   use_estimator=m.estimator_status,
                                   lens=None if m.zoom is None else LensReports(m.zoom))

    def _ground_alt(self) -> tuple[float | None, str]:
        """The ground altitude (m MSL) and how it was found, or None while waiting
        (origin.GroundAltitude)."""
        return self._ground.ground_alt(self._waiting[-1].t_s if self._waiting else -math.inf)

    def _feed(self, tr: PoseTracker, until_s: float) -> None:
        """Give the tracker the waiting samples up to ``until_s`` (all when live; a backlog
        bit by bit, so that its history window never drops what a frame needs)."""
        w = self._waiting
        while w and w[0].t_s <= until_s:
            s = w.popleft()
            if isinstance(s, AttitudeSample):
                tr.add_attitude(s)
                stream = "attitude"
            elif isinstance(s, PositionSample):
                tr.add_position(s)
                stream = "position"
            elif isinstance(s, EstimatorSample):
                # Not a stream a frame waits for: a report carries no time of its own and is
                # stamped at arrival, so none can come for a frame whose attitude is in.
                tr.add_estimator(s)
                continue
            elif isinstance(s, LensSample):  # lens_reports.py: the estimator's rule
                tr.add_lens(s)
                if tr.lens is not None and tr.lens.other_camera:
                    self.counters.faults["zoom_reports_other_camera"] = tr.lens.other_camera
                continue
            else:
                before = tr.gimbal_source
                tr.add_gimbal(s)
                if tr.gimbal_source != before:
                    self.schedule.forget("gimbal")
                if s.source != tr.gimbal_source:
                    continue
                stream = "gimbal"
            self.schedule.saw(stream, s.t_s)

    @property
    def t0_s(self) -> float | None:
        """The rate lattice's first frame (autopilot clock, s), once it started."""
        return self.schedule.t0_s

    def process(self) -> int:
        """Decide every frame that can be decided; returns how many were added. Frames are
        evaluated in batches (one vectorised PoseTracker call) spanning at most a quarter
        of the tracker's history; the boxes of the frames used are geolocated with their
        poses (``detections``)."""
        added = self._process()
        self.detections.decided(self.last_frame_t_s)
        return added

    def _process(self) -> int:
        if self.tracker is None:
            self._try_start()
        tr = self.tracker
        if tr is None:
            return 0
        sched = self.schedule
        added = 0
        while True:
            t = sched.next_frame_t()
            if t is None and self.frame_source == FrameSource.RATE:
                t = sched.start_lattice(tr)
            if t is None:
                if not self._waiting:
                    return added
                self._feed(tr, self._waiting[0].t_s + 0.5 * self.history_s)
                continue
            if sched.skip_hole(t):  # before deciding a long hole batch by batch
                continue
            first_t = t
            batch: list[float] = []
            while t is not None and t - (batch[0] if batch else t) <= 0.25 * self.history_s:
                self._feed(tr, t + 0.5 * self.history_s)
                if not sched.decidable(t):
                    break
                batch.append(t)
                sched.advance()
                t = sched.next_frame_t()
            if not batch:
                if not sched.skip_hole(first_t):
                    return added
                continue
            added += self._evaluate(tr, np.array(batch))

    def resume_lattice(self, t0_s: float | None, last_frame_t_s: float) -> None:
        """Continue a checkpointed run: the frame lattice anchored at ``t0_s`` (rate mode),
        the frames after ``last_frame_t_s`` (autopilot clock, s, continued by the link)."""
        self.schedule.resume_lattice(t0_s, last_frame_t_s)

    def _touch(self, window: tuple[int, int, int, int]) -> None:
        """Cells rows r0:r1, columns c0:c1 may have changed: their tiles are compared and
        their status metrics recomputed when next due."""
        self.tile_sender.touch(window)
        self.metrics.mark(window)

    def _evaluate(self, tr: PoseTracker, t_s: np.ndarray) -> int:
        """Add the frames at times ``t_s`` (increasing) that are valid, trusted (or the
        mount says to use untrusted ones) and high enough; count the others by reason."""
        m = self.cfg.mission
        self.schedule.last_frame_t_s = float(t_s[-1])
        b = tr.frames_at(t_s)
        policy = untrusted_policy(m.mount)
        valid = b.valid
        use = frames_used(valid, b.trusted, policy)
        for reason in b.skip_reason[~valid]:
            self.counters.skipped[str(reason)] += 1
        untrusted = valid & ~b.trusted
        self.counters.faults["frames_untrusted"] += int(untrusted.sum())
        if policy != "use":
            for reason in b.untrusted_reason[untrusted]:
                self.counters.skipped[f"{UNTRUSTED_PREFIX}{reason}"] += 1
        if not use.any():
            return 0
        _q, R_enu_cam = rebuilt_R_enu_cam(b.R_enu_cam[use])
        added = 0
        unjudged = 0
        cameras = frame_cameras(m.zoom, b.lens_value[use])
        for R, r, t, R_body, judged, v, omega, camera in zip(
                R_enu_cam, b.r_cam_enu[use], b.t_s[use], b.R_ned_body[use],
                b.estimator_judged[use], b.v_cam_enu_m_s[use], b.omega_enu_rad_s[use],
                cameras, strict=True):
            pose = CameraPose(R, r, float(t), *known_motion(v, omega))
            self.last_pose, self.last_R_ned_body = pose, R_body
            if below_min_height(pose.r_cam_enu[2], m.min_height_m):
                self.counters.skipped[SkipReason.BELOW_MIN_HEIGHT] += 1
                continue
            self.grid.update_with(pose, camera)
            if self.grid.touched is not None:
                self._touch(self.grid.touched)
            self.detections.frame(pose, camera)
            added += 1
            unjudged += not judged
        self.state.frames = self.grid.frames
        self.counters.used += added
        if unjudged and m.estimator_status:
            self.counters.faults["frames_without_estimator_status"] += unjudged
            if not self._estimator_seen and not self._noted_no_estimator:
                self._noted_no_estimator = True
                self._note = ("no estimator status (EKF_STATUS_REPORT / ESTIMATOR_STATUS) on "
                              "the link: frames are not checked against the autopilot's "
                              "position estimate (counted in faults."
                              "frames_without_estimator_status)")
        return added

    @property
    def frames_pending(self) -> int:
        return self.schedule.frames_pending

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

    def checkpointed(self) -> None:
        """The shell wrote a checkpoint of the current grid."""
        self._frames_at_checkpoint = self.grid.frames

    def footprint_lonlat(self) -> np.ndarray | None:
        """The last frame's footprint ring (M, 2) as lon/lat degrees, or None."""
        return status.footprint_lonlat(self)

    def status_fields(self, *, uptime_s: float, seq: int, link: dict[str, Any],
                      checkpoint: dict[str, Any]) -> dict[str, Any]:
        """The status object's fields (bus.status, docs/protocol.md)."""
        return status.status_fields(self, uptime_s=uptime_s, seq=seq, link=link,
                                    checkpoint=checkpoint)
