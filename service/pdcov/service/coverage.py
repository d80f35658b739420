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
bandwidth budget, when to checkpoint, and the NAMED_VALUE_FLOAT / STATUSTEXT values.
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.bus.grid_state import GridState
from pdcov.bus.tiles import encode_tiles, tile_grid_shape, tile_wire_bytes
from pdcov.core.footprint import footprint_ring_enu
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.grid import CoverageGrid
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import CameraPose
from pdcov.service.tile_metrics import TileMetrics
from pdcov.telemetry.frame_policy import (
    UNTRUSTED_PREFIX,
    FrameLattice,
    FrameSource,
    SkipReason,
    below_min_height,
    frames_used,
    home_ground_alt,
    position_ground_alt,
    rebuilt_R_enu_cam,
    untrusted_policy,
)
from pdcov.telemetry.gimbal import GimbalInterpretation, resolve_interpretation
from pdcov.telemetry.pose_tracker import PoseTracker, position_jump
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    HeartbeatSample,
    HomeSample,
    PositionSample,
    Sample,
    usable_quaternion,
)

if TYPE_CHECKING:  # a value handed in: the decisions never load a config
    from pdcov.service.settings import ServeConfig

MILESTONES = (0.25, 0.5, 0.75, 0.9, 1.0)
NAMED_VALUE_PERIOD_S = 1.0
PARAMS_ORIGIN = "the autopilot's parameters over MAVLink"
MAX_WAITING_SAMPLES = 2_000_000
"""Samples kept while the origin or gimbal reading is unknown (about 10 h of telemetry)."""
TrackedSample = AttitudeSample | PositionSample | GimbalSample | EstimatorSample
"""The samples the PoseTracker takes (the others are read by LiveCoverage itself)."""


