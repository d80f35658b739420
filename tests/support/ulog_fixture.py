"""A small PX4 ULog writer for tests (the file format of docs.px4.io "ULog File Format"):
header, flag bits, formats, info, parameters, subscriptions, then data messages in time
order. pyulog reads what it writes; the tests check that it does."""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from pathlib import Path

ULOG_HEADER = b"ULog\x01\x12\x35"
_PACK = {"uint8_t": "B", "int8_t": "b", "uint16_t": "H", "int16_t": "h", "uint32_t": "I",
         "int32_t": "i", "uint64_t": "Q", "int64_t": "q", "float": "f", "double": "d",
         "bool": "?"}


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _kv(type_and_name: str, value: bytes) -> bytes:
    key = type_and_name.encode()
    return struct.pack("<B", len(key)) + key + value


def write_ulog(path: Path, topics: Mapping[str | tuple[str, int],
                                           tuple[Sequence[tuple[str, str]],
                                                 Sequence[Sequence[float]]]],
               params: Mapping[str, float] | None = None, start_us: int = 0) -> Path:
    """``topics``: name, or (name, multi_id) for an instance other than 0 -> (fields as
    (type, name), first ("uint64_t", "timestamp"); rows of values, arrays flattened).
    Arrays are types like ``float[4]``. Returns ``path``."""
    out = bytearray(ULOG_HEADER + struct.pack("<BQ", 1, start_us))
    out += _msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    formats: dict[str, str] = {}
    for key, (fields, _rows) in topics.items():
        name = key if isinstance(key, str) else key[0]
        formats.setdefault(name, f"{name}:" + "".join(f"{t} {n};" for t, n in fields))
    for fmt in formats.values():  # one format per topic, shared by its instances
        out += _msg(b"F", fmt.encode())
    out += _msg(b"I", _kv("char[9] sys_name", b"PX4_tests"))
    for name, value in (params or {}).items():
        out += _msg(b"P", _kv(f"float {name}", struct.pack("<f", value)))
    packers = {}
    for msg_id, (key, (fields, _rows)) in enumerate(topics.items()):
        name, multi_id = (key, 0) if isinstance(key, str) else key
        out += _msg(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())
        codes = ""
        for t, _n in fields:
            base, _, count = t.partition("[")
            codes += (count.rstrip("]") if count else "") + _PACK[base]
        packers[key] = (msg_id, struct.Struct("<" + codes))
    data = []
    for key, (_fields, rows) in topics.items():
        msg_id, packer = packers[key]
        for row in rows:
            data.append((int(row[0]), _msg(b"D", struct.pack("<H", msg_id) + packer.pack(
                *[int(v) if c in "BbHhIiQq?" else v for v, c in zip(
                    row, _codes(packer.format), strict=True)]))))
    for _t, blob in sorted(data, key=lambda d: d[0]):
        out += blob
    path.write_bytes(bytes(out))
    return path


def _codes(fmt: str) -> str:
    """One letter per value of a struct format like '<Q4f'."""
    out, count = "", ""
    for ch in fmt.lstrip("<"):
        if ch.isdigit():
            count += ch
        else:
            out += ch * int(count or 1)
            count = ""
    return out
