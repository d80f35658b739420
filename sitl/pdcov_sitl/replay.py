"""``pdcov-sitl replay FILE.tlog [--connect URL] [--speed N]``: send a recorded tlog (the
simulator's or a real autopilot's) over a link at its recorded pace, N times faster, or, at
``--speed 0``, as fast as a receiver can take it.

A tlog is a sequence of records: an 8-byte big-endian timestamp (microseconds since the
Unix epoch) followed by one MAVLink 1 or 2 packet (pymavlink's mavlogfile format).
``scan_tlog`` finds the records in bytes, skipping damaged ones (junk such as console text,
a broken timestamp, a packet whose checksum fails); ``replay_schedule`` says when each
record is due; ``replay`` is the I/O around them. Packets are sent as recorded, byte for
byte: sources, sequence numbers and signatures are the log's (packets due together may
share a UDP datagram).
"""

from __future__ import annotations

import argparse
import struct
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import all as mavlink_all

from .link import DEFAULT_URL, Link, LinkError, open_link

TLOG_MIN_US = 978_307_200_000_000  # 2001-01-01: earlier stamps are taken for junk
TLOG_MAX_US = 4_102_444_800_000_000  # 2100-01-01
BURST_PACKETS = 20
"""Packets sent back to back (at --speed 0, or where a log is denser than the receiver can
take: stamps that repeat, a log recorded faster than real time) before a pause of
BURST_PAUSE_S, so at most about 10 000 packets/s: a Python
MAVLink receiver on this machine parses about 20 000 packets/s, and a UDP receiver that
falls behind by more than its socket buffer (about 200 kB) loses datagrams."""
BURST_PAUSE_S = 0.002
MAX_DATAGRAM_BYTES = 1400
"""Packets sent back to back share a datagram up to this size (below a 1500-byte MTU), as
MAVLink over UDP allows: a receiver's socket buffer is counted per datagram (about 1 kB of
kernel overhead each), so one datagram per 40-byte packet would fill it after ~300."""
TCP_MAX_PENDING_BYTES = 65536
DRAIN_S = 5.0
"""How long the bytes still queued for a TCP client may take at the end."""
_CRC_EXTRA = {msg_id: cls.crc_extra for msg_id, cls in mavlink_all.mavlink_map.items()}


@dataclass(frozen=True, slots=True)
class TlogScan:
    """The records found in a tlog (timestamp in µs, packet bytes) and the bytes skipped."""

    records: list[tuple[int, bytes]]
    skipped_bytes: int

    @property
    def span_s(self) -> float:
        if not self.records:
            return 0.0
        times = [t for t, _ in self.records]
        return (max(times) - times[0]) * 1e-6


def _packet_length(data: bytes, i: int) -> tuple[int, int] | None:
    """(length, message id) of the MAVLink packet starting at data[i], from its header."""
    n = len(data)
    if i + 1 >= n:
        return None
    magic, payload_len = data[i], data[i + 1]
    if magic == 0xFD:
        if i + 10 > n:
            return None
        signed = data[i + 2] & 0x01
        msg_id = data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
        return 10 + payload_len + 2 + (13 if signed else 0), msg_id
    if magic == 0xFE:
        if i + 6 > n:
            return None
        return 6 + payload_len + 2, data[i + 5]
    return None


def _checksum_ok(packet: bytes, msg_id: int) -> bool | None:
    """Whether the packet's CRC matches; None for a message id we do not know."""
    extra = _CRC_EXTRA.get(msg_id)
    if extra is None:
        return None
    header_len = 10 if packet[0] == 0xFD else 6
    end = header_len + packet[1]
    crc = mavlink_all.x25crc(packet[1:end])
    crc.accumulate(bytes((extra,)))
    return crc.crc == struct.unpack_from("<H", packet, end)[0]


def _record_at(data: bytes, i: int) -> tuple[int, bytes] | None:
    """The (timestamp, packet) starting at data[i] if it looks sound, else None."""
    if i + 9 > len(data):
        return None
    (t_us,) = struct.unpack_from(">Q", data, i)
    if not TLOG_MIN_US <= t_us <= TLOG_MAX_US:
        return None
    header = _packet_length(data, i + 8)
    if header is None or i + 8 + header[0] > len(data):
        return None
    packet = data[i + 8:i + 8 + header[0]]
    ok = _checksum_ok(packet, header[1])
    if ok is None:  # unknown id: trust it only if a sound record (or the end) follows
        j = i + 8 + len(packet)
        ok = j == len(data) or _record_at_shallow(data, j)
    return (t_us, packet) if ok else None


def _record_at_shallow(data: bytes, i: int) -> bool:
    if i + 9 > len(data):
        return False
    (t_us,) = struct.unpack_from(">Q", data, i)
    return TLOG_MIN_US <= t_us <= TLOG_MAX_US and data[i + 8] in (0xFD, 0xFE)


