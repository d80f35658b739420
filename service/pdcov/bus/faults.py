"""The keys of the status's ``faults`` counts: what the daemon survived, counted and reported,
never raised. Declared here once; docs/protocol.md "Fault keys" lists the same names
(tests/unit/test_fault_keys.py holds the two equal and every count to these names).

A count is keyed by a ``Fault`` (a str: its value is the key on the bus), or by a
``FaultFamily`` key: a prefix and the lower-case name of a reason enum member.
"""

from __future__ import annotations

import enum

__all__ = ["Fault", "FaultFamily"]


class Fault(str, enum.Enum):
    """One key of the status's ``faults`` (docs/protocol.md "Fault keys")."""

    # The link and its samples.
    BAD_MESSAGES = "bad_messages"
    LINK_PARSE_ERRORS = "link_parse_errors"
    REJECTED_MESSAGES = "rejected_messages"
    OTHER_SYSTEMS_MESSAGES = "other_systems_messages"
    REBOOTS = "reboots"
    LINK_LOSSES = "link_losses"
    KERNEL_DROPS = "kernel_drops"
    UNTIMED_SAMPLES = "untimed_samples"
    NAN_SAMPLES = "nan_samples"
    INVALID_SAMPLES = "invalid_samples"
    POSITION_JUMPS = "position_jumps"
    GIMBAL_FAILURES = "gimbal_failures"
    ZOOM_REPORTS_OTHER_CAMERA = "zoom_reports_other_camera"
    SAMPLES_DROPPED_WAITING = "samples_dropped_waiting"
    # Frames of the grid.
    FRAMES_UNTRUSTED = "frames_untrusted"
    FRAMES_WITHOUT_ESTIMATOR_STATUS = "frames_without_estimator_status"
    TERRAIN_MISMATCH = "terrain_mismatch"
    HOME_OFF_DEM = "home_off_dem"
    # The detector's frames messages and boxes.
    BAD_FRAMES_MESSAGES = "bad_frames_messages"
    FRAMES_OUT_OF_RANGE = "frames_out_of_range"
    FRAMES_REFUSED_TOO_OLD = "frames_refused_too_old"
    FRAMES_REFUSED_AHEAD_OF_CLOCK = "frames_refused_ahead_of_clock"
    FRAMES_DROPPED_WAITING = "frames_dropped_waiting"
    BOXES_REFUSED_UNKNOWN_CLASS = "boxes_refused_unknown_class"
    BOXES_OF_FRAMES_NOT_TAKEN = "boxes_of_frames_not_taken"
    BOXES_OF_SKIPPED_FRAMES = "boxes_of_skipped_frames"
    BOXES_DROPPED_WAITING = "boxes_dropped_waiting"
    BOXES_OFF_GROUND = "boxes_off_ground"
    BOXES_OVER_CANDIDATES = "boxes_over_candidates"
    CANDIDATES_EVICTED = "candidates_evicted"
    # The bus, the disk and the retask requests.
    SNAPSHOT_QUERIES_REFUSED = "snapshot_queries_refused"
    CANDIDATES_QUERIES_REFUSED = "candidates_queries_refused"
    ZENOH_PUT_ERRORS = "zenoh_put_errors"
    CHECKPOINT_ERRORS = "checkpoint_errors"
    CANDIDATES_JOURNAL_ERRORS = "candidates_journal_errors"
    RETASK_REFUSED = "retask_refused"

    def __str__(self) -> str:
        return str(self.value)


class FaultFamily(str, enum.Enum):
    """Keys of one count per reason: the prefix and the reason's lower-case name."""

    FRAMES_REFUSED = "frames_refused_"
    """A frames message refused whole, per ``bus.errors.Refusal``."""
    RETASK_REFUSED = "retask_refused_"
    """A retask request refused, per ``service.retask_auth.RetaskRefusal``."""

    def key(self, reason: enum.Enum) -> str:
        """The fault key of ``reason``: e.g. frames_refused_outside_picture."""
        return f"{self.value}{reason.name.lower()}"
