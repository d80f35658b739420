"""A previous run's folder and file modes, for the tests of the output folders."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from pdcov.atomic import replacing_dir, write_text_atomic


@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield lambda m: os.umask(m)
    os.umask(old)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def previous_run(out: Path) -> dict[str, bytes]:
    with replacing_dir(out):
        write_text_atomic(out / "metrics.json", '{"frames": 495}')
        write_text_atomic(out / "heatmap.png", "495 frames")
    return snapshot(out)


def snapshot(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}
