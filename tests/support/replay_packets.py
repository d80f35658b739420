"""MAVLink packets and the .tlog bytes of them, for the tests of `pdcov-sitl replay`."""

from __future__ import annotations

import struct

from pymavlink.dialects.v20 import common as mavlink2

T0_US = 1_767_225_600_000_000


def packets(n, msg_type="attitude"):
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for i in range(n):
        msg = mav.attitude_encode(i * 10, 0.1 * i, 0.0, 0.0, 0.0, 0.0, 0.0)
        out.append(bytes(msg.pack(mav)))
        mav.seq = (mav.seq + 1) % 256
    return out


def tlog_bytes(pkts, step_us=20_000):
    return b"".join(struct.pack(">Q", T0_US + i * step_us) + p for i, p in enumerate(pkts))