@dataclass(slots=True)
class Due:
    """What the shell should do now: publish status, send these tiles bytes, checkpoint,
    send NAMED_VALUE_FLOAT with this value and/or STATUSTEXT with this text, log this
    note (once)."""

    status: bool = False
    tiles: bytes | None = None
    checkpoint: bool = False
    named_value: float | None = None
    statustext: str | None = None
    note: str | None = None


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
        self._grid_hash = self.state.hash  # the geometry and mask never change
        self.frame_source = FrameSource(cfg.frame_source)
        self.rate_hz = m.frame_rate_hz
        self.max_gap_s = m.max_gap_s
        self.history_s = max(20.0, 8.0 * m.max_gap_s)
        self.counters = Counters()
        self.origin: Origin | None = None
        self.origin_how = ""
        self.interpretation: GimbalInterpretation | None = None
        self.tracker: PoseTracker | None = None
        self._waiting: deque[TrackedSample] = deque()  # not yet given to the tracker
        self._homes: list[HomeSample] = []
        self._first_position: PositionSample | None = None
        self._last_position: PositionSample | None = None
        self._armed_t_s: float | None = None
        self._heartbeats = False
        self._estimator_seen = False  # an estimator status came over the link
        self._note: str | None = None  # said once by poll (Due.note)
        self._noted_no_estimator = False
        self._latest: dict[str, float] = {}       # stream -> newest sample time given
        self._needed = ("attitude", "position") + (
            ("gimbal",) if isinstance(m.mount, GimbalMount) else ())
        self.lattice: FrameLattice | None = None  # rate frames, once the streams start
        self._k_next = 0
        self._queue: list[float] = []             # capture / detector frame times
        self.last_frame_t_s = -math.inf
        self.last_pose: CameraPose | None = None
        self._last_R_ned_body = np.eye(3)  # the body attitude at last_pose (once there is one)
        # Tiles: values as last sent, per tile; the tiles frames touched since the last
        # comparison (all at first: a resumed grid); when each tile first changed unsent.
        ts = cfg.bus.tile_size
        self.tile_size = ts
        self._tile_shape = tile_grid_shape(ts, *grid.geometry.shape)
        self._sent_n_obs = np.zeros_like(grid.n_obs)
        self._touched_tiles = np.ones(self._tile_shape, bool)
        self._dirty_since: dict[tuple[int, int], float] = {}
        self.tiles_seq = tiles_seq
        self._allowance = float(cfg.bus.tiles_max_bytes_per_s)
        self._ratio = 0.5  # compressed / raw bytes, learnt from what was sent
        self._next_status_s = now_s
        self._next_tiles_s = now_s
        self._last_tiles_s = now_s
        self._next_checkpoint_s = now_s + cfg.service.checkpoint_period_s
        self._next_value_s = now_s
        self._frames_at_checkpoint = grid.frames
        self.target_pd = cfg.target_pd
        self.metrics = TileMetrics(self.state, ts, (*m.thresholds, self.target_pd))
        share = self.share_at_target()
        self._milestones = [x for x in MILESTONES if share < x - 1e-12]

    # --- telemetry in ---------------------------------------------------------------------

    def add_sample(self, sample: Sample) -> None:
        """A sample from the link, stamped in the autopilot clock (s)."""
        if not math.isfinite(sample.t_s):
            self.counters.faults["untimed_samples"] += 1
            return
        if isinstance(sample, HomeSample):
            if not (math.isfinite(sample.alt_msl_m) and abs(sample.lat_deg) <= 90
                    and abs(sample.lon_deg) <= 180):
                self.counters.faults["invalid_samples"] += 1
                return
            self._homes.append(sample)
            return
        if isinstance(sample, HeartbeatSample):
            self._heartbeats = True
            if sample.armed and self._armed_t_s is None:
                self._armed_t_s = sample.t_s
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
            if self._first_position is None and math.isfinite(sample.relative_alt_m):
                self._first_position = sample
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
        if isinstance(sample, (AttitudeSample, PositionSample, GimbalSample, EstimatorSample)):
            if len(self._waiting) >= MAX_WAITING_SAMPLES:
                self._waiting.popleft()
                self.counters.faults["samples_dropped_waiting"] += 1
            self._waiting.append(sample)

    def add_frame_times(self, t_s: list[float] | tuple[float, ...]) -> list[float]:
        """Frame times (autopilot clock, s) from capture events or the detector; returns
        those taken, in order (not: a duplicate, or one at or before a decided frame)."""
        taken = []
        for t in t_s:
            if self.is_late(t):
                self.counters.skipped[SkipReason.LATE_FRAME_TIME] += 1
                continue
            if t == self.last_frame_t_s:
                continue
            i = bisect.bisect_left(self._queue, t)
            if i == len(self._queue) or self._queue[i] != t:
                self._queue.insert(i, t)
                taken.append(t)
        return taken

    def is_late(self, t_s: float) -> bool:
        """A frame time before the last decided frame: never taken (the frames after it are
        in the grid already)."""
        return t_s < self.last_frame_t_s

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
                                   use_estimator=m.estimator_status)

    def _ground_alt(self) -> tuple[float | None, str]:
        """The ground altitude (m MSL) and how it was found, or None while waiting.

        ArduPilot resets home at arming, and ``pdcov evaluate`` takes a log's last
        HOME_POSITION; live, the home in force at arming is taken: the latest HOME_POSITION
        sent from 2 s before the first armed HEARTBEAT on, waiting home_wait_s (autopilot
        clock) for it; samples wait until the vehicle arms. No such home, or no HEARTBEAT
        at all (a bare replay): after home_wait_s the latest home, else the first
        position's altitude minus its height above home."""
        m = self.cfg.mission
        if m.ground_alt_msl_m is not None:
            return m.ground_alt_msl_m, "configured"
        wait = self.cfg.service.home_wait_s
        now = max((self._waiting[-1].t_s if self._waiting else -math.inf),
                  self._homes[-1].t_s if self._homes else -math.inf)
        armed = self._armed_t_s
        if armed is not None:
            at_arming = [h for h in self._homes if h.t_s >= armed - 2.0]
            if at_arming:
                return at_arming[-1].alt_msl_m, ("the autopilot's home at arming "
                                                 "(HOME_POSITION)")
            if now < armed + wait:
                return None, ""
        elif (self._heartbeats or self._first_position is None
              or now < self._first_position.t_s + wait):
            return None, ""
        home = home_ground_alt(self._homes)
        if home is not None:
            return home
        p = self._first_position
        if p is None:
            return None, ""
        return position_ground_alt(p.alt_msl_m, p.relative_alt_m)

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
            else:
                before = tr.gimbal_source
                tr.add_gimbal(s)
                if tr.gimbal_source != before:
                    self._latest.pop("gimbal", None)
                if s.source != tr.gimbal_source:
                    continue
                stream = "gimbal"
            self._latest[stream] = max(self._latest.get(stream, -math.inf), s.t_s)

    @property
    def t0_s(self) -> float | None:
        """The rate lattice's first frame (autopilot clock, s), once it started."""
        return self.lattice.t0_s if self.lattice is not None else None

    def _next_frame_t(self) -> float | None:
        if self.frame_source == FrameSource.RATE:
            if self.lattice is None:
                return None
            return self.lattice.t(self._k_next)
        return self._queue[0] if self._queue else None

    def process(self) -> int:
        """Decide every frame that can be decided; returns how many were added. Frames are
        evaluated in batches (one vectorised PoseTracker call) spanning at most a quarter
        of the tracker's history."""
        if self.tracker is None:
            self._try_start()
        tr = self.tracker
        if tr is None:
            return 0
        added = 0
        while True:
            t = self._next_frame_t()
            if t is None and self.frame_source == FrameSource.RATE:
                t = self._start_lattice(tr)
            if t is None:
                if not self._waiting:
                    return added
                self._feed(tr, self._waiting[0].t_s + 0.5 * self.history_s)
                continue
            if self._skip_hole(t):  # before deciding a long hole batch by batch
                continue
            first_t = t
            batch: list[float] = []
            while t is not None and t - (batch[0] if batch else t) <= 0.25 * self.history_s:
                self._feed(tr, t + 0.5 * self.history_s)
                if not self._decidable(t):
                    break
                batch.append(t)
                if self.frame_source == FrameSource.RATE:
                    self._k_next += 1
                else:
                    self._queue.pop(0)
                t = self._next_frame_t()
            if not batch:
                if not self._skip_hole(first_t):
                    return added
                continue
            added += self._evaluate(tr, np.array(batch))

    def _skip_hole(self, t: float) -> bool:
        """Skip at once, as 'attitude gap' (what offline says of them), the frames from
        ``t`` on that lie in a hole of the telemetry: after every sample given to the
        tracker and more than max_gap_s + reorder_s before every waiting sample (a link
        outage or an autopilot reboot longer than half the history, a time jump). True when
        some were skipped. Without this the loop would wait for samples it never feeds."""
        if not self._waiting or t <= self._latest_all():
            return False
        end = min(s.t_s for s in self._waiting) - self.max_gap_s - self.cfg.service.reorder_s
        if t >= end:
            return False
        lattice = self.lattice
        if lattice is not None:  # rate mode (``t`` is on the lattice, so it has started)
            k_end = max(self._k_next + 1, lattice.first_at_or_after(end))
            n, self._k_next = k_end - self._k_next, k_end
            self.last_frame_t_s = lattice.t(k_end - 1)
        else:
            n = max(1, bisect.bisect_left(self._queue, end))
            self.last_frame_t_s = self._queue[n - 1]
            del self._queue[:n]
        self.counters.skipped[SkipReason.ATTITUDE_GAP] += n
        return True

    def resume_lattice(self, t0_s: float | None, last_frame_t_s: float) -> None:
        """Continue a checkpointed run: the frame lattice anchored at ``t0_s`` (rate mode),
        the frames after ``last_frame_t_s`` (autopilot clock, s, continued by the link)."""
        self.last_frame_t_s = last_frame_t_s
        if t0_s is not None and self.frame_source == FrameSource.RATE:
            self.lattice = FrameLattice(t0_s, self.rate_hz)
            self._k_next = self.lattice.count_until(last_frame_t_s)

    def _latest_all(self) -> float:
        return max(self._latest.values(), default=-math.inf)

    def _start_lattice(self, tr: PoseTracker) -> float | None:
        if any(s not in self._latest for s in self._needed):
            return None
        t0, _t1 = tr.coverage_s()
        if not math.isfinite(t0):
            return None
        self.lattice, self._k_next = FrameLattice(t0, self.rate_hz), 0
        return self.lattice.t(0)

    def _decidable(self, t: float) -> bool:
        # The newest telemetry, fed or still waiting beyond the feed horizon (after an
        # autopilot reboot the clock jumps ahead: frames in the jump are gaps).
        newest = max(self._latest_all(), self._waiting[-1].t_s if self._waiting
                     else -math.inf)
        if t > newest:
            return False  # no telemetry reaches this frame yet
        final = True
        for s in self._needed:
            last = self._latest.get(s, -math.inf)
            if last < t:
                final = False
                if newest - self.cfg.service.reorder_s - last > self.max_gap_s:
                    return True  # this stream's gap is already too long: skip it now
        return final

    def _touch(self, window: tuple[int, int, int, int]) -> None:
        """Cells rows r0:r1, columns c0:c1 may have changed: their tiles are compared and
        their status metrics recomputed when next due."""
        r0, r1, c0, c1 = window
        ts = self.tile_size
        self._touched_tiles[r0 // ts:(r1 - 1) // ts + 1, c0 // ts:(c1 - 1) // ts + 1] = True
        self.metrics.mark(window)

    def _evaluate(self, tr: PoseTracker, t_s: np.ndarray) -> int:
        """Add the frames at times ``t_s`` (increasing) that are valid, trusted (or the
        mount says to use untrusted ones) and high enough; count the others by reason."""
        m = self.cfg.mission
        self.last_frame_t_s = float(t_s[-1])
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
        for R, r, t, R_body, judged in zip(R_enu_cam, b.r_cam_enu[use],
                                           b.t_s[use], b.R_ned_body[use],
                                           b.estimator_judged[use], strict=True):
            pose = CameraPose(R, r, float(t))
            self.last_pose, self._last_R_ned_body = pose, R_body
            if below_min_height(pose.r_cam_enu[2], m.min_height_m):
                self.counters.skipped[SkipReason.BELOW_MIN_HEIGHT] += 1
                continue
            self.grid.update(pose)
            if self.grid.touched is not None:
                self._touch(self.grid.touched)
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
        if self.frame_source != FrameSource.RATE:
            return len(self._queue)
        t = self._next_frame_t()  # None until the lattice starts
        if t is None or not self._latest:
            return 0
        return max(0, math.floor((self._latest_all() - t) * self.rate_hz) + 1)

    # --- output ---------------------------------------------------------------------------

    def share_at_target(self) -> float:
        return self.metrics.summary().proportion_at_or_above(self.target_pd)

    def poll(self, now_s: float) -> Due:
        """What is due at ``now_s`` (the daemon's monotonic clock, s)."""
        bus, svc = self.cfg.bus, self.cfg.service
        due = Due(note=self._note)
        self._note = None
        if now_s >= self._next_status_s:
            due.status = True
            self._next_status_s = max(self._next_status_s + bus.status_period_s, now_s)
        if now_s >= self._next_tiles_s:
            self._next_tiles_s = max(self._next_tiles_s + bus.tiles_period_s, now_s)
            due.tiles = self._tiles(now_s)
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

    def _tiles(self, now_s: float) -> bytes | None:
        """Changed tiles within the bandwidth budget (a token bucket of one second at
        tiles_max_bytes_per_s), oldest change first; None when nothing is due."""
        rate = float(self.cfg.bus.tiles_max_bytes_per_s)
        self._allowance = min(rate, self._allowance + rate * (now_s - self._last_tiles_s))
        self._last_tiles_s = now_s
        ts = self.tile_size
        n_obs, sent = self.grid.n_obs, self._sent_n_obs
        # Only tiles frames touched can differ from what was sent (row-major, as the
        # whole-grid comparison this replaces).
        for tr, tc in zip(*np.nonzero(self._touched_tiles), strict=True):
            win = np.s_[tr * ts:(tr + 1) * ts, tc * ts:(tc + 1) * ts]
            if (int(tr), int(tc)) not in self._dirty_since and (n_obs[win] != sent[win]).any():
                self._dirty_since[(int(tr), int(tc))] = now_s
        self._touched_tiles[:] = False
        if not self._dirty_since or self._allowance <= 0:
            return None
        order = sorted(self._dirty_since, key=self._dirty_since.__getitem__)
        per_tile = tile_wire_bytes(ts) * self._ratio
        n = max(1, min(len(order), int(self._allowance // max(per_tile, 1.0)), 0xFFFF))
        ids = order[:n]
        payload = encode_tiles(self.state, ids, seq=self.tiles_seq, t_s=self.last_frame_t_s,
                               tile_size=ts, grid_hash=self._grid_hash)
        self.tiles_seq += 1
        self._allowance -= len(payload)
        self._ratio = max(0.01, len(payload) / (n * tile_wire_bytes(ts)))
        for tr, tc in ids:
            del self._dirty_since[(tr, tc)]
            win = np.s_[tr * ts:(tr + 1) * ts, tc * ts:(tc + 1) * ts]
            self._sent_n_obs[win] = self.grid.n_obs[win]
        return payload

    def footprint_lonlat(self) -> np.ndarray | None:
        """The last frame's footprint ring (M, 2) as lon/lat degrees, or None."""
        if self.last_pose is None or self.origin is None:
            return None
        ring = footprint_ring_enu(self.grid.camera, self.last_pose, self.grid.max_range_m)
        if len(ring) < 3:
            return None
        geo = enu_to_geodetic(np.column_stack([ring, np.zeros(len(ring))]), self.origin)
        return geo[:, [1, 0]]

    def status_fields(self, *, uptime_s: float, seq: int, link: dict[str, Any],
                      checkpoint: dict[str, Any]) -> dict[str, Any]:
        """The status object's fields (bus.status, docs/protocol.md)."""
        m = self.cfg.mission
        metrics = self.metrics.summary()
        g = self.grid.geometry
        pose = None
        if self.last_pose is not None and self.origin is not None:
            lat, lon, alt = enu_to_geodetic(self.last_pose.r_cam_enu, self.origin)
            R = self._last_R_ned_body
            pose = {"lat_deg": float(lat), "lon_deg": float(lon), "alt_msl_m": float(alt),
                    "heading_deg": math.degrees(math.atan2(R[1, 0], R[0, 0])) % 360.0,
                    "t_s": self.last_pose.t_s}
        interp = self.interpretation
        gimbal = ({"mount": "fixed", "interpretation": "fixed", "describe": "fixed mount"}
                  if not isinstance(m.mount, GimbalMount) else
                  {"mount": "gimbal", "interpretation": interp.frame if interp else None,
                   "describe": interp.describe() if interp else "waiting for the mount "
                                                                "parameters"})
        faults = dict(self.counters.faults)
        return {
            "vehicle_id": m.vehicle_id, "seq": seq, "uptime_s": uptime_s,
            "t_s": self._latest_all() if self._latest else None,
            "thresholds": list(m.thresholds),
            "proportion_at_or_above": {str(float(t)): metrics.proportion_at_or_above(t)
                                       for t in m.thresholds},
            "mean_pd": metrics.mean_pd, "expected_false_alarms": metrics.expected_false_alarms,
            "cells_free": metrics.cells_free, "cells_observed": metrics.cells_observed,
            "frames": {"used": self.counters.used, "grid": self.grid.frames,
                       "skipped": dict(self.counters.skipped),
                       "pending": self.frames_pending, "source": str(self.frame_source),
                       "last_t_s": self.last_frame_t_s if self.last_frame_t_s > -math.inf
                       else None},
            "link": link, "pose": pose, "gimbal": gimbal,
            "grid": {"hash": self._grid_hash, "x0_m": g.x0_m, "y0_m": g.y0_m,
                     "cell_size_m": g.cell_size_m, "n_rows": g.n_rows, "n_cols": g.n_cols,
                     "tile_size": self.tile_size,
                     "origin": {"lat_deg": m.origin_lat_deg, "lon_deg": m.origin_lon_deg,
                                "ground_alt_msl_m": self.origin.ground_alt_msl_m
                                if self.origin else None, "how": self.origin_how}},
            "tiles_seq": self.tiles_seq - 1,
            # Changed tiles not yet sent (the bandwidth budget holds them back): with 0, a
            # watcher holding tiles_seq and frames.grid holds this grid exactly.
            "tiles_behind": len(self._dirty_since),
            "faults": faults, "checkpoint": checkpoint,
        }
