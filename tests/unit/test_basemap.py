"""Offline basemaps (ground/basemap.py): an XYZ folder and an MBTiles file made here, read
directly (the MBTiles TMS row flipped), and bad input refused with a message saying what is
wrong; the web map answers a tile outside the set 404, never an exception."""

from __future__ import annotations

import asyncio
import sqlite3

import pytest

from pdcov.errors import ConfigError
from pdcov.ground.basemap import MBTiles, TileFolder, open_basemap
from pdcov.ground.web import WebMap
from pdcov.ground.web_auth import WebAccess, served_names

PNG = b"\x89PNG\r\n\x1a\n tile "
JPG = b"\xff\xd8\xff tile "
TOKEN = "basemap-test-token-0123456789abcdef"


def mbtiles(path, tiles: dict[tuple[int, int, int], bytes], fmt: str | None = "png",
            **meta: str) -> None:
    """An MBTiles file holding ``tiles`` keyed (z, x, y) with y from the north."""
    db = sqlite3.connect(path)
    db.executescript("CREATE TABLE metadata (name text, value text);"
                     "CREATE TABLE tiles (zoom_level integer, tile_column integer, "
                     "tile_row integer, tile_data blob);")
    if fmt is not None:
        meta["format"] = fmt
    db.executemany("INSERT INTO metadata VALUES (?, ?)", list(meta.items()))
    db.executemany("INSERT INTO tiles VALUES (?, ?, ?, ?)",
                   [(z, x, 2 ** z - 1 - y, data) for (z, x, y), data in tiles.items()])
    db.commit()
    db.close()


def test_an_xyz_folder_serves_its_tiles(tmp_path):
    for z, x, y in ((2, 1, 3), (3, 4, 2)):
        (tmp_path / str(z) / str(x)).mkdir(parents=True)
        (tmp_path / str(z) / str(x) / f"{y}.jpg").write_bytes(JPG + bytes([z]))
    (tmp_path / "notes").mkdir()
    b = open_basemap(tmp_path)
    assert isinstance(b, TileFolder)
    assert b.info.as_json() == {"zooms": [2, 3], "ext": "jpg", "kind": "xyz",
                                "name": tmp_path.name, "attribution": ""}
    assert b.tile(3, 4, 2, None) == (JPG + b"\x03", "image/jpeg")
    assert b.tile(3, 4, 2, "jpg") == (JPG + b"\x03", "image/jpeg")
    for z, x, y, ext in ((3, 4, 1, None), (3, 4, 2, "png"), (3, 4, 2, "exe"), (3, 8, 2, None),
                         (31, 0, 0, None), (-1, 0, 0, None)):
        assert b.tile(z, x, y, ext) is None, (z, x, y, ext)


def test_an_mbtiles_file_is_read_in_tms_order(tmp_path):
    path = tmp_path / "area.mbtiles"
    # z 1: x 0 with y 0 (north) and y 1 (south) differ, so a missed flip shows.
    mbtiles(path, {(1, 0, 0): PNG + b"north", (1, 0, 1): PNG + b"south",
                   (2, 3, 1): PNG + b"z2"}, name="Test area", attribution="(c) us")
    b = open_basemap(path)
    try:
        assert isinstance(b, MBTiles)
        assert b.info.as_json() == {"zooms": [1, 2], "ext": "png", "kind": "mbtiles",
                                    "name": "Test area", "attribution": "(c) us"}
        assert b.tile(1, 0, 0, "png") == (PNG + b"north", "image/png")
        assert b.tile(1, 0, 1, None) == (PNG + b"south", "image/png")
        assert b.tile(2, 3, 1, None) == (PNG + b"z2", "image/png")
        for z, x, y, ext in ((1, 1, 0, None), (1, 0, 2, None), (1, 0, 0, "jpg"),
                             (40, 0, 0, None), (5, 0, 0, None)):
            assert b.tile(z, x, y, ext) is None, (z, x, y, ext)
    finally:
        b.close()
    # No format in the metadata: told by the tiles' magic bytes.
    mbtiles(tmp_path / "jpeg.mbtiles", {(0, 0, 0): JPG}, fmt=None)
    j = open_basemap(tmp_path / "jpeg.mbtiles")
    assert j.info.ext == "jpg" and j.tile(0, 0, 0, "jpeg") == (JPG, "image/jpeg")
    j.close()


