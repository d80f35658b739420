"""One vehicle-id rule and one MAVLink system-id range (pdcov/ids.py), the same wherever an
id is read: the mission config, the daemon's link section, the bus's keys and payloads."""

from __future__ import annotations

import json

import pytest

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.frames import decode_frames
from pdcov.bus.keys import VehicleKeys
from pdcov.config.load import mission_from_dict
from pdcov.errors import ConfigError
from pdcov.ids import MAX_VEHICLE_ID_CHARS, SYSTEM_IDS, valid_system_id, valid_vehicle_id
from pdcov.service.settings import LinkConfig
from tests.support.evaluate_inputs import mission_doc

NOT_VEHICLE_IDS = ["", "uav é", "uavé", "ｕａｖ1", "uav/1", "uav*", "uav 1", "uav.1", 7, None]


@pytest.mark.parametrize("vid", ["uav1", "UAV-1_a", "0", "a-b_c-9"])
def test_vehicle_ids_of_ascii_letters_digits_dash_and_underscore_are_accepted(vid):
    assert valid_vehicle_id(vid)
    assert mission_from_dict(mission_doc(vehicle_id=vid)).vehicle_id == vid
    assert VehicleKeys(vid).status == f"pdcov/{vid}/status"


@pytest.mark.parametrize("vid", NOT_VEHICLE_IDS)
def test_a_bad_vehicle_id_is_a_config_error_in_the_config_and_refused_by_the_bus(vid):
    assert not valid_vehicle_id(vid)
    with pytest.raises(ConfigError, match=r"m.yaml: vehicle_id: expected ASCII letters"):
        mission_from_dict(mission_doc(vehicle_id=vid), source="m.yaml")
    with pytest.raises(ValueError, match="expected ASCII letters"):
        VehicleKeys(vid)


def test_system_ids_are_1_to_255_in_the_log_and_link_sections():
    assert (SYSTEM_IDS.start, SYSTEM_IDS.stop) == (1, 256)
    for sid in (1, 254, 255):
        assert valid_system_id(sid)
        assert mission_from_dict(mission_doc(log={"system_id": sid})).system_id == sid
        assert LinkConfig(system_id=sid).system_id == sid
    for sid in (0, 256, -1, True, 1.0, "1"):
        assert not valid_system_id(sid)
        with pytest.raises(ConfigError, match=r"log.system_id: expected a MAVLink system id "
                                              r"1..255"):
            mission_from_dict(mission_doc(log={"system_id": sid}))
        with pytest.raises(ConfigError, match=r"link.system_id: expected 1..255"):
            LinkConfig(system_id=sid)


def test_a_vehicle_id_of_more_than_64_characters_is_refused_by_config_and_bus():
    assert valid_vehicle_id("u" * MAX_VEHICLE_ID_CHARS)
    long_id = "u" * (MAX_VEHICLE_ID_CHARS + 1)
    assert not valid_vehicle_id(long_id)
    with pytest.raises(ConfigError, match=r"vehicle_id: expected .*1\.\.64 characters"):
        mission_from_dict(mission_doc(vehicle_id=long_id), source="m.yaml")
    with pytest.raises(ValueError, match=r"1\.\.64 characters"):
        VehicleKeys(long_id)
    with pytest.raises(BusPayloadError, match=r"vehicle: expected a string of at most 64 "):
        decode_frames(json.dumps({"schema": "pdcov.frames", "version": 2, "vehicle": long_id,
                                  "frames": [{"t_boot_s": 1.0, "boxes": []}]}).encode())