def scan_tlog(data: bytes) -> TlogScan:
    """Split tlog bytes into records; damaged bytes are skipped one at a time until a
    sound record starts (plausible timestamp, MAVLink header, valid checksum)."""
    records: list[tuple[int, bytes]] = []
    i = skipped = 0
    while i < len(data):
        rec = _record_at(data, i)
        if rec is None:
            i += 1
            skipped += 1
            continue
        records.append(rec)
        i += 8 + len(rec[1])
    return TlogScan(records, skipped)


def replay_schedule(times_us: Sequence[int], speed: float) -> list[float]:
    """Wall-clock offsets (s from the start) at which each record is due: the log's pace
    divided by ``speed``, never earlier than a record before it (stamps that go back are
    sent at once). ``speed`` 0: all at 0 (the sender paces itself in bursts)."""
    if speed < 0:
        raise ValueError(f"speed {speed!r}: expected >= 0")
    if speed == 0 or not times_us:
        return [0.0] * len(times_us)
    out = []
    latest = times_us[0]
    for t in times_us:
        latest = max(latest, t)
        out.append((latest - times_us[0]) * 1e-6 / speed)
    return out


@dataclass(frozen=True, slots=True)
class ReplayResult:
    n_messages: int
    skipped_bytes: int
    span_s: float
    took_s: float

    def summary(self) -> str:
        skipped = f", {self.skipped_bytes} damaged bytes skipped" if self.skipped_bytes else ""
        return (f"replayed {self.n_messages} messages spanning {self.span_s:.1f} s "
                f"in {self.took_s:.1f} s{skipped}")


def replay(scan: TlogScan, link: Link, speed: float) -> ReplayResult:
    """Send the records over ``link`` at ``speed`` (see ``replay_schedule``)."""
    due_s = replay_schedule([t for t, _ in scan.records], speed)
    t0 = time.monotonic()
    batch = bytearray()
    back_to_back = 0

    def flush() -> None:
        if batch:
            link.write(bytes(batch))
            batch.clear()

    for n, ((_, packet), due) in enumerate(zip(scan.records, due_s, strict=True)):
        wait = t0 + due - time.monotonic()
        if wait > 0:
            flush()
            time.sleep(wait)
            back_to_back = 0
        elif back_to_back >= BURST_PACKETS:  # behind the log's pace, or --speed 0
            flush()
            time.sleep(BURST_PAUSE_S)
            back_to_back = 0
            while link.pending_bytes() > TCP_MAX_PENDING_BYTES:
                time.sleep(BURST_PAUSE_S)
        if len(batch) + len(packet) > MAX_DATAGRAM_BYTES:
            flush()
        batch += packet
        back_to_back += 1
        if n % 256 == 0:
            link.read()  # what ground stations send us is dropped, unread buffers full
    flush()
    drain_end = time.monotonic() + DRAIN_S
    while link.pending_bytes() and link.ready() and time.monotonic() < drain_end:
        time.sleep(BURST_PAUSE_S)
    return ReplayResult(len(scan.records), scan.skipped_bytes, scan.span_s,
                        time.monotonic() - t0)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("tlog", type=Path, metavar="FILE.tlog", help="the log to send")
    parser.add_argument("--connect", default=DEFAULT_URL, metavar="URL",
                        help=f"link to send on (default {DEFAULT_URL}; udpin:, tcp: server, "
                             "tcpout:, pty: as for fly)")
    parser.add_argument("--speed", type=float, default=1.0, metavar="N",
                        help="1 the recorded pace (default), N times faster, 0 as fast as "
                             "the receiver takes it")


def run(args: argparse.Namespace) -> int:
    """Replay as ``add_arguments`` parsed; bad input -> message on stderr, 2."""
    if not args.speed >= 0:
        print(f"pdcov-sitl replay: --speed {args.speed}: expected a number >= 0",
              file=sys.stderr)
        return 2
    try:
        data = args.tlog.read_bytes()
    except OSError as exc:
        print(f"pdcov-sitl replay: cannot read {args.tlog}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    scan = scan_tlog(data)
    if not scan.records:
        print(f"pdcov-sitl replay: {args.tlog}: no MAVLink tlog records found "
              f"({len(data)} bytes)", file=sys.stderr)
        return 2
    try:
        link = open_link(args.connect)
    except (LinkError, OSError) as exc:
        print(f"pdcov-sitl replay: {exc}", file=sys.stderr)
        return 2
    try:
        if not link.ready():
            print(f"waiting for a ground station on {link.describe()}", file=sys.stderr)
            while not link.ready():
                time.sleep(0.05)
        result = replay(scan, link, args.speed)
    except KeyboardInterrupt:
        return 130
    finally:
        link.close()
    print(result.summary())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point: ``argv`` are the arguments after ``replay`` (strings), or an
    argparse.Namespace already parsed with ``add_arguments``."""
    if isinstance(argv, argparse.Namespace):
        return run(argv)
    parser = argparse.ArgumentParser(prog="pdcov-sitl replay", description=__doc__.split(
        "\n\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))
