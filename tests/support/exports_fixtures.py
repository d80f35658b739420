"""A small coverage and a vehicle's detections document for the export tests (shape of
docs/protocol.md "detections"), made here so that the tests need no daemon or detector."""

from __future__ import annotations

from typing import Any

import numpy as np

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.report.search_areas import Coverage

ORIGIN = Origin(46.5, 7.25, 600.0)


def coverage() -> Coverage:
    """40 x 30 cells of 1 m (south-west corner at (-20, -15) m): P_D grows eastwards from 0
    to 1, a 4 x 4 hole of P_D 0.1 in the well-covered east, the two western columns not
    free."""
    g = GridGeometry(-20.0, -15.0, 1.0, 30, 40)
    _, cols = np.mgrid[0:30, 0:40]
    pd = cols / 39.0
    pd[10:14, 34:38] = 0.1
    mask = np.ones((30, 40), bool)
    mask[:, :2] = False
    return Coverage(pd, mask, g, ORIGIN, (0.5, 0.8), 0.8)


def point(x_m: float, y_m: float) -> dict[str, float]:
    lat, lon, alt = enu_to_geodetic(np.array([x_m, y_m, 0.0]), ORIGIN)
    return {"lat_deg": float(lat), "lon_deg": float(lon), "alt_msl_m": float(alt),
            "x_m": x_m, "y_m": y_m}


EPOCH = "3fa2c1"
"""The daemon's epoch in the uids made here (docs/protocol.md "detections")."""


def uid(cid: int, vehicle: str = "uav1") -> str:
    return f"{vehicle}.{EPOCH}.{cid}"


def candidate(cid: int, x_m: float, y_m: float, hits: int = 9, looks: int = 14,
              last_t_boot_s: float = 30.0, p_person: float = 0.9731, vehicle: str = "uav1"
              ) -> dict[str, Any]:
    return {"id": cid, "uid": uid(cid, vehicle), "class": "person", **point(x_m, y_m),
            "sigma_m": 0.5, "hits": hits, "looks": looks, "p_person": p_person, "pd": 0.6,
            "pfa": 0.01, "confidence": 0.93, "first_t_boot_s": 10.0,
            "last_t_boot_s": last_t_boot_s}


def detection(cid: int, x_m: float, y_m: float, t_boot_s: float = 12.5,
              vehicle: str = "uav1") -> dict[str, Any]:
    return {"t_boot_s": t_boot_s, "class": "person", "confidence": 0.9,
            "box_px": [100.0, 120.0, 12.0, 30.0], **point(x_m, y_m), "sigma_m": 0.7,
            "candidate": cid, "uid": uid(cid, vehicle)}


def detections_doc(vehicle: str = "alpha") -> dict[str, Any]:
    """Pin 3 (likely: p_person 0.9731, 9 hits of 14 looks) and pin 4 (unlikely: 0.0412,
    1 of 3), with three detections."""
    return {"schema": "pdcov.detections", "version": 2, "vehicle": vehicle,
            "detections": [detection(3, 15.2, 2.4, vehicle=vehicle),
                           detection(3, 15.6, 2.0, 13.0, vehicle=vehicle),
                           detection(4, -10.5, -5.5, 20.0, vehicle=vehicle)],
            "candidates": [candidate(3, 15.4, 2.2, vehicle=vehicle),
                           candidate(4, -10.5, -5.5, 1, 3, 20.0, 0.0412, vehicle=vehicle)]}
