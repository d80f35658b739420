"""Key expressions: everything one vehicle publishes lives under ``pdcov/<vehicle_id>/``."""

from __future__ import annotations

from dataclasses import dataclass

from pdcov.bus.errors import BusPayloadError
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id

PREFIX = "pdcov"
KINDS = ("status", "tiles", "snapshot", "footprint", "mission", "alive", "frames", "detections",
         "candidates", "retask")


@dataclass(frozen=True, slots=True)
class VehicleKeys:
    """The key expressions of one vehicle (``pdcov/<vehicle_id>/<kind>``)."""

    vehicle_id: str

    def __post_init__(self) -> None:
        if not valid_vehicle_id(self.vehicle_id):
            raise ValueError(f"vehicle_id {self.vehicle_id!r}: expected {VEHICLE_ID_RULE}")

    def key(self, kind: str) -> str:
        if kind not in KINDS:
            raise ValueError(f"key kind {kind!r}: expected one of {', '.join(KINDS)}")
        return f"{PREFIX}/{self.vehicle_id}/{kind}"

    @property
    def status(self) -> str:
        return self.key("status")

    @property
    def tiles(self) -> str:
        return self.key("tiles")

    @property
    def snapshot(self) -> str:
        return self.key("snapshot")

    @property
    def footprint(self) -> str:
        return self.key("footprint")

    @property
    def mission(self) -> str:
        return self.key("mission")

    @property
    def alive(self) -> str:
        return self.key("alive")

    @property
    def frames(self) -> str:
        return self.key("frames")

    @property
    def detections(self) -> str:
        return self.key("detections")

    @property
    def candidates(self) -> str:
        return self.key("candidates")

    @property
    def retask(self) -> str:
        return self.key("retask")


def all_vehicles(kind: str) -> str:
    """The key expression matching ``kind`` of every vehicle (``pdcov/*/<kind>``)."""
    if kind not in KINDS:
        raise ValueError(f"key kind {kind!r}: expected one of {', '.join(KINDS)}")
    return f"{PREFIX}/*/{kind}"


def parse_key(key: str) -> tuple[str, str]:
    """(vehicle_id, kind) of a pdcov key expression; BusPayloadError for anything else."""
    parts = str(key).split("/")
    if len(parts) != 3 or parts[0] != PREFIX or parts[2] not in KINDS \
            or not valid_vehicle_id(parts[1]):
        raise BusPayloadError(f"key {key!r}: expected {PREFIX}/<vehicle_id>/<"
                              f"{'|'.join(KINDS)}>")
    return parts[1], parts[2]
