"""Fuzzing the daemon's MAVLink read path in memory (issue 15, bad input): random bytes and
valid frames with hostile field values, duplicated, reordered, from other systems, with time
going back, through pymavlink's parser into LinkProtocol and LiveCoverage (link_feed). The
daemon never raises, never writes a non-finite value into the grid, and counts what it
rejected in its status."""

from __future__ import annotations

import math
import os
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.support.link_feed import Hover, LinkFeed, grid_is_sane, pack, serve_config

EXAMPLES = int(os.environ.get("PDCOV_FUZZ_EXAMPLES", "25"))
"""Examples per property; ``python -m benchmarks.reliability`` runs many more."""
SETTINGS = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])
HOVER = Hover(seconds=4.0).messages()
TAIL = [pack(HOVER[0], seq=200 + i) for i in range(3)]  # clean HEARTBEATs
BAD_FLOATS = (math.nan, math.inf, -math.inf, 1e38, -1e38, 7.0, -100.0, 3e-39)
INT32 = (-(2**31), 2**31 - 1)


@pytest.fixture(scope="module")
def configs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fuzz")
    return {True: serve_config(tmp, gimbal=True), False: serve_config(tmp, gimbal=False)}


def run(cfg, frames: list[bytes], chunks: list[int] | None = None) -> LinkFeed:
    """Feed the frames' bytes (in chunks of the given sizes, cycling), stepping the
    daemon's clock 20 ms per chunk, then tick for 10 s more."""
    f = LinkFeed(cfg)
    data = b"".join(frames)
    sizes = chunks or [len(data) or 1]
    at, k, now = 0, 0, 0.0
    while at < len(data):
        n = max(1, sizes[k % len(sizes)])
        f.feed(data[at:at + n], now)
        at, k, now = at + n, k + 1, now + 0.02
    for _ in range(20):
        now += 0.5
        f.tick(now)
    grid_is_sane(f.live)
    return f


def rejected(f: LinkFeed) -> int:
    """Everything the status reports as refused input."""
    s = f.status()
    faults = s["faults"]
    return (sum(faults.get(k, 0) for k in ("bad_messages", "nan_samples", "invalid_samples"))
            + sum(s["link"]["rejected"].values()) + s["link"]["other_systems"]
            + s["link"]["unknown"])


def test_the_clean_hover_is_used(configs):
    for gimbal in (True, False):
        f = run(configs[gimbal], [pack(m) for m in HOVER])
        assert f.live.counters.used >= 15, f.status()["frames"]
        assert rejected(f) == 0, f.status()


@SETTINGS
@given(junk=st.lists(st.tuples(st.integers(0, len(HOVER)), st.binary(min_size=1,
                                                                       max_size=64)),
                     max_size=20),
       chunks=st.lists(st.integers(1, 300), min_size=1, max_size=8),
       flips=st.lists(st.integers(0, 10**6), max_size=20), gimbal=st.booleans())
def test_random_bytes_between_and_inside_frames(configs, junk, chunks, flips, gimbal):
    frames = [pack(m, seq=i) for i, m in enumerate(HOVER)]
    for at, blob in sorted(junk, reverse=True):
        frames.insert(at, blob)
    data = bytearray(b"".join(frames))
    for i in flips:
        data[i % len(data)] ^= 0xA5
    # The link goes on (clean heartbeats): a damaged header at the very end would otherwise
    # leave the parser waiting for bytes that never come, and nothing could count it.
    f = run(configs[gimbal], [bytes(data), *TAIL], chunks)
    if junk or bytes(data) != b"".join(pack(m, seq=i) for i, m in enumerate(HOVER)):
        assert rejected(f) >= 1, f.status()


def test_a_corrupted_message_id_is_counted(configs):
    """Found by the 500-example run: a flipped bit in an ATTITUDE's message id (30 ^ 0xA5 =
    187, an id the dialect does not know) passes the parser, whose checksum cannot be checked
    without the id's CRC_EXTRA: the message is lost, and counted as unknown."""
    frames = [pack(m, seq=i) for i, m in enumerate(HOVER)]
    k = next(i for i, m in enumerate(HOVER) if m.get_type() == "ATTITUDE")
    bad = bytearray(frames[k])
    bad[7] ^= 0xA5  # MAVLink 2: STX len incompat compat seq sys comp msgid(3 bytes) ...
    frames[k] = bytes(bad)
    f = run(configs[False], frames)
    assert f.status()["link"]["unknown"] == 1
    assert rejected(f) == 1


@SETTINGS
@given(blob=st.binary(max_size=4000), gimbal=st.booleans())
def test_only_random_bytes(configs, blob, gimbal):
    f = run(configs[gimbal], [blob], [97])
    assert f.live.counters.used == 0


ATT_FIELDS = ("roll", "pitch", "yaw")
GIMBAL_Q = ("zero", "nan", "inf", "tiny", "huge", "non-unit")


def _hostile_quaternion(kind: str) -> list[float]:
    return {"zero": [0.0, 0.0, 0.0, 0.0], "nan": [math.nan, 0, 0, 1.0],
            "inf": [math.inf, 0, 0, 0], "tiny": [1e-30, 0, 0, 0],
            "huge": [1e30, 1e30, 0, 0], "non-unit": [0.3, 0.0, -0.3, 0.0]}[kind]


