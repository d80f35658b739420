"""The pins' ranks: every export, the map and the report number the candidates alike, 1 the
highest ``p_person`` ("pin 3" on the radio is the same pin in CalTopo, ATAK, map.png and
report.html)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol


class Findings(Protocol):
    """One vehicle's candidates (report/exports.py's VehicleDetections)."""

    @property
    def vehicle(self) -> str: ...

    @property
    def candidates(self) -> Sequence[Mapping[str, Any]]: ...


def candidate_ranks(findings: Sequence[Findings]) -> dict[tuple[str, str], int]:
    """Each candidate's rank by (vehicle, uid): 1, 2, ... by ``p_person`` descending over
    every vehicle; equal (or unknown, last) ``p_person`` keep the order given."""
    entries = [(f.vehicle, str(c["uid"]), c.get("p_person")) for f in findings
               for c in f.candidates]

    def key(entry: tuple[str, str, Any]) -> float:
        p = entry[2]
        return -float(p) if isinstance(p, (int, float)) else float("inf")
    return {(vehicle, uid): k for k, (vehicle, uid, _) in enumerate(sorted(entries, key=key), 1)}
