"""The mission config's ``domain`` section: the area to search and its obstacles, and the
``Domain`` (ENU m) they make."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.config.values import number, resolve
from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin
from pdcov.errors import ConfigError, PdcovError, where


@dataclass(frozen=True, slots=True)
class DomainSection:
    """``domain``: one of polygon_enu_m, polygon_geodetic_deg or geojson (a file), the
    obstacles in the same frame, and the grid's cell size (m). The polygons are read by
    ``Domain``; here they are kept as given."""

    polygon_enu_m: Any = None
    polygon_geodetic_deg: Any = None
    geojson: Any = None
    obstacles_enu_m: Any = None
    obstacles_geodetic_deg: Any = None
    cell_size_m: float = 1.0

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> DomainSection:
        cell = number(doc, "cell_size_m", src, "domain", default=1.0, positive=True)
        return cls(**{**{k: v for k, v in doc.items() if k != "cell_size_m"},
                      "cell_size_m": cell})


def load_domain(dom: DomainSection, src: str | None, base: Path, origin: Origin) -> Domain:
    """The Domain of the section's one polygon form (ENU; geodetic forms about ``origin``;
    a geojson file relative to ``base``)."""
    forms = [k for k in ("polygon_enu_m", "polygon_geodetic_deg", "geojson")
             if getattr(dom, k) is not None]
    if len(forms) != 1:
        raise ConfigError(f"{where(src, 'domain')}: expected exactly one of polygon_enu_m, "
                          f"polygon_geodetic_deg or geojson, got {forms or 'none'}")
    try:
        if forms[0] == "polygon_enu_m":
            return Domain.from_enu(dom.polygon_enu_m, dom.obstacles_enu_m, src)
        if forms[0] == "polygon_geodetic_deg":
            return Domain.from_geodetic(dom.polygon_geodetic_deg, dom.obstacles_geodetic_deg,
                                        origin, src)
        return Domain.from_geojson(resolve(dom.geojson, base, src, "domain.geojson"), origin)
    except PdcovError as exc:
        raise ConfigError(str(exc)) from None
