"""Offline basemaps for the web map (``pdcov watch --basemap PATH``), read directly, nothing
converted: a folder of XYZ tiles (``PATH/{z}/{x}/{y}.png``, ``.jpg``, ``.jpeg`` or ``.webp``;
web Mercator, y counted from the north as OpenStreetMap numbers tiles) or an MBTiles file
(SQLite, the MBTiles 1.3 ``tiles`` table: zoom_level, tile_column, tile_row, tile_data; rows
in TMS order, counted from the south, so row = 2**z - 1 - y). The page asks for
``/basemap/{z}/{x}/{y}`` (optionally ``.ext``); ``tile`` answers the image or None (404).

Opening checks the input once and says what is wrong (ConfigError): a missing path, a file
that is not SQLite or has no ``tiles`` table, vector tiles (pbf: the map draws raster tiles
only), a folder or file with no tiles. A tile request outside the set is None, never an
exception.

Bounded (``read_tile``, what the web map calls): a tile larger than MAX_TILE_BYTES is refused
before it is read (its size from the file system or SQLite's ``length``), and every read
runs on the set's own two threads, off the event loop, for at most TILE_READ_TIMEOUT_S (an
MBTiles query still running then is interrupted): a slow or hostile file answers its tile
requests with an error and never freezes the map (it froze it for 59 s).
"""

from __future__ import annotations

import asyncio
import sqlite3
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.errors import ConfigError, PdcovError
from pdcov.report.map_figure import BasemapTiles

IMAGE_TYPES = {"png": "image/png", "jpg": "image/jpeg", "jpeg": "image/jpeg",
               "webp": "image/webp"}
MAX_ZOOM = 30  # tile numbers past this overflow what any tile set holds
_MAGIC = ((b"\x89PNG", "png"), (b"\xff\xd8\xff", "jpg"), (b"RIFF", "webp"))
_SQLITE_HEADER = b"SQLite format 3\x00"
MAX_TILE_BYTES = 4 << 20
"""Largest basemap tile served (a 512 px raster tile is tens of kB)."""
TILE_READ_TIMEOUT_S = 2.0
"""Longest a tile read may take before its request is answered 504."""
_READ_THREADS = 2


class TileRefused(PdcovError):
    """A tile not served: too large (HTTP 413) or not read in time (504)."""

    def __init__(self, message: str, http_status: int) -> None:
        super().__init__(message)
        self.http_status = http_status


def _too_large(n_bytes: int, z: int, x: int, y: int) -> TileRefused:
    return TileRefused(f"basemap tile {z}/{x}/{y}: {n_bytes:,} bytes, more than "
                       f"{MAX_TILE_BYTES:,}", 413)


@dataclass(frozen=True, slots=True)
class BasemapInfo:
    """What the page needs to ask for tiles: the zoom levels held (ascending), the image
    type (a key of IMAGE_TYPES), the kind (``xyz`` folder or ``mbtiles``), its name and an
    attribution to show (plain text; empty when the set gives none)."""

    zooms: tuple[int, ...]
    ext: str
    kind: str
    name: str
    attribution: str = ""

    def as_json(self) -> dict[str, Any]:
        return {"zooms": list(self.zooms), "ext": self.ext, "kind": self.kind,
                "name": self.name, "attribution": self.attribution}


def _tile_numbers_ok(z: int, x: int, y: int) -> bool:
    return 0 <= z <= MAX_ZOOM and 0 <= x < 2 ** z and 0 <= y < 2 ** z


class TileFolder:
    """XYZ tiles in ``folder/{z}/{x}/{y}.{ext}``."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.pool = ThreadPoolExecutor(_READ_THREADS, thread_name_prefix="basemap")
        zooms = sorted(int(p.name) for p in folder.iterdir()
                       if p.is_dir() and p.name.isdigit() and int(p.name) <= MAX_ZOOM)
        ext = None
        for z in zooms:
            found = next((p for p in sorted((folder / str(z)).glob("*/*.*"))
                          if p.suffix.lstrip(".").lower() in IMAGE_TYPES), None)
            if found is not None:
                ext = found.suffix.lstrip(".").lower()
                break
        if ext is None:
            raise ConfigError(f"--basemap {folder}: no tiles in this folder (expected XYZ "
                              f"tiles as {{z}}/{{x}}/{{y}}.png or .jpg, e.g. from QGIS "
                              f"'Generate XYZ tiles (Directory)'; docs/ground-station.md "
                              f"'Basemap')")
        self.info = BasemapInfo(tuple(zooms), ext, "xyz", folder.name)

    def tile(self, z: int, x: int, y: int, ext: str | None) -> tuple[bytes, str] | None:
        """The image of tile z/x/y (y from the north) with its content type, None when the
        set has none; ``ext``: the extension asked for, None for the set's own."""
        ext = (ext or self.info.ext).lower()
        if not _tile_numbers_ok(z, x, y) or ext not in IMAGE_TYPES:
            return None
        path = self.folder / str(z) / str(x) / f"{y}.{ext}"
        try:
            if (size := path.stat().st_size) > MAX_TILE_BYTES:
                raise _too_large(size, z, x, y)
            return path.read_bytes(), IMAGE_TYPES[ext]
        except OSError:
            return None

    def interrupt(self) -> None:
        """A file read cannot be interrupted: its thread finishes it."""

    def close(self) -> None:
        """Only the read threads are held."""
        self.pool.shutdown(wait=False, cancel_futures=True)


