"""`pdcov watch --web` as a process: the tokened URL printed once, an open token file and bad
token options refused."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from pdcov.ground.demo import Children
from pdcov.ground.web_auth import TOKEN_ENV
from tests.support.web_requests import TOKEN, get


def watch(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "pdcov.cli", "watch", "--no-multicast-scouting", "--plain",
         *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, **(env or {})}, start_new_session=True)


def stop(p: subprocess.Popen[str]) -> str:
    """SIGTERM (its group SIGKILLed after 30 s); returns the rest of its output."""
    Children.terminate(p, 30.0)
    rest = p.stdout.read() + p.stderr.read()
    p.stdout.close()
    p.stderr.close()
    return rest


@pytest.mark.parametrize("given", ["new", "env", "file"])
def test_watch_prints_the_tokened_url_once(tmp_path, given):
    env, extra = {}, []
    if given == "env":
        env[TOKEN_ENV] = TOKEN
    elif given == "file":
        f = tmp_path / "token"
        f.write_text(TOKEN)
        f.chmod(0o600)
        extra = ["--web-token-file", str(f)]
        env[TOKEN_ENV] = "not-this-one-0123456789"  # the file wins
    p = watch("--web", "127.0.0.1:0", *extra, env=env)
    rest = ""
    try:
        line = p.stdout.readline()
        m = re.search(r"web map at http://127\.0\.0\.1:(\d+)/\?token=([A-Za-z0-9_.~-]+)$",
                      line.strip())
        assert m, line
        port, token = int(m.group(1)), m.group(2)
        assert token == TOKEN if given != "new" else len(token) == 43
        assert get(port, "/state.json")[0] == 401
        status, _, cookies, _ = get(port, f"/?token={token}")
        assert status == 200 and cookies
        assert get(port, "/state.json", {"Authorization": f"Bearer {token}"})[0] == 200
        cmdline = Path(f"/proc/{p.pid}/cmdline").read_bytes()
        assert token.encode() not in cmdline  # other users' ps never shows it
    finally:
        rest = stop(p)
    assert p.returncode == 0
    assert token not in rest  # printed once, in the first line only


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604], ids=lambda m: f"{m:04o}")
def test_watch_refuses_an_open_token_file(tmp_path, mode):
    f = tmp_path / "token"
    f.write_text(TOKEN)
    f.chmod(mode)
    p = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--web", "127.0.0.1:0",
                        "--web-token-file", str(f)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2
    assert p.stderr.strip() == (f"pdcov watch: error: --web-token-file {f}: permissions "
                                f"0{mode:o} are too open: group and others must have no "
                                f"access to it (chmod 600 {f})")
    assert p.stdout == "" and TOKEN not in p.stderr


def test_watch_refuses_a_bad_token_or_options_without_web(tmp_path):
    for args, env, message in (
            (["--web", "127.0.0.1:0"], {TOKEN_ENV: "short"}, "PDCOV_WEB_TOKEN: expected a "
             "token of at least 16"),
            (["--web-token-file", str(tmp_path / "t")], {}, "go with --web HOST:PORT"),
            (["--web-allow-host", "x.example"], {}, "go with --web HOST:PORT"),
            (["--basemap", str(tmp_path)], {}, "go with --web HOST:PORT"),
            (["--web", "127.0.0.1:0", "--basemap", str(tmp_path / "none.mbtiles")], {},
             f"--basemap {tmp_path / 'none.mbtiles'}: no such file or folder"),
            (["--web", "127.0.0.1:0", "--plan", str(tmp_path / "none.plan")], {},
             "none.plan")):
        p = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", *args],
                           capture_output=True, text=True, timeout=60,
                           env={**os.environ, **env})
        assert p.returncode == 2 and message in p.stderr, p.stderr
        assert "Traceback" not in p.stderr
