"""Faults end to end with real processes (issue 15, part A), at CI sizes: the functions of
``benchmarks/reliability/``, whose documented run (``python -m benchmarks.reliability
--write-docs``: a 2-hour soak, 50 kills, a 60 s router outage) writes docs/reliability.md.
Each starts ``pdcov-sitl fly``, ``pdcov serve`` and a Zenoh router in this process and runs
the watcher's shell in a thread; every process is killed and every session closed at the
end, also on failure."""

from __future__ import annotations

import pytest

from benchmarks.reliability.crash import crash
from benchmarks.reliability.outages import disk_full, router_outage
from benchmarks.reliability.soak import soak


def test_soak_10_simulated_minutes_with_faults(tmp_path):
    r = soak(tmp_path, flight_s=600, speed=12, rss_every_s=1.0, timeout_s=240)
    assert r.exit_code == 0 and not r.traceback
    assert r.frames_live > 1500
    # The final grid is pdcov evaluate of what the daemon received, and the watcher's.
    assert r.frames_live == r.frames_recording
    assert r.differ_recording == 0 and r.differ_watcher == 0
    # Frames missing from the recording outside the injected faults can only be telemetry
    # the kernel dropped because the daemon fell behind at 12x on a loaded machine (counted
    # at its socket), never telemetry it received and lost.
    assert r.udp_drops is not None
    assert not r.lost or r.udp_drops > 0, (r.lost, r.udp_drops)
    assert r.status["faults"].get("bad_messages", 0) > 0  # corrupt bytes were counted
    # Resident memory flat after warm-up (the grid, buffers and history are bounded).
    assert r.rss_growth_mib < 15, r.rss


def test_kill_9_resumes_a_recent_checkpoint(tmp_path):
    r = crash(tmp_path, kills=5, period_s=0.25)
    assert not r.failures, r.failures
    assert r.resumed == 5 and r.set_aside == 0
    # The resumed checkpoint is at most one period old, plus a tick, a write and the
    # loop's delays on a loaded machine.
    assert max(r.ages_s) <= r.period_s + 0.5, r.ages_s
    # Kills 1, 3 and 5 are aimed at a checkpoint write: most leave its temporary file.
    assert r.aimed == 3 and r.during_write >= 2, (r.aimed, r.during_write, r.tmp_sizes)


def test_the_watcher_recovers_the_grid_after_the_router_was_gone(tmp_path):
    r = router_outage(tmp_path, outage_s=10.0)
    assert r.exit_code == 0
    assert r.frames_final > r.frames_after_outage >= r.frames_before
    assert r.differ == 0


def test_disk_full_keeps_computing_and_checkpoints_again(tmp_path):
    r = disk_full(tmp_path, full_s=6.0)
    if r.skipped:
        pytest.skip(r.skipped)
    assert r.frames_while_full > 0 and r.statuses_while_full >= 5
    assert r.checkpoint_errors > 0 and "No space left" in (r.error_in_status or "")
    assert r.checkpoint_again_s < 5.0 and r.recording_again
    assert r.exit_code == 0 and r.final_frames > r.frames_when_full
