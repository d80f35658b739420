"""argparse types shared by every command: numbers checked for range and finiteness, output
paths checked before any work is done, MAVLink connection URLs. A bad value is argparse's
usage error (one line naming the option, exit 2), never a traceback after minutes of work.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from pdcov.atomic import check_output_dir, check_output_file
from pdcov.errors import OutputError
from pdcov.telemetry.link_url import TOOL_SCHEMES, link_url_problem


def _number(text: str, kind: type = float) -> float:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def finite(text: str) -> float:
    """Any finite number (angles, ENU coordinates)."""
    return _number(text)


def positive(text: str) -> float:
    """A finite number > 0 (altitude, speed, spacing, size, duration)."""
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def nonnegative(text: str) -> float:
    """A finite number >= 0 (a clearance, a time limit where 0 turns a step off)."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def probability(text: str) -> float:
    """A probability or proportion in [0, 1]."""
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return value


def overlap(text: str) -> float:
    """A side overlap of the swath in [0, 1)."""
    value = _number(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"expected an overlap in [0, 1), got {text!r}")
    return value


def _path_type(check: Callable[[Path], Path]) -> Callable[[str], Path]:
    def parse(text: str) -> Path:
        try:
            return check(Path(text))
        except OutputError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return parse


output_dir = _path_type(check_output_dir)
output_dir.__doc__ = "An output folder that can be created or replaced (atomic.py)."
output_file = _path_type(check_output_file)
output_file.__doc__ = "An output file whose folder exists and is writable."

def mavlink_url(text: str) -> str:
    """A MAVLink connection of the ground tools (telemetry/link_url.py TOOL_SCHEMES)."""
    problem = link_url_problem(text, TOOL_SCHEMES)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return text
