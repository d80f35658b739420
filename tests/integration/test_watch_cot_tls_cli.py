"""`pdcov watch --cot tls://` refuses a bad client identity before the watcher starts: one
line naming the option and the file, exit status 2 (tests/unit/test_cot_tls.py has every
refusal's wording)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.support.tls_certs import Authority

pytest.importorskip("pytak")


@pytest.mark.parametrize("case", ["expired", "wrong key", "not tls"])
def test_a_bad_identity_is_one_line_and_status_2(tmp_path, case):
    ca = Authority(tmp_path / "tak")
    good, old = ca.leaf("pdcov-ground"), ca.leaf("old", expired=True)
    url, cert, key, expect = {
        "expired": ("tls://127.0.0.1:8089", old.cert, old.key,
                    f"--cot-cert {old.cert}: CN=old expired on "),
        "wrong key": ("tls://127.0.0.1:8089", good.cert, old.key,
                      f"--cot-key {old.key}: not the key of --cot-cert {good.cert}"),
        "not tls": ("tcp://127.0.0.1:8087", good.cert, good.key,
                    "--cot-cert, --cot-key, --cot-ca: only with --cot tls://HOST:PORT"),
    }[case]
    p = subprocess.run(
        [sys.executable, "-m", "pdcov.cli", "watch", "--mode", "client", "--zenoh-connect",
         "tcp/127.0.0.1:1", "--no-multicast-scouting", "--plain", "--cot", url,
         "--cot-cert", str(cert), "--cot-key", str(key), "--cot-ca", str(ca.ca)],
        capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, p
    assert p.stdout == "" and p.stderr.count("\n") == 1, p.stderr
    assert p.stderr.startswith(f"pdcov watch: error: {expect}"), p.stderr
