"""A run folder's files as the handover report reads them (report/handover.py): each read
once, bounded in size, never recomputed; a missing file is None, a malformed or oversized
one an InputFileError naming it."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.errors import InputFileError

MAX_JSON_BYTES = 64 * 2**20
"""The largest metrics.json, detections.geojson or caltopo.geojson the report reads."""
MAX_IMAGE_BYTES = 32 * 2**20
"""The largest figure (map.png, heatmap.png, thresholds.png) the report puts inline."""
MAX_LISTED_FILES = 500
"""The most files of a run folder the report lists."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True, slots=True)
class RunFiles:
    """What the report shows, as read from a run folder: None where a file is absent."""

    name: str  # the folder's name
    metrics: dict[str, Any]
    detections: dict[str, Any] | None
    caltopo: dict[str, Any] | None
    heatmap_png: bytes | None
    thresholds_png: bytes | None
    map_png: bytes | None
    files: tuple[tuple[str, int], ...]  # (name, bytes) of its files; a folder "name/", -1


def read_bounded(path: Path, limit: int) -> bytes | None:
    """The bytes of ``path`` (None when absent); over ``limit`` bytes it is refused."""
    try:
        size = path.stat().st_size
        if size > limit:
            raise InputFileError(f"{path}: {size:,} bytes, over the report's limit of "
                                 f"{limit:,}; is it a pdcov run's file?")
        with path.open("rb") as f:
            data = f.read(limit + 1)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(data) > limit:  # grew while read
        raise InputFileError(f"{path}: over the report's limit of {limit:,} bytes")
    return data


def _json(path: Path) -> dict[str, Any] | None:
    data = read_bounded(path, MAX_JSON_BYTES)
    if data is None:
        return None
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise InputFileError(f"{path}: expected a JSON object")
    return doc


def _png(path: Path) -> bytes | None:
    data = read_bounded(path, MAX_IMAGE_BYTES)
    if data is not None and not data.startswith(PNG_SIGNATURE):
        raise InputFileError(f"{path}: not a PNG image")
    return data


def _listing(run: Path) -> tuple[tuple[str, int], ...]:
    rows = []
    with os.scandir(run) as entries:
        for e in entries:
            if e.name.startswith("."):  # pdcov's folder marker
                continue
            rows.append((e.name + "/", -1) if e.is_dir() else (e.name, e.stat().st_size))
            if len(rows) > MAX_LISTED_FILES:
                raise InputFileError(f"{run}: over {MAX_LISTED_FILES} files; is it a pdcov "
                                     "run folder?")
    return tuple(sorted(rows))


def read_run_files(run_dir: str | Path) -> RunFiles:
    """The files of ``run_dir`` the report shows. Raises InputFileError naming the file
    when the folder holds no metrics.json or a file is malformed or over its limit."""
    run = Path(run_dir)
    if not run.is_dir():
        raise InputFileError(f"{run}: not a folder (a pdcov run folder, e.g. evaluate --out)")
    metrics = _json(run / "metrics.json")
    if metrics is None:
        raise InputFileError(f"{run}: no metrics.json: not a pdcov run folder")
    return RunFiles(run.resolve().name, metrics, _json(run / "detections.geojson"),
                    _json(run / "caltopo.geojson"), _png(run / "heatmap.png"),
                    _png(run / "thresholds.png"), _png(run / "map.png"), _listing(run))
