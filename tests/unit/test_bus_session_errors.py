"""A Zenoh endpoint or session that is wrong reaches the user as one line of pdcov's: what it
was doing, the endpoint, what to do; never Zenoh's own text with its Rust source paths.
(The session really failing to open: tests/system/test_watch_zenoh.py.)"""

from __future__ import annotations

import pytest

from pdcov.bus.session import (
    BusConfig,
    check_endpoint,
    open_refusal,
    zenoh_config,
    zenoh_text,
)
from pdcov.cli import main as pdcov_main
from pdcov.errors import ConfigError

SRC = " at /root/.cargo/git/checkouts/zenoh-9c599d5ef3e0480e/cc83980/zenoh/src/net/runtime"


@pytest.mark.parametrize(("endpoint", "listen"), [
    ("tcp/192.168.1.10:7447", False), ("tls/[::1]:7447", False), ("quic/router:7447", False),
    ("tcp/0.0.0.0:0", True), ("tcp/10.0.0.2:7447?prio=1#iface=eth0", False),
    ("unixsock-stream//tmp/zenoh.sock", True), ("serial//dev/ttyUSB0#baudrate=115200", False),
])
def test_zenoh_endpoints_of_every_form_are_taken(endpoint: str, listen: bool) -> None:
    check_endpoint(endpoint, "bus.connect", listen=listen)


@pytest.mark.parametrize(("endpoint", "says"), [
    ("tcp/127.0.0.1", "expected tcp/HOST:PORT with a port in 1..65535"),
    ("tcp/127.0.0.1:0", "expected tcp/HOST:PORT with a port in 1..65535"),
    ("tcp/::1:7447", "(IPv6: tcp/[::1]:7447)"),
    ("xyz/1.2.3.4:7447", "the protocol one of tcp, udp, tls, quic, ws"),
    ("192.168.1.10:7447", "expected PROTOCOL/ADDRESS such as tcp/192.168.1.10:7447"),
])
def test_a_malformed_endpoint_is_refused_before_zenoh_sees_it(endpoint: str, says: str
                                                               ) -> None:
    with pytest.raises(ConfigError, match=r"^bus.connect: endpoint ") as exc:
        BusConfig(connect=(endpoint,))
    assert says in str(exc.value) and repr(endpoint) in str(exc.value)


def test_the_command_line_endpoint_is_named_by_its_option(capsys) -> None:
    assert pdcov_main(["watch", "--zenoh-connect", "tcp/127.0.0.1"]) == 2
    err = capsys.readouterr().err
    assert err == ("pdcov watch: error: --zenoh-connect: endpoint 'tcp/127.0.0.1': expected "
                   "tcp/HOST:PORT with a port in 1..65535 (IPv6: tcp/[::1]:7447)\n")
    with pytest.raises(ConfigError, match="^--zenoh-listen: endpoint 'x'"):
        BusConfig().with_endpoints(None, ("x",))


def test_an_unreachable_router_says_what_to_check() -> None:
    bus = BusConfig(connect=("tls/10.0.0.2:7447",), multicast_scouting=False)
    refused = zenoh_text(RuntimeError(
        f"Unable to connect to any of [Single(tls/10.0.0.2:7447)]! {SRC}/orchestrator.rs:447."))
    line = open_refusal(bus, refused)
    assert line.startswith("bus: cannot open the Zenoh session (client (auto), connect "
                           "[tls/10.0.0.2:7447]")
    assert ("nothing answers at tls/10.0.0.2:7447 (refused or unreachable): check that the "
            "router (zenohd) or the daemon listening there runs") in line
    assert "the certificates (--zenoh-config)" in line and "--zenoh-connect" in line
    timed_out = "Unable to connect to any of [Single(tls/10.0.0.2:7447)]. Timeout!"
    assert "(no answer in time)" in open_refusal(bus, timed_out)


def test_a_listen_endpoint_in_use_says_so() -> None:
    bus = BusConfig(listen=("tcp/127.0.0.1:7447",), multicast_scouting=False)
    text = zenoh_text(RuntimeError(
        "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: [127.0.0.1:7447: "
        f"Address already in use (os error 98){SRC}/tcp.rs:61.]{SRC}/unicast.rs:338."))
    assert ".rs" not in text
    assert open_refusal(bus, text).endswith(
        "cannot listen on tcp/127.0.0.1:7447: Address already in use: give an address of "
        "this machine and a port nothing else holds (--zenoh-listen)")


def test_a_config_zenoh_refuses_names_the_setting_and_zenohs_reason() -> None:
    with pytest.raises(ConfigError) as exc:
        zenoh_config(BusConfig(zenoh={"transport/link/tls/enable_mtls": "yes"}))
    text = str(exc.value)
    assert text.startswith('bus: Zenoh refuses the session config, at bus.zenoh '
                           'transport/link/tls/enable_mtls: "yes": invalid type: string "yes", '
                           'expected a boolean')
    assert ".rs" not in text and "Json5Err" not in text
