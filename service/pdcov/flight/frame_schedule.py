"""Where the daemon's frames fall and when each can be decided: ``FrameSchedule``.

Frames lie on the ``frame_policy.FrameLattice`` (frame source 'rate': every 1/rate s from
the first time all needed streams have samples, as ``pdcov evaluate`` places them), or at
the capture / detector frame times queued (otherwise). A frame is decidable once every
stream has a sample at or after it (its bracketing samples are final), or once some
stream's last sample lies more than max_gap_s (+ reorder_s) behind the newest telemetry
(then the tracker skips it, as offline). A hole in the telemetry is skipped at once. All
times are the autopilot clock (s).
"""

from __future__ import annotations

import bisect
import math
from collections import Counter
from collections.abc import Sequence
from typing import TYPE_CHECKING

from pdcov.telemetry.frame_policy import FrameLattice, FrameSource, SkipReason

if TYPE_CHECKING:
    from pdcov.telemetry.pose_tracker import PoseTracker
    from pdcov.telemetry.samples import Sample

__all__ = ["FrameSchedule"]


class FrameSchedule:
    """The frames to come. needed: the streams a frame waits for ('attitude', 'position',
    'gimbal'); waiting: the samples not yet given to the tracker (the caller's queue, read
    only); skipped: the counter of skipped frames by reason (counted into)."""

    def __init__(self, frame_source: FrameSource, rate_hz: float, max_gap_s: float,
                 reorder_s: float, needed: tuple[str, ...], waiting: Sequence[Sample],
                 skipped: Counter) -> None:
        self.frame_source = frame_source
        self.rate_hz = rate_hz
        self.max_gap_s = max_gap_s
        self.reorder_s = reorder_s
        self.needed = needed
        self._waiting = waiting
        self._skipped = skipped
        self.latest: dict[str, float] = {}  # stream -> newest sample time given
        self.lattice: FrameLattice | None = None  # rate frames, once the streams start
        self._k_next = 0
        self._queue: list[float] = []  # capture / detector frame times
        self.last_frame_t_s = -math.inf

    def add_frame_times(self, t_s: Sequence[float]) -> list[float]:
        """Frame times from capture events or the detector; returns those taken, in order
        (not: a duplicate, or one at or before a decided frame)."""
        taken = []
        for t in t_s:
            if self.is_late(t):
                self._skipped[SkipReason.LATE_FRAME_TIME] += 1
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

    def saw(self, stream: str, t_s: float) -> None:
        """The tracker was given a sample of ``stream`` at ``t_s``."""
        self.latest[stream] = max(self.latest.get(stream, -math.inf), t_s)

    def forget(self, stream: str) -> None:
        """``stream`` starts anew (the gimbal source changed)."""
        self.latest.pop(stream, None)

    @property
    def t0_s(self) -> float | None:
        """The rate lattice's first frame, once it started."""
        return self.lattice.t0_s if self.lattice is not None else None

    def next_frame_t(self) -> float | None:
        if self.frame_source == FrameSource.RATE:
            if self.lattice is None:
                return None
            return self.lattice.t(self._k_next)
        return self._queue[0] if self._queue else None

    def advance(self) -> None:
        """The next frame was taken into a batch."""
        if self.frame_source == FrameSource.RATE:
            self._k_next += 1
        else:
            self._queue.pop(0)

    def skip_hole(self, t: float) -> bool:
        """Skip at once, as 'attitude gap' (what offline says of them), the frames from
        ``t`` on that lie in a hole of the telemetry: after every sample given to the
        tracker and more than max_gap_s + reorder_s before every waiting sample (a link
        outage or an autopilot reboot longer than half the history, a time jump). True when
        some were skipped. Without this the loop would wait for samples it never feeds."""
        if not self._waiting or t <= self.latest_all():
            return False
        end = min(s.t_s for s in self._waiting) - self.max_gap_s - self.reorder_s
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
        self._skipped[SkipReason.ATTITUDE_GAP] += n
        return True

    def resume_lattice(self, t0_s: float | None, last_frame_t_s: float) -> None:
        """Continue a checkpointed run: the frame lattice anchored at ``t0_s`` (rate mode),
        the frames after ``last_frame_t_s`` (continued by the link)."""
        self.last_frame_t_s = last_frame_t_s
        if t0_s is not None and self.frame_source == FrameSource.RATE:
            self.lattice = FrameLattice(t0_s, self.rate_hz)
            self._k_next = self.lattice.count_until(last_frame_t_s)

    def latest_all(self) -> float:
        return max(self.latest.values(), default=-math.inf)

    def start_lattice(self, tr: PoseTracker) -> float | None:
        if any(s not in self.latest for s in self.needed):
            return None
        t0, _t1 = tr.coverage_s()
        if not math.isfinite(t0):
            return None
        self.lattice, self._k_next = FrameLattice(t0, self.rate_hz), 0
        return self.lattice.t(0)

    def decidable(self, t: float) -> bool:
        # The newest telemetry, fed or still waiting beyond the feed horizon (after an
        # autopilot reboot the clock jumps ahead: frames in the jump are gaps).
        newest = max(self.latest_all(), self._waiting[-1].t_s if self._waiting
                     else -math.inf)
        if t > newest:
            return False  # no telemetry reaches this frame yet
        final = True
        for s in self.needed:
            last = self.latest.get(s, -math.inf)
            if last < t:
                final = False
                if newest - self.reorder_s - last > self.max_gap_s:
                    return True  # this stream's gap is already too long: skip it now
        return final

    @property
    def frames_pending(self) -> int:
        if self.frame_source != FrameSource.RATE:
            return len(self._queue)
        t = self.next_frame_t()  # None until the lattice starts
        if t is None or not self.latest:
            return 0
        return max(0, math.floor((self.latest_all() - t) * self.rate_hz) + 1)
