"""The value checks the mission config's sections share: a number, an optional number, a
mapping, a file path, a section's defaults. Every error names the file and the key."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

from pdcov.errors import ConfigError, where

FLOAT_MAX = sys.float_info.max


def defaults(section: type) -> dict[str, Any]:
    """The default value of each field of a section dataclass that has one."""
    return {f.name: f.default for f in fields(section) if f.default is not MISSING}


def mapping(doc: Mapping[str, Any], key: str, src: str | None,
            required: bool = True) -> Mapping[str, Any]:
    """``doc[key]``, a mapping ({} when absent and not ``required``)."""
    v = doc.get(key)
    if v is None and not required:
        return {}
    if not isinstance(v, dict):
        raise ConfigError(f"{where(src, key)}: expected a mapping, got {v!r}")
    return v


def number(doc: Mapping[str, Any], key: str, src: str | None, section: str,
           default: float | None = None, positive: bool = False) -> float:
    """``doc[key]`` (else ``default``) as a finite float, > 0 if ``positive``; errors name
    ``section.key``."""
    full = f"{section}.{key}"
    v = doc.get(key, default)
    if v is None:
        raise ConfigError(f"{where(src, full)}: missing (a number)")
    # abs(v) <= max float: false for NaN, infinities and integers a float cannot hold
    # (math.isfinite raises OverflowError on those).
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= FLOAT_MAX:
        raise ConfigError(f"{where(src, full)}: expected a finite number, got {v!r}")
    if positive and v <= 0:
        raise ConfigError(f"{where(src, full)}: expected a positive number, got {v!r}")
    return float(v)


def opt_number(doc: Mapping[str, Any], key: str, src: str | None, section: str
               ) -> float | None:
    """``doc[key]`` as a positive float, None when absent or null."""
    return None if doc.get(key) is None else number(doc, key, src, section, positive=True)


def resolve(v: Any, base: Path, src: str | None, key: str) -> Path:
    """The file ``v`` names (relative to ``base``, the config's folder); ConfigError naming
    ``key`` when it is not a path or not a file."""
    if not isinstance(v, str) or not v:
        raise ConfigError(f"{where(src, key)}: expected a file path, got {v!r}")
    p = Path(v).expanduser()
    p = p if p.is_absolute() else base / p
    if not p.is_file():
        raise ConfigError(f"{where(src, key)}: file not found: {p}")
    return p
