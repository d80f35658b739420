"""Who may read the web map (ground/web_auth.py): the decision by hand-checkable cases, the
token file's checks, and the real aiohttp server on 127.0.0.1 (a free port) answering the
page, its assets, the state, the event stream and the basemap with no token, a wrong one
and the right one (query, cookie, bearer); then `pdcov watch --web` as a process."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from http.cookies import SimpleCookie

import pytest

from pdcov.errors import ConfigError
from pdcov.ground.basemap import open_basemap
from pdcov.ground.web import SECURITY_HEADERS
from pdcov.ground.web_auth import (
    TOKEN_ENV,
    Granted,
    Refusal,
    WebAccess,
    check_token,
    host_allowed,
    read_token_file,
    served_names,
    web_access,
)
from tests.support.watch_fixtures import ThreadedWebMap
from tests.support.web_requests import TOKEN, get

NAMES = served_names("127.0.0.1", "groundstation", ["proxy.example.org"])
ACCESS = WebAccess(TOKEN, NAMES)
PATHS = ("/", "/app.js", "/style.css", "/state.json", "/events", "/basemap/3/4/2.png")
UNKNOWN = ("/nothing-here", "/basemap/3/4/9.png", "/events/")


# --- the decision ------------------------------------------------------------------------

def test_no_token_wrong_token_right_token():
    none = ACCESS.check("127.0.0.1:8080", None, None, None)
    assert isinstance(none, Refusal) and none.status == 401
    assert "needs its access token" in none.text and "?token=" in none.text
    for wrong in ("", "x", TOKEN[:-1], TOKEN + "x", TOKEN.upper(), "ünïcødé\udc80"):
        for verdict in (ACCESS.check("127.0.0.1", wrong, None, None),
                        ACCESS.check("127.0.0.1", None, wrong, None),
                        ACCESS.check("127.0.0.1", None, None, f"Bearer {wrong}")):
            assert isinstance(verdict, Refusal) and verdict.status == 401, wrong
            assert "wrong or expired" in verdict.text
    assert ACCESS.check("127.0.0.1", TOKEN, None, None) == Granted(set_cookie=True)
    assert ACCESS.check("127.0.0.1", None, TOKEN, None) == Granted(set_cookie=False)
    assert ACCESS.check("127.0.0.1", "old-bookmark", TOKEN, None) == Granted(set_cookie=False)
    assert ACCESS.check("127.0.0.1", None, None, f"bearer {TOKEN}") == Granted(False)
    assert isinstance(ACCESS.check("127.0.0.1", None, None, f"Basic {TOKEN}"), Refusal)


def test_host_header_against_the_served_names():
    for host in ("127.0.0.1:8080", "192.168.10.5", "[::1]:8080", "[fe80::1]", "localhost:80",
                 "LOCALHOST", "groundstation:8080", "groundstation.local", "proxy.example.org",
                 "localhost.", None):
        assert host_allowed(host, NAMES), host
    for host in ("evil.example:8080", "127.0.0.1.nip.io", "groundstation.evil.example",
                 "localhost.evil", "", "[::1"):
        assert not host_allowed(host, NAMES), host
        refused = ACCESS.check(host, TOKEN, TOKEN, None)  # the token does not help
        assert isinstance(refused, Refusal) and refused.status == 403
        assert "--web-allow-host" in refused.text
    assert "my.lan" in served_names("My.Lan.", "h")


def test_tokens_too_short_or_with_other_characters_are_refused():
    assert check_token("a" * 16, "x") == "a" * 16
    for bad in ("", "a" * 15, "a" * 20 + " b", "a" * 20 + ";", "a" * 20 + "é"):
        with pytest.raises(ConfigError, match="at least 16 characters"):
            check_token(bad, "PDCOV_WEB_TOKEN")
    with pytest.raises(ConfigError):
        WebAccess("short", NAMES)


def test_token_from_file_environment_or_new(tmp_path):
    f = tmp_path / "token"
    f.write_text(TOKEN + "\n")
    f.chmod(0o600)
    assert read_token_file(f) == TOKEN
    assert web_access("0.0.0.0", f, [], {TOKEN_ENV: "e" * 20}, "h").token == TOKEN
    assert web_access("0.0.0.0", None, [], {TOKEN_ENV: " " + "e" * 20}, "h").token == "e" * 20
    a, b = (web_access("0.0.0.0", None, [], {}, "h") for _ in range(2))
    assert a.token != b.token and len(a.token) == 43  # 32 random bytes, base64url
    for mode in (0o640, 0o604, 0o620, 0o602, 0o660, 0o644):
        f.chmod(mode)
        with pytest.raises(ConfigError, match=rf"permissions 0{mode:o} are too open.*chmod 600"):
            read_token_file(f)
    f.chmod(0o400)
    assert read_token_file(f) == TOKEN
    with pytest.raises(ConfigError, match="cannot read it"):
        read_token_file(tmp_path / "missing")
    with pytest.raises(ConfigError, match="not a regular file"):
        read_token_file(tmp_path)


# --- the real server ---------------------------------------------------------------------

@pytest.fixture
def server(tmp_path):
    (tmp_path / "tiles" / "3" / "4").mkdir(parents=True)
    (tmp_path / "tiles" / "3" / "4" / "2.png").write_bytes(b"\x89PNG tile")
    s = ThreadedWebMap(lambda: {"version": 7, "vehicles": [], "grid": None}, ACCESS,
                       open_basemap(tmp_path / "tiles"))
    try:
        yield s
    finally:
        s.close()


def test_every_path_needs_the_token(server):
    port = server.web.port
    for path in UNKNOWN:  # nothing is learnt by probing: the same 401 without the token
        assert get(port, path)[0] == 401
        assert get(port, path, {"Authorization": f"Bearer {TOKEN}"})[0] == 404
    for path in PATHS:
        for query, headers, why in (
                ("", {}, "needs its access token"),
                ("?token=wrong-token-0123456789", {}, "wrong or expired"),
                ("", {"Cookie": f"pdcov_watch_token_{port}=wrong-token-0123456789"},
                 "wrong or expired"),
                ("", {"Cookie": f"pdcov_watch_token_{port + 1}={TOKEN}"},  # another map's
                 "needs its access token"),
                ("", {"Authorization": "Bearer nope-nope-nope-nope"}, "wrong or expired")):
            status, h, cookies, body = get(port, path + query, headers)
            assert status == 401, (path, query, headers)
            assert h["Content-Type"].startswith("text/plain")
            assert why in body.decode() and len(body) < 300
            assert h["WWW-Authenticate"] == 'Bearer realm="pdcov watch"'
            assert cookies == [] and TOKEN not in body.decode()


def test_the_right_token_by_query_cookie_or_bearer(server):
    port = server.web.port
    cookie = {"Cookie": f"pdcov_watch_token_{port}={TOKEN}"}
    for path in PATHS:
        sep = "&" if "?" in path else "?"
        for query, headers in ((f"{sep}token={TOKEN}", {}), ("", cookie),
                               ("", {"Authorization": f"Bearer {TOKEN}"})):
            status, h, _, body = get(port, path + query, headers)
            assert status == 200, (path, query, headers, body)
            for name, value in SECURITY_HEADERS.items():
                assert h[name] == value, (path, name)
            if path == "/":
                assert b"<div id=\"map\"" in body
            elif path == "/state.json":
                assert json.loads(body) == server.state()
            elif path == "/events":
                assert body.startswith(b"data: ") and json.loads(body[6:]) == server.state()
            elif path.startswith("/basemap"):
                assert body == b"\x89PNG tile"


def test_the_tokened_page_sets_a_strict_httponly_cookie_once(server):
    port = server.web.port
    assert server.web.url == f"http://127.0.0.1:{port}/?token={TOKEN}"
    status, _, cookies, _ = get(port, f"/?token={TOKEN}")
    assert status == 200 and len(cookies) == 1
    jar = SimpleCookie(cookies[0])
    morsel = jar[f"pdcov_watch_token_{port}"]
    assert morsel.value == TOKEN
    assert morsel["httponly"] is True and morsel["samesite"] == "Strict"
    assert morsel["path"] == "/"
    assert not morsel["max-age"] and not morsel["expires"]  # gone with the browser session
    # The cookie alone is then enough, and not set again.
    status, _, again, _ = get(port, "/", {"Cookie": f"{morsel.key}={morsel.value}"})
    assert status == 200 and again == []


def test_a_foreign_host_is_refused_even_with_the_token(server):
    port = server.web.port
    for path in PATHS:
        status, h, cookies, body = get(port, f"{path}?token={TOKEN}",
                                       {"Host": f"rebound.evil.example:{port}"})
        assert status == 403 and h["Content-Type"].startswith("text/plain")
        assert b"rebound.evil.example" in body and b"--web-allow-host" in body
        assert cookies == []
    assert get(port, f"/?token={TOKEN}", {"Host": "proxy.example.org"})[0] == 200
    assert get(port, f"/?token={TOKEN}", {"Host": f"localhost:{port}"})[0] == 200


# --- pdcov watch --web -------------------------------------------------------------------

def watch(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "pdcov.cli", "watch", "--no-multicast-scouting", "--plain",
         *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, **(env or {})}, start_new_session=True)
