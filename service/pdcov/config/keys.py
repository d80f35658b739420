"""The keys of a mission config: the schema of every section (checked before any value is
read), and the reserved sections the daemon's and the ground station's modules declare."""

from __future__ import annotations

from collections.abc import Mapping

from pdcov.config.camera import CAMERA_SECTIONS
from pdcov.config.coverage import CoverageSection
from pdcov.config.detections import DetectionsSection
from pdcov.config.domain import DomainSection
from pdcov.config.log import LogSection
from pdcov.config.origin import OriginSection
from pdcov.config.planning import PlanningSection
from pdcov.config.search import SearchSection
from pdcov.config.terrain import TerrainSection
from pdcov.schema import Section

# Sections of the onboard daemon (`pdcov serve`) and the ground station (`fleet`), declared
# by their own modules: see ``mission_schema``. Until a schema is passed for one, any
# mapping is accepted there.
RESERVED_SECTIONS = ("link", "bus", "service", "fleet")

MISSION_CONFIG = Section.of(
    "vehicle_id", "calibration", "thresholds", "cameras",
    origin=Section.of_dataclass(OriginSection),
    domain=Section.of_dataclass(DomainSection),
    **CAMERA_SECTIONS,
    coverage=Section.of_dataclass(CoverageSection),
    terrain=Section.of_dataclass(TerrainSection),
    log=Section.of_dataclass(LogSection),
    planning=Section.of_dataclass(PlanningSection),
    detections=Section.of_dataclass(DetectionsSection),
    search=Section.of_dataclass(SearchSection),
    **dict.fromkeys(RESERVED_SECTIONS, Section(open=True)))


def mission_schema(sections: Mapping[str, Section] | None = None) -> Section:
    """The keys of a mission config, every section and subsection (checked by
    ``mission_from_dict`` before any value is read).

    ``sections``: schemas of the reserved top-level sections ``link``, ``bus`` and
    ``service``, which belong to the onboard daemon: its modules declare them (a ``Section``,
    or a frozen dataclass per section through ``Section.of_dataclass(LinkConfig)``) and load
    the config with ``load_mission(path, sections={"link": LINK_CONFIG, ...})``; the section's
    mapping is then in ``Mission.raw["link"]`` for the daemon to build its values from. A
    reserved section without a schema here is accepted as any mapping (the offline tools do
    not read it).
    """
    sections = dict(sections or {})
    other = sorted(set(sections) - set(RESERVED_SECTIONS))
    if other:
        raise ValueError(f"only the reserved sections {RESERVED_SECTIONS} can be declared "
                         f"by another module, not {other}")
    return MISSION_CONFIG.extended(**sections)
