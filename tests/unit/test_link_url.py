"""MAVLink link URLs (telemetry/link_url.py): a malformed one is refused in one line naming
it and the forms taken, before anything is opened; a refused TCP link prints nothing of
pymavlink's ("Connection refused sleeping"), in the daemon and in the ground tools."""

from __future__ import annotations

import pytest
import yaml

from pdcov.cli import main as pdcov_main
from pdcov.errors import ConfigError
from pdcov.service.mavlink_socket import open_connection
from pdcov.telemetry.link_url import (
    TOOL_SCHEMES,
    check_link_url,
    link_url_problem,
    pymavlink_device,
)
from pdcov.telemetry.upload import UploadError, mavlink2_connection
from tests.support.cmac_mission import CMAC
from tests.support.harness import free_port

GOOD = ["udpin:0.0.0.0:14550", "udp:127.0.0.1:14550", "udpin:127.0.0.1:0",
        "udpout:192.168.1.5:14550", "tcp:localhost:5760", "/dev/ttyAMA0",
        "/dev/ttyAMA0,921600", "serial:/dev/ttyAMA0:921600", "serial:/dev/ttyUSB0",
        "/dev/serial/by-id/usb-ArduPilot_fmuv3-if00,115200"]


@pytest.mark.parametrize("url", GOOD)
def test_the_documented_forms_are_taken(url: str) -> None:
    assert link_url_problem(url) is None
    assert check_link_url(url, "--connect") == url


@pytest.mark.parametrize(("url", "says"), [
    ("udpin:nonsense", "expected udpin:HOST:PORT with a port in 0..65535"),
    ("tcp:127.0.0.1", "expected tcp:HOST:PORT with a port in 1..65535"),
    ("udpout:127.0.0.1:0", "expected udpout:HOST:PORT with a port in 1..65535"),
    ("tcp:127.0.0.1:99999", "expected tcp:HOST:PORT"),
    ("tcp:[::1]:5760", "expected tcp:HOST:PORT"),
    ("serial:ttyAMA0:921600", "expected serial:/dev/DEVICE:BAUD"),
    ("foo", "unknown connection 'foo': expected one of udpin:HOST:PORT"),
    ("tpc:127.0.0.1:5760", "unknown connection 'tpc:127.0.0.1:5760'"),
    ("/dev/ttyAMA0,fast", "unknown connection"),
    ("tcpin:0.0.0.0:5760", "unknown connection"),  # the daemon reads its sockets itself
    ("", "unknown connection"),
])
def test_a_malformed_url_is_refused_naming_it(url: str, says: str) -> None:
    with pytest.raises(ConfigError) as exc:
        check_link_url(url, "--connect")
    text = str(exc.value)
    assert text.startswith("--connect: ") and says in text and repr(url) in text
    assert "\n" not in text


def test_the_ground_tools_also_take_tcpin_and_udpbcast() -> None:
    assert link_url_problem("tcpin:0.0.0.0:5760", TOOL_SCHEMES) is None
    assert link_url_problem("udpbcast:192.168.1.255:14550", TOOL_SCHEMES) is None
    assert "tcpin:HOST:PORT" in (link_url_problem("x", TOOL_SCHEMES) or "")


def test_what_pymavlink_opens() -> None:
    assert pymavlink_device("serial:/dev/ttyAMA0:921600") == ("/dev/ttyAMA0", 921600)
    assert pymavlink_device("/dev/ttyAMA0,57600") == ("/dev/ttyAMA0", 57600)
    assert pymavlink_device("udpin:0.0.0.0:14550") == ("udpin:0.0.0.0:14550", None)


def test_serve_refuses_a_malformed_url_before_starting(tmp_path, capsys) -> None:
    state = tmp_path / "state"
    cfg = tmp_path / "m.yaml"
    cfg.write_text(yaml.safe_dump({**CMAC, "service": {"state_dir": str(state)}}))
    assert pdcov_main(["serve", "--config", str(cfg), "--connect", "udpin:nonsense"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--connect: expected udpin:HOST:PORT" in err
    assert not state.exists()  # refused before anything was made
    cfg.write_text(yaml.safe_dump({**CMAC, "link": {"connect": ["tcp:localhost"]}}))
    assert pdcov_main(["serve", "--config", str(cfg), "--check"]) == 2
    assert "link.connect: expected tcp:HOST:PORT" in capsys.readouterr().err


def test_a_refused_tcp_link_prints_nothing_of_pymavlink(capfd) -> None:
    url = f"tcp:127.0.0.1:{free_port()}"  # nobody listens there
    with pytest.raises(ConnectionRefusedError):
        open_connection(url, 1, 191, None)
    with pytest.raises(UploadError, match="Connection refused"):
        mavlink2_connection(url, 255, 190)
    assert capfd.readouterr() == ("", "")