class MBTiles:
    """An MBTiles file, opened read-only; ``close`` when done."""

    def __init__(self, path: Path) -> None:
        self.path = path
        where = f"--basemap {path}"
        try:
            with path.open("rb") as f:
                header = f.read(len(_SQLITE_HEADER))
        except OSError as exc:
            raise ConfigError(f"{where}: cannot read it ({exc.strerror})") from None
        if header != _SQLITE_HEADER:
            raise ConfigError(f"{where}: neither a folder of XYZ tiles nor an MBTiles file "
                              "(an MBTiles file is an SQLite database)")
        # Read-only: the file is the operator's; several maps may share it. Used from the
        # event loop's thread only, which is not always the thread that opened it.
        self._db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True,
                                   check_same_thread=False)
        try:
            meta = dict(self._db.execute("SELECT name, value FROM metadata").fetchall()) \
                if self._has("metadata") else {}
            if not self._has("tiles"):
                raise ConfigError(f"{where}: an SQLite file without the MBTiles 'tiles' "
                                  "table: not an MBTiles file")
            zooms = tuple(int(r[0]) for r in self._db.execute(
                "SELECT DISTINCT zoom_level FROM tiles ORDER BY zoom_level"))
            if not zooms:
                raise ConfigError(f"{where}: the MBTiles file holds no tiles")
            ext = str(meta.get("format") or self._sniff()).lower()
        except sqlite3.DatabaseError as exc:
            self._db.close()
            raise ConfigError(f"{where}: cannot read it as MBTiles ({exc})") from None
        except ConfigError:
            self._db.close()
            raise
        if ext not in IMAGE_TYPES:
            self._db.close()
            raise ConfigError(f"{where}: tiles of format {ext!r}; the map draws raster "
                              f"tiles only ({', '.join(IMAGE_TYPES)})")
        self.pool = ThreadPoolExecutor(_READ_THREADS, thread_name_prefix="basemap")
        self.info = BasemapInfo(zooms, "jpg" if ext == "jpeg" else ext, "mbtiles",
                                str(meta.get("name") or path.stem),
                                str(meta.get("attribution") or ""))

    def _has(self, table: str) -> bool:
        return self._db.execute("SELECT 1 FROM sqlite_master WHERE name = ? AND type IN "
                                "('table', 'view')", (table,)).fetchone() is not None

    def _sniff(self) -> str:
        """The image type of the first tile, from its magic bytes (no ``format`` given)."""
        row = self._db.execute("SELECT tile_data FROM tiles LIMIT 1").fetchone()
        data = bytes(row[0]) if row and row[0] is not None else b""
        return next((name for magic, name in _MAGIC if data.startswith(magic)), "unknown")

    def tile(self, z: int, x: int, y: int, ext: str | None) -> tuple[bytes, str] | None:
        """As TileFolder.tile; y from the north (the file's TMS row is 2**z - 1 - y)."""
        if not _tile_numbers_ok(z, x, y) or (
                ext is not None and IMAGE_TYPES.get(ext.lower()) != IMAGE_TYPES[self.info.ext]):
            return None
        try:
            row = self._db.execute(
                "SELECT length(tile_data), CASE WHEN length(tile_data) <= ? THEN tile_data "
                "END FROM tiles WHERE zoom_level = ? AND tile_column = ? AND tile_row = ?",
                (MAX_TILE_BYTES, z, x, 2 ** z - 1 - y)).fetchone()
        except sqlite3.Error:
            return None
        if row is None or row[0] is None:
            return None
        if row[1] is None:
            raise _too_large(int(row[0]), z, x, y)
        return bytes(row[1]), IMAGE_TYPES[self.info.ext]

    def interrupt(self) -> None:
        """Abort the query running on another thread (read_tile's timeout)."""
        self._db.interrupt()

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)
        self._db.close()


Basemap = TileFolder | MBTiles


async def read_tile(basemap: Basemap, z: int, x: int, y: int, ext: str | None,
                    timeout_s: float = TILE_READ_TIMEOUT_S) -> tuple[bytes, str] | None:
    """``basemap.tile`` on the set's own threads, off the event loop, for at most
    ``timeout_s``: the tile, None when the set has none; TileRefused (too large, too slow)."""
    read = asyncio.get_running_loop().run_in_executor(basemap.pool, basemap.tile, z, x, y,
                                                      ext)
    try:
        return await asyncio.wait_for(read, timeout_s)
    except TimeoutError:
        basemap.interrupt()
        raise TileRefused(f"basemap tile {z}/{x}/{y}: not read within {timeout_s:g} s "
                          f"(a slow or damaged {basemap.info.kind} set)", 504) from None


def open_basemap(path: Path) -> Basemap:
    """The tile set at ``path``: a folder of XYZ tiles, or an MBTiles file. ConfigError
    saying what is wrong otherwise."""
    if path.is_dir():
        return TileFolder(path)
    if not path.exists():
        raise ConfigError(f"--basemap {path}: no such file or folder (expected a folder of "
                          "XYZ tiles {z}/{x}/{y}.png or an .mbtiles file)")
    return MBTiles(path)


def map_tiles(basemap: Basemap) -> BasemapTiles:
    """``basemap`` as the handover map reads it (report/map_figure.py): a tile too large
    is no tile."""
    def tile(z: int, x: int, y: int) -> bytes | None:
        try:
            found = basemap.tile(z, x, y, None)
        except TileRefused:
            return None
        return None if found is None else found[0]
    return BasemapTiles(tile, basemap.info.zooms, basemap.info.attribution)
