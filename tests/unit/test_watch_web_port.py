"""`pdcov watch --web HOST:PORT` where it cannot listen: one line naming the address and
what to do, exit 2, no traceback (a real socket holds the port on 127.0.0.1)."""

from __future__ import annotations

import errno
import socket

import pytest

from pdcov.cli import main as pdcov_main
from pdcov.ground.app import web_bind_refusal


def test_a_port_in_use_is_one_line_naming_it(capsys) -> None:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        assert pdcov_main(["watch", "--web", f"127.0.0.1:{port}", "--plain",
                           "--no-multicast-scouting"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"pdcov watch: error: --web 127.0.0.1:{port}: the address is in "
                          "use")
    assert f"`ss -ltnp 'sport = :{port}'`" in err
    assert "give another port, or 127.0.0.1:0 for a free one" in err


@pytest.mark.parametrize(("exc", "says"), [
    (OSError(errno.EACCES, "Permission denied"), "may not listen on port 80"),
    (OSError(errno.EADDRNOTAVAIL, "Cannot assign"), "10.9.9.9 is not an address of this"),
    (socket.gaierror(-2, "Name or service not known"), "is not a name this machine resolves"),
    (OSError(errno.EMFILE, "Too many open files"), "cannot listen there (Too many open"),
])
def test_other_bind_errors_say_what_to_do(exc: OSError, says: str) -> None:
    host = "10.9.9.9" if exc.errno == errno.EADDRNOTAVAIL else "127.0.0.1"
    line = web_bind_refusal((host, 80), exc)
    assert line.startswith(f"--web {host}:80: ") and says in line and "\n" not in line
    assert web_bind_refusal(("::1", 80), exc).startswith("--web [::1]:80: ")
