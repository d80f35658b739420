"""What the daemon asks of its link and how its links' states read as one, with no I/O.

``link_requests``: the message intervals and mount parameters ``LinkProtocol`` asks the
autopilot for, from the mission; ``link_state``: the links' states as the status's one;
``LinkReport``: what the shell's links and files say, for the status.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pdcov.core.mount import GimbalMount
from pdcov.telemetry.gimbal import mount_params_complete, mount_params_to_read
from pdcov.telemetry.link_protocol import (
    ATTITUDE,
    GIMBAL_DEVICE_ATTITUDE_STATUS,
    GLOBAL_POSITION_INT,
    GPS_RAW_INT,
    HOME_POSITION,
    SYSTEM_TIME,
    ZOOM_MESSAGES,
    LinkState,
)

if TYPE_CHECKING:  # a value handed in: the decisions never load a config
    from pdcov.service.settings import ServeConfig

__all__ = ["GNSS_ACCURACY_HZ", "HOME_POSITION_HZ", "SYSTEM_TIME_HZ", "ZOOM_REPORT_HZ",
           "LinkReport", "link_requests", "link_state"]

HOME_POSITION_HZ = 0.2
GNSS_ACCURACY_HZ = 2.0
"""The rate GPS_RAW_INT (the GNSS accuracy the boxes are geolocated with, telemetry/
gnss_accuracy.py) is asked for: a few reports within each GNSS_ACCURACY_HOLD_S."""
SYSTEM_TIME_HZ = 1.0
"""The rate SYSTEM_TIME (the autopilot's UTC beside its boot clock: the detections'
time_utc, core/utc_clock.py) is asked for."""
ZOOM_REPORT_HZ = 5.0
"""The rate the zoom report camera.zoom follows is asked for, of the autopilot (ArduPilot
sends its cameras' messages when asked; a MAVLink camera component streams its own)."""

@dataclass(frozen=True, slots=True)
class LinkReport:
    """What the shell's links and files say, for the status (I/O facts the core cannot
    see): each link's ``describe()`` and state, their URLs, losses, datagrams the kernel
    dropped, chunks pymavlink failed to parse, the recording's error."""

    links: tuple[dict[str, Any], ...] = ()
    states: tuple[LinkState, ...] = ()
    url: str = ""
    losses: int = 0
    kernel_drops: int = 0
    parse_errors: int = 0
    recording_error: str | None = None


def link_requests(cfg: ServeConfig) -> tuple[dict[int, float], tuple[str, ...],
                                             Callable[[Mapping[str, float]], bool] | None]:
    """(message intervals to ask for {message id: Hz}, mount parameters to read, when they
    are complete): the streams a frame needs, HOME_POSITION, GPS_RAW_INT, SYSTEM_TIME, the
    zoom reports the cameras' camera.zoom follow (ZOOM_MESSAGES), and for gimbals their
    reports and the one list of mount parameters of each gimbal device
    (gimbal.mount_params_to_read, as mount-check)."""
    link, cams = cfg.link, cfg.mission.cameras
    intervals = {ATTITUDE: link.attitude_hz, GLOBAL_POSITION_INT: link.position_hz,
                 HOME_POSITION: HOME_POSITION_HZ, GPS_RAW_INT: GNSS_ACCURACY_HZ,
                 SYSTEM_TIME: SYSTEM_TIME_HZ}
    for cam in cams:
        if cam.zoom is not None:
            intervals[ZOOM_MESSAGES[cam.zoom.lens.quantity]] = ZOOM_REPORT_HZ
    instances = sorted({c.mount.instance for c in cams if isinstance(c.mount, GimbalMount)})
    if not instances:
        return intervals, (), None
    intervals[GIMBAL_DEVICE_ATTITUDE_STATUS] = link.gimbal_hz
    names: list[str] = []
    for instance in instances:
        current, legacy = mount_params_to_read(instance)
        names += [*current, *legacy]
    return (intervals, tuple(dict.fromkeys(names)),
            lambda values: all(mount_params_complete(values, i) for i in instances))


def link_state(states: Iterable[LinkState], autopilot_known: bool) -> LinkState:
    """The links' state as one: connected once a link is and the autopilot is known;
    waiting while a link is open (or silent) without it; else the first link's."""
    states = list(states)
    if LinkState.CONNECTED in states and autopilot_known:
        return LinkState.CONNECTED
    if LinkState.CONNECTED in states or LinkState.WAITING in states:
        return LinkState.WAITING
    return states[0] if states else LinkState.NONE
