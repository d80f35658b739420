"""What the fuzz properties of the file and payload readers share (issue 15, bad input):
the example count, the hostile values, mutations of documents and of bytes, and the rule
that a reader raises a PdcovError with a message or nothing. ``PDCOV_FUZZ_EXAMPLES`` sets
the examples per property (25; ``python -m benchmarks.reliability`` runs 500)."""

from __future__ import annotations

import copy
import math
import os

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from pdcov.errors import PdcovError

EXAMPLES = int(os.environ.get("PDCOV_FUZZ_EXAMPLES", "25"))
SETTINGS = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])
HOSTILE = (None, "", "x" * 300, -1, 0, 1e308, -1e308, math.nan, math.inf, True, [], {},
           [[]], {"a": 1}, [1, 2, 3], 2**64, "0", "nan", ".inf")


def _paths(doc, prefix=()):
    """Every path (tuple of keys / indices) to a node of a JSON-like document."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


@st.composite
def mutated_doc(draw, doc):
    """``doc`` with a few nodes replaced by hostile values or deleted."""
    out = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p in _paths(out) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = out
        for k in path[:-1]:
            parent = parent[k]
        if draw(st.booleans()) and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            # A copy: a later mutation may write into it, and HOSTILE's lists and mappings
            # are shared by every example (writing into them made cyclic documents).
            parent[path[-1]] = copy.deepcopy(draw(st.one_of(
                st.sampled_from(HOSTILE), st.floats(), st.integers(), st.text(max_size=20))))
    return out


@st.composite
def mutated_bytes(draw, data: bytes):
    """``data`` truncated, with bytes flipped, deleted or inserted."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(("flip", "cut", "insert", "truncate")))
        i = draw(st.integers(0, max(0, len(b) - 1)))
        if op == "flip" and b:
            b[i] ^= draw(st.integers(1, 255))
        elif op == "cut":
            del b[i:i + draw(st.integers(1, 16))]
        elif op == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=16))
        else:
            del b[i:]
    return bytes(b)


def only_pdcov_errors(read, *args) -> object | None:
    """Call the reader: a value, or None when it raised a PdcovError with a message. Any
    other exception fails the test (it would reach the user as a traceback)."""
    try:
        return read(*args)
    except PdcovError as exc:
        assert str(exc).strip(), "an error without a message"
        return None