def test_bad_basemaps_are_refused_saying_what_is_wrong(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "text.mbtiles").write_text("not a database")
    sqlite3.connect(tmp_path / "other.sqlite").execute("CREATE TABLE t (a)").connection.close()
    mbtiles(tmp_path / "vector.mbtiles", {(0, 0, 0): b"\x1a\x02pbf"}, fmt="pbf")
    mbtiles(tmp_path / "none.mbtiles", {})
    for name, why in (("missing", "no such file or folder"), ("empty", "no tiles in this folder"),
                      ("text.mbtiles", "neither a folder of XYZ tiles nor an MBTiles file"),
                      ("other.sqlite", "without the MBTiles 'tiles' table"),
                      ("vector.mbtiles", "format 'pbf'; the map draws raster tiles only"),
                      ("none.mbtiles", "holds no tiles")):
        with pytest.raises(ConfigError, match=why) as e:
            open_basemap(tmp_path / name)
        assert str(tmp_path / name) in str(e.value)


def test_the_web_map_answers_tiles_and_404_outside_the_set(tmp_path):
    path = tmp_path / "area.mbtiles"
    mbtiles(path, {(1, 0, 0): PNG})
    basemap = open_basemap(path)

    async def run() -> list[tuple[int, bytes, str]]:
        import aiohttp

        web = WebMap("127.0.0.1", 0, lambda: {"version": 1}, lambda: 1,
                     WebAccess(TOKEN, served_names("127.0.0.1", "h")), basemap)
        await web.start()
        out = []
        try:
            async with aiohttp.ClientSession(
                    headers={"Authorization": f"Bearer {TOKEN}"}) as http:
                for tail in ("1/0/0.png", "1/0/0", "1/0/1.png", "1/0/0.jpg", "99/0/0.png",
                             "1/0/99999999999999999999.png", "1/x/0.png", "1/0/٣.png",
                             "1/0/0.png.png"):
                    async with http.get(f"http://127.0.0.1:{web.port}/basemap/{tail}") as r:
                        out.append((r.status, await r.read(), r.content_type))
        finally:
            await web.stop()
        return out

    got = asyncio.run(run())
    basemap.close()
    assert got[0] == got[1] == (200, PNG, "image/png")
    assert [s for s, _, _ in got[2:]] == [404] * 7


def test_a_tile_too_large_is_refused_before_it_is_read(tmp_path, monkeypatch):
    import pdcov.ground.basemap as bm
    monkeypatch.setattr(bm, "MAX_TILE_BYTES", len(PNG) + 99)
    big = PNG + b"x" * 100
    (tmp_path / "xyz" / "1" / "0").mkdir(parents=True)
    (tmp_path / "xyz" / "1" / "0" / "0.png").write_bytes(big)
    (tmp_path / "xyz" / "1" / "0" / "1.png").write_bytes(PNG)
    mbtiles(tmp_path / "a.mbtiles", {(1, 0, 0): big, (1, 0, 1): PNG})
    for basemap in (open_basemap(tmp_path / "xyz"), open_basemap(tmp_path / "a.mbtiles")):
        assert basemap.tile(1, 0, 1, None) == (PNG, "image/png")
        with pytest.raises(bm.TileRefused, match=rf"basemap tile 1/0/0: {len(big)} bytes, "
                                                 rf"more than {len(big) - 1}") as exc:
            basemap.tile(1, 0, 0, None)
        assert exc.value.http_status == 413
        basemap.close()


def test_a_slow_tile_read_times_out_off_the_event_loop(tmp_path):
    import threading

    import pdcov.ground.basemap as bm
    mbtiles(tmp_path / "a.mbtiles", {(1, 0, 0): PNG})
    basemap = open_basemap(tmp_path / "a.mbtiles")
    release = threading.Event()
    interrupted = []
    basemap.tile = lambda *a: release.wait(10) and None  # a hostile file: a read that hangs
    basemap.interrupt = lambda: (interrupted.append(True), release.set())

    async def run() -> int:
        ticks = 0

        async def other_requests() -> None:  # the loop keeps answering meanwhile
            nonlocal ticks
            while not release.is_set():
                ticks += 1
                await asyncio.sleep(0.01)

        other = asyncio.create_task(other_requests())
        with pytest.raises(bm.TileRefused, match=r"basemap tile 1/0/0: not read within "
                                                 r"0.2 s") as exc:
            await bm.read_tile(basemap, 1, 0, 0, None, timeout_s=0.2)
        await other
        assert exc.value.http_status == 504
        return ticks

    assert asyncio.run(run()) >= 5 and interrupted == [True]
    basemap.close()
