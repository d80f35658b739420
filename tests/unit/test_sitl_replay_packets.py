"""`pdcov-sitl replay`'s reading of a log in memory: the scan finds every record, skips junk,
bad checksums and broken stamps, the schedule follows the log's pace, bad input exits 2."""

from __future__ import annotations

import struct

import pytest

from pdcov_sitl.replay import main, replay_schedule, scan_tlog
from tests.support.replay_packets import T0_US, packets, tlog_bytes


def test_scan_finds_every_record_of_a_clean_log():
    pkts = packets(50)
    scan = scan_tlog(tlog_bytes(pkts))
    assert [p for _, p in scan.records] == pkts and scan.skipped_bytes == 0
    assert scan.span_s == pytest.approx(49 * 0.02)


def test_scan_skips_junk_bad_checksums_and_broken_stamps():
    pkts = packets(6)
    records = [struct.pack(">Q", T0_US + i * 1000) + p for i, p in enumerate(pkts)]
    damaged = bytearray(records[2])
    damaged[20] ^= 0xFF  # payload byte: the checksum fails
    broken_stamp = b"\xff" * 8 + pkts[4]
    data = (b"console text\r\n\xfd\x09" + records[0] + records[1] + bytes(damaged)
            + records[3] + broken_stamp + records[5] + b"\x00\x01truncated\xfd")
    scan = scan_tlog(data)
    assert [p for _, p in scan.records] == [pkts[0], pkts[1], pkts[3], pkts[5]]
    assert scan.skipped_bytes == len(data) - sum(len(records[i]) for i in (0, 1, 3, 5))


def test_schedule_follows_the_log_pace():
    times = [T0_US, T0_US + 1_000_000, T0_US + 500_000, T0_US + 3_000_000]
    assert replay_schedule(times, 1.0) == [0.0, 1.0, 1.0, 3.0]  # never back in time
    assert replay_schedule(times, 10.0) == pytest.approx([0.0, 0.1, 0.1, 0.3])
    assert replay_schedule(times, 0.0) == [0.0] * 4
    with pytest.raises(ValueError, match="-1"):
        replay_schedule(times, -1.0)


@pytest.mark.parametrize(("args", "says"), [
    (["missing.tlog"], "cannot read missing.tlog"),
    (["{junk}"], "no MAVLink tlog records found"),
    (["{junk}", "--speed", "-2"], "--speed -2.0: expected a number >= 0"),
    (["{clean}", "--connect", "udp:1:2"], "link 'udp:1:2': expected"),
])
def test_bad_input_exits_2_with_a_message(tmp_path, capsys, monkeypatch, args, says):
    (tmp_path / "junk.tlog").write_bytes(b"not a tlog at all" * 10)
    (tmp_path / "clean.tlog").write_bytes(tlog_bytes(packets(2)))
    monkeypatch.chdir(tmp_path)
    args = [a.format(junk=tmp_path / "junk.tlog", clean=tmp_path / "clean.tlog")
            for a in args]
    assert main(args) == 2
    assert says in capsys.readouterr().err
