"""The mission config's ``search`` section: what the search assumes before any look (the
prior density of people, per km^2)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pdcov.config.values import defaults, number
from pdcov.errors import ConfigError, where

MAX_PEOPLE_PER_KM2 = 1e6
"""The most people per km^2 ``search.prior_people_per_km2`` takes: one per m^2."""


@dataclass(frozen=True, slots=True)
class SearchSection:
    """``search``: what the search assumes before any look: ``prior_people_per_km2``,
    people expected per km^2 where no POA map is given (the prior of a candidate's
    p_person, detection/candidates.py)."""

    prior_people_per_km2: float = 1.0

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> SearchSection:
        v = number(doc, "prior_people_per_km2", src, "search",
                    default=defaults(cls)["prior_people_per_km2"])
        if not 0 < v <= MAX_PEOPLE_PER_KM2:
            raise ConfigError(f"{where(src, 'search.prior_people_per_km2')}: expected a "
                              f"number > 0 and <= {MAX_PEOPLE_PER_KM2:g}, got {v!r}")
        return cls(v)
