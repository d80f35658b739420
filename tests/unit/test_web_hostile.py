"""The web map under hostile input and many clients (issue 23): nothing non-finite reaches
the page's data, the state is built once per change for every client, the page shows an
update it cannot read instead of freezing, and a rogue Zenoh session's poison statuses
stop neither `pdcov watch` nor its map (real router, real watch process, real HTTP)."""

from __future__ import annotations

import asyncio
import json
import math

import pytest

from pdcov.ground.web import WebMap, state_json
from pdcov.ground.web_auth import WebAccess, served_names

TOKEN = "hostile-test-token-0123456789abcdef"
ACCESS = WebAccess(TOKEN, served_names("127.0.0.1", "groundstation", []))
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def strict(text: str | bytes):
    """json.loads that refuses NaN and the infinities, as the browser's JSON.parse does."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_state_json_makes_non_finite_numbers_null():
    state = {"version": 3, "fleet": {"mean_pd": math.inf, "proportion": {"0.8": math.nan}},
             "vehicles": [{"age_s": -math.inf, "track": [[1.0, math.nan]]}]}
    doc = strict(state_json(state))
    assert doc["fleet"] == {"mean_pd": None, "proportion": {"0.8": None}}
    assert doc["vehicles"] == [{"age_s": None, "track": [[1.0, None]]}]
    with pytest.raises(ValueError, match="Infinity"):
        strict(json.dumps(state))  # what the page used to receive


async def _first_event(resp) -> dict:
    buf = b""
    while not buf.endswith(b"\n\n"):
        buf += await resp.content.readany()
    (line,) = [ln for ln in buf.split(b"\n") if ln.startswith(b"data: ")][-1:]
    return strict(line[6:])


async def _serve(state, version, **kw) -> WebMap:
    web = WebMap("127.0.0.1", 0, state, version, ACCESS, None, **kw)
    await web.start()
    return web


def test_non_finite_state_reaches_both_endpoints_as_strict_json():
    async def run():
        import aiohttp

        web = await _serve(lambda: {"version": 1, "mean_pd": math.inf}, lambda: 1,
                           period_s=0.02)
        try:
            async with aiohttp.ClientSession(headers=AUTH) as http:
                base = f"http://127.0.0.1:{web.port}"
                async with http.get(f"{base}/state.json") as r:
                    assert r.status == 200 and r.content_type == "application/json"
                    assert strict(await r.read())["mean_pd"] is None
                async with http.get(f"{base}/events") as r:
                    assert (await _first_event(r))["mean_pd"] is None
        finally:
            await web.stop()
    asyncio.run(run())


def test_the_state_is_built_once_per_version_for_every_client():
    """N live-event clients and M /state.json readers: one build per version change, not
    one per client (the red team's 200 clients pinned a core)."""
    n_clients, n_changes = 40, 5
    version = [0]
    builds = []

    def state():
        builds.append(version[0])
        return {"version": version[0]}

    async def run():
        import aiohttp

        web = await _serve(state, lambda: version[0], period_s=0.02, refresh_s=3600.0)
        base = f"http://127.0.0.1:{web.port}"
        try:
            async with aiohttp.ClientSession(headers=AUTH) as http:
                streams = [await http.get(f"{base}/events") for _ in range(n_clients)]
                for r in streams:
                    assert (await _first_event(r))["version"] == 0
                for v in range(1, n_changes + 1):
                    version[0] = v
                    got = await asyncio.wait_for(
                        asyncio.gather(*(_first_event(r) for r in streams)), 10)
                    assert [g["version"] for g in got] == [v] * n_clients
                    for _ in range(10):
                        async with http.get(f"{base}/state.json") as r:
                            assert strict(await r.read())["version"] == v
                for r in streams:
                    r.close()
        finally:
            await web.stop()
    asyncio.run(run())
    assert builds == list(range(n_changes + 1)), builds


def test_a_state_that_cannot_be_built_keeps_the_map_and_says_so(caplog):
    """A defect in building one update must not end the stream or answer 500: the page
    keeps the last state, with the error to show (app.js), and the next version is built
    again."""
    version = [0]

    def state():
        if version[0] == 1:
            raise KeyError("fleet")
        return {"version": version[0], "fleet": {"target": 0.8}}

    async def run():
        import aiohttp

        web = await _serve(state, lambda: version[0], period_s=0.02, refresh_s=3600.0)
        base = f"http://127.0.0.1:{web.port}"
        try:
            async with aiohttp.ClientSession(headers=AUTH) as http:
                stream = await http.get(f"{base}/events")
                assert (await _first_event(stream))["version"] == 0
                version[0] = 1
                bad = await asyncio.wait_for(_first_event(stream), 10)
                assert bad["version"] == 1 and bad["fleet"] == {"target": 0.8}
                assert bad["build_error"] == "KeyError: 'fleet'"
                async with http.get(f"{base}/state.json") as r:
                    assert r.status == 200 and strict(await r.read())["build_error"]
                version[0] = 2
                good = await asyncio.wait_for(_first_event(stream), 10)
                assert good == {"version": 2, "fleet": {"target": 0.8}}
                stream.close()
        finally:
            await web.stop()
    asyncio.run(run())
    assert sum("could not be built" in r.getMessage() for r in caplog.records) == 1


def test_the_state_is_rebuilt_after_refresh_s_for_the_ages():
    builds = []

    async def run():
        web = await _serve(lambda: builds.append(1) or {"n": len(builds)}, lambda: 7,
                           refresh_s=0.05)
        try:
            first = web.current()
            assert web.current() is first and len(builds) == 1
            await asyncio.sleep(0.06)
            assert strict(web.current().data) == {"n": 2}
        finally:
            await web.stop()
    asyncio.run(run())


# -- end to end: a rogue session on the default bus -----------------------------------
