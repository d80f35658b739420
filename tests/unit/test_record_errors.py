"""`pdcov watch --record` on a disk that fails (issue 23): a write error is logged once per
episode, counted and retried; the payloads wait in order in a bounded backlog, and the
recording ends complete once the disk takes them again. Nothing ever raises to the shell."""

from __future__ import annotations

import errno
import json
import logging
import os
from pathlib import Path

import pytest

from pdcov.ground.record import TILE_RECORD, Recording


class FlakyDisk:
    """os.write that fails with ``error`` while ``failing``, and writes at most ``chunk``
    bytes a call (a short write, as a full or slow file system gives)."""

    def __init__(self, error: int = errno.ENOSPC, chunk: int | None = None) -> None:
        self.failing = False
        self.error = error
        self.chunk = chunk
        self.calls = 0

    def __call__(self, fd: int, data: memoryview) -> int:
        self.calls += 1
        if self.failing:
            raise OSError(self.error, os.strerror(self.error))
        return os.write(fd, data if self.chunk is None else data[: self.chunk])


def received(n: int) -> list[tuple[str, str, bytes]]:
    """n payloads of each kind, as the shell hands them to the recorder."""
    out = []
    for i in range(n):
        out.append(("uav1", "status", json.dumps({"schema": "pdcov.status", "seq": i}).encode()))
        out.append(("uav1", "tiles", b"PDTL" + bytes([i]) * (40 + i)))
    out.append(("uav1", "snapshot", b"PK snapshot bytes"))
    out.append(("uav1", "mission", b'{"schema": "pdcov.mission"}'))
    return out


def tiles_records(path: Path) -> list[bytes]:
    data = path.read_bytes()
    out, at = [], 0
    while at < len(data):
        _, n = TILE_RECORD.unpack_from(data, at)
        at += TILE_RECORD.size
        out.append(data[at:at + n])
        at += n
    assert at == len(data)
    return out


def check_complete(folder: Path, payloads) -> None:
    statuses = [json.loads(line)["status"]["seq"]
                for line in (folder / "uav1" / "status.jsonl").read_text().splitlines()]
    assert statuses == [json.loads(p)["seq"] for _, k, p in payloads if k == "status"]
    assert tiles_records(folder / "uav1" / "tiles.bin") == [
        p for _, k, p in payloads if k == "tiles"]
    assert (folder / "uav1" / "snapshot-1.npz").read_bytes() == b"PK snapshot bytes"
    assert (folder / "uav1" / "mission-1.json").read_bytes() == b'{"schema": "pdcov.mission"}'


def test_a_full_disk_for_a_while_loses_nothing_that_fits(tmp_path, caplog):
    disk = FlakyDisk()
    rec = Recording(tmp_path / "rec", write=disk)
    payloads = received(20)
    caplog.set_level(logging.WARNING, "pdcov.watch")
    for k, (vid, kind, payload) in enumerate(payloads):
        disk.failing = 5 <= k < 30  # ENOSPC for 25 payloads, then space again
        rec(vid, kind, payload)  # never raises
        if disk.failing:
            assert rec.pending == k - 4 and "No space left on device" in (rec.last_error or "")
            # What the views show (terminal, --plain, web map: ground/app.py).
            assert f"No space left on device), {k - 4} payloads waiting" in (
                rec.warning or "")
    assert rec.pending == 0 and rec.last_error is None and rec.dropped == 0
    assert rec.warning is None  # nothing lost: nothing to say once writing works
    assert rec.write_errors == 25
    rec.close()
    check_complete(tmp_path / "rec", payloads)
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 2, warnings  # one episode: its start, and writing again
    assert "cannot write" in warnings[0] and "No space left on device" in warnings[0]
    assert "writing again (25 failed attempts" in warnings[1]


def test_short_writes_and_eio_never_repeat_or_cut_a_record(tmp_path):
    disk = FlakyDisk(error=errno.EIO, chunk=7)
    rec = Recording(tmp_path / "rec", write=disk)
    payloads = received(10)
    for k, (vid, kind, payload) in enumerate(payloads):
        disk.failing = k % 3 == 1
        rec(vid, kind, payload)
    disk.failing = False
    assert rec.flush() and rec.write_errors > 0
    rec.close()
    check_complete(tmp_path / "rec", payloads)


def test_the_backlog_is_bounded_and_what_overflows_is_counted(tmp_path, caplog):
    disk = FlakyDisk()
    rec = Recording(tmp_path / "rec", write=disk, max_backlog_bytes=1000)
    payloads = received(40)
    disk.failing = True
    for vid, kind, payload in payloads:
        rec(vid, kind, payload)
    kept = rec.pending
    assert 0 < kept < len(payloads) and rec.dropped == len(payloads) - kept
    disk.failing = False
    assert rec.flush() and rec.pending == 0
    statuses = (tmp_path / "rec" / "uav1" / "status.jsonl").read_text().splitlines()
    first = payloads[:kept]  # what came up to the first drop, nothing after it
    assert [json.loads(line)["status"]["seq"] for line in statuses] == [
        json.loads(p)["seq"] for _, k, p in first if k == "status"]
    assert tiles_records(tmp_path / "rec" / "uav1" / "tiles.bin") == [
        p for _, k, p in first if k == "tiles"]
    assert not list((tmp_path / "rec" / "uav1").glob("snapshot-*"))
    rec("uav1", "snapshot", b"PK after")  # writing again: taken again; numbered as received
    assert (tmp_path / "rec" / "uav1" / "snapshot-2.npz").read_bytes() == b"PK after"
    assert rec.warning.endswith(f"writing again, {rec.dropped} payloads not recorded")
    rec.close()
    lines = rec.finish(_NoGrids(), None)
    assert f"{rec.dropped} dropped" in lines[0]


class _NoGrids:
    """A watcher that rebuilt nothing (finish only reads these two)."""

    feeds: dict = {}

    def fleet_state(self):
        return None, ()


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_a_real_full_device_never_raises(tmp_path, caplog):
    """status.jsonl on /dev/full (every write: ENOSPC), the rest on the real disk."""
    rec = Recording(tmp_path / "rec")
    (tmp_path / "rec" / "uav1").mkdir()
    (tmp_path / "rec" / "uav1" / "status.jsonl").symlink_to("/dev/full")
    caplog.set_level(logging.WARNING, "pdcov.watch")
    for _ in range(5):
        rec("uav1", "status", b'{"seq": 1}')
        rec("uav1", "tiles", b"PDTL tiles")
    assert rec.write_errors == 10 and rec.pending == 10
    assert "No space left on device" in (rec.last_error or "")
    assert len(caplog.records) == 1
    rec.close()  # the last try fails too: logged, not raised
    assert rec.pending == 10 and "could not be written" in caplog.records[-1].getMessage()


def test_a_status_with_non_finite_numbers_is_recorded_as_strict_json(tmp_path):
    rec = Recording(tmp_path / "rec")
    rec("uav1", "status", b'{"mean_pd": Infinity}')
    rec("uav1", "status", b'{"mean_pd": 0.5}')
    rec("uav1", "status", b"\xff not json")
    rec.close()
    lines = (tmp_path / "rec" / "uav1" / "status.jsonl").read_text().splitlines()

    def refuse(name):
        raise ValueError(name)
    docs = [json.loads(line, parse_constant=refuse)["status"] for line in lines]
    assert docs == ['{"mean_pd": Infinity}', {"mean_pd": 0.5}, "\ufffd not json"]