@st.composite
def mutation(draw):
    """(index into HOVER, what to do, value): a hostile value in one field of one message."""
    i = draw(st.integers(2, len(HOVER) - 1))
    name = HOVER[i].get_type()
    if name == "ATTITUDE":
        return i, draw(st.sampled_from(ATT_FIELDS)), draw(
            st.one_of(st.sampled_from(BAD_FLOATS), st.floats(width=32)))
    if name == "GLOBAL_POSITION_INT":
        return i, draw(st.sampled_from(("lat", "lon", "alt", "relative_alt"))), draw(
            st.one_of(st.sampled_from(INT32 + (900_000_001, -1_800_000_001, 0)),
                      st.integers(*INT32)))
    if name == "GIMBAL_DEVICE_ATTITUDE_STATUS":
        return i, "q", draw(st.sampled_from(GIMBAL_Q))
    return i, "time_boot_ms", draw(st.integers(0, 2**32 - 1))


def _invalid(field: str, value) -> bool:
    """Whether the daemon must refuse (and count) the message with this value."""
    if field in ATT_FIELDS:
        return not (math.isfinite(value) and abs(value) <= 2 * math.pi + 0.01)
    if field == "lat":
        return abs(value) > 900_000_000
    if field == "lon":
        return abs(value) > 1_800_000_000
    if field == "q":
        return value in ("zero", "nan", "inf", "tiny")
    return False


@SETTINGS
@given(muts=st.lists(mutation(), max_size=12), gimbal=st.booleans())
def test_hostile_field_values_are_refused_and_counted(configs, muts, gimbal):
    msgs = list(HOVER)
    invalid: dict[int, bool] = {}
    final: dict[tuple[int, str], object] = {}
    for i, field, value in muts:
        m = msgs[i]
        m = type(m)(*[getattr(m, n) for n in m.fieldnames])
        m._header = HOVER[i]._header
        if field == "q":
            m.q = _hostile_quaternion(value)
        else:
            setattr(m, field, value)
        if field == "lat" and m.lon == 0 and value == 0:
            continue  # lat 0, lon 0 is ArduPilot's "no position yet", not bad data
        msgs[i] = m
        final[(i, field)] = value  # a later mutation of the same field replaces it
    for (i, field), value in final.items():
        invalid[i] = invalid.get(i, False) or (_invalid(field, value)
                                               and (gimbal or field != "q"))
    f = run(configs[gimbal], [pack(m) for m in msgs])
    assert rejected(f) >= sum(invalid.values()), (muts, f.status()["faults"], f.status()["link"])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), duplicate=st.floats(0, 0.5), reorder=st.floats(0, 0.5),
       other=st.floats(0, 0.3), back=st.floats(0, 0.2), gimbal=st.booleans())
def test_duplicates_reordering_other_systems_time_going_back(configs, seed, duplicate,
                                                             reorder, other, back, gimbal):
    rng = random.Random(seed)
    frames: list[bytes] = [pack(HOVER[0]), pack(HOVER[1])]
    n_other = 0
    for m in HOVER[2:]:
        if hasattr(m, "time_boot_ms") and rng.random() < back:
            m = type(m)(*[getattr(m, n) for n in m.fieldnames])
            m.time_boot_ms = max(0, m.time_boot_ms - rng.choice((50, 1500, 2500, 10**6)))
        if rng.random() < other:
            frames.append(pack(m, system_id=rng.choice((2, 42, 255)),
                               component_id=rng.randrange(256)))
            n_other += 1
            continue
        frames.append(pack(m))
        if rng.random() < duplicate:
            frames.append(frames[-1])
        if len(frames) > 3 and rng.random() < reorder:
            frames[-1], frames[-2] = frames[-2], frames[-1]
    f = run(configs[gimbal], frames, [rng.randrange(1, 200) for _ in range(5)])
    assert f.status()["link"]["other_systems"] >= n_other


def test_a_time_jump_far_ahead_does_not_stall_the_daemon(configs):
    """A CRC-valid time_boot_ms near 2**32 ms (49 days) must not make the frame lattice walk
    every 0.2 s frame to it one batch at a time."""
    import time
    msgs = list(HOVER)
    for i in range(40, 44):
        m = msgs[i]
        if hasattr(m, "time_boot_ms"):
            m = type(m)(*[getattr(m, n) for n in m.fieldnames])
            m.time_boot_ms = 2**32 - 1000
            msgs[i] = m
    start = time.process_time()
    f = run(configs[False], [pack(m) for m in msgs])
    assert time.process_time() - start < 5.0
    assert f.live.counters.used >= 15, f.status()["frames"]
    assert f.live.counters.skipped["attitude gap"] > 2e7  # 49 days of 5 Hz frames, counted


@pytest.mark.parametrize("gimbal", [True, False])
def test_frames_after_a_long_outage_or_a_reboot_are_used(configs, gimbal):
    """Telemetry stops for 15 s (longer than half the tracker's history), or the autopilot
    reboots (its clock restarts; the daemon's clock jumps 60 s on): the frames after it are
    evaluated (the daemon used to wait for ever for samples it did not feed)."""
    msgs = Hover(seconds=40).messages()
    gone = [m for m in msgs if not 10_000 <= getattr(m, "time_boot_ms", 0) < 25_000]
    f = run(configs[gimbal], [pack(m) for m in gone])
    assert f.live.counters.used >= 5 * 24, f.status()["frames"]
    rebooted = []
    for m in msgs:
        if getattr(m, "time_boot_ms", 0) >= 20_000:
            m = type(m)(*[getattr(m, n) for n in m.fieldnames])
            m.time_boot_ms -= 15_000
        rebooted.append(m)
    f = run(configs[gimbal], [pack(m) for m in rebooted])
    assert f.status()["link"]["reboots"] == 1
    assert f.live.counters.used >= 5 * 36, f.status()["frames"]
