"""Mission documents edited by key path, for the tests of the config schema."""

from __future__ import annotations

import copy


def renamed(doc: dict, path: str, new_key: str, value=None) -> dict:
    """``doc`` with the key at ``path`` (a.b.c) renamed to ``new_key`` (or added with
    ``value`` when absent)."""
    doc = copy.deepcopy(doc)
    *parents, key = path.split(".")
    m = doc
    for p in parents:
        m = m.setdefault(p, {})
    m[new_key] = m.pop(key) if key in m else value
    return doc
