"""Reading a mission config (docs/mission-config.md): ``load_mission`` from a YAML file,
``mission_from_dict`` from a parsed mapping; keys first, then every section's values. Every
error names the file, the key and what was expected."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pdcov.config.camera import mission_camera
from pdcov.config.camera_list import camera_list, check_camera_ids
from pdcov.config.coverage import CoverageSection
from pdcov.config.detections import DetectionsSection
from pdcov.config.domain import DomainSection, load_domain
from pdcov.config.keys import mission_schema
from pdcov.config.log import LogSection
from pdcov.config.mission import DEFAULT_THRESHOLDS, MAX_THRESHOLDS, Mission
from pdcov.config.origin import OriginSection
from pdcov.config.search import SearchSection
from pdcov.config.terrain import (
    DEFAULT_TERRAIN_MARGIN_M,
    TerrainSection,
    cover_terrain,
    dem_ground_alt,
    open_dem,
    searched_domain,
)
from pdcov.config.values import mapping
from pdcov.core import dem as dem_rules
from pdcov.core.dem import height_mismatch, terrain_surface
from pdcov.core.geodesy import Origin
from pdcov.core.looks import LooksConfig, LooksRule
from pdcov.errors import ConfigError, PdcovError, where
from pdcov.ids import VEHICLE_ID_RULE, valid_vehicle_id
from pdcov.schema import Section, check_keys
from pdcov.yaml_file import load_yaml


def load_mission(path: str | Path, sections: Mapping[str, Section] | None = None) -> Mission:
    """Read and validate a mission config; relative paths inside resolve against its folder.
    ``sections``: schemas of the daemon's reserved sections (``mission_schema``)."""
    path = Path(path)
    doc = load_yaml(path, "mission config")
    return mission_from_dict(doc, source=str(path), base_dir=path.parent, sections=sections)


def mission_from_dict(doc: Any, source: str | None = None, base_dir: Path | None = None,
                      sections: Mapping[str, Section] | None = None) -> Mission:
    """Validate a parsed mission config mapping: first its keys, all sections
    (``mission_schema``), then the values."""
    src = source
    base = base_dir or Path(".")
    check_keys(doc, mission_schema(sections), src or "mission config")
    listed = camera_list(doc, src)
    for key in ("origin", "domain", "camera", "detector"):
        if listed and key in ("camera", "detector"):
            continue
        if key not in doc and not (key == "camera" and "calibration" in doc):
            raise ConfigError(f"{where(src, key)}: missing (see docs/mission-config.md)")

    origin = OriginSection.from_mapping(mapping(doc, "origin", src), src)
    try:
        origin_value = Origin(origin.lat_deg, origin.lon_deg, origin.ground_alt_msl_m or 0.0)
    except ConfigError as exc:
        raise ConfigError(f"{src}: {exc}" if src else str(exc)) from None

    dom = DomainSection.from_mapping(mapping(doc, "domain", src), src)
    cell = dom.cell_size_m
    domain = load_domain(dom, src, base, origin_value)
    ter = (TerrainSection.from_mapping(mapping(doc, "terrain", src), src)
           if doc.get("terrain") is not None else None)
    cov = CoverageSection.from_mapping(mapping(doc, "coverage", src, required=False), src)
    if ter is not None and ter.surface is not None and cov.looks is not LooksRule.INDEPENDENT:
        raise ConfigError(f"{where(src, 'terrain.surface')}: what stands on the ground is "
                          f"taken into account with independent looks only (for now); "
                          f"coverage.looks is {cov.looks}: use coverage.looks: independent, "
                          "or leave terrain.surface out")
    dem = None
    ground_alt, ground_how, warnings = origin.ground_alt_msl_m, "configured", []
    if ter is not None:
        dem = open_dem(ter, src, base, domain.grid_geometry(cell), origin_value)
        if ground_alt is None:
            ground_alt = dem_ground_alt(dem, origin, src, domain.grid_geometry(cell),
                                        origin_value)
            ground_how = "the DEM at the origin"
            origin_value = Origin(origin.lat_deg, origin.lon_deg, ground_alt)
            domain = load_domain(dom, src, base, origin_value)  # geodetic polygons at that ground
        elif err := dem_rules.home_offset_error(dem, origin.lat_deg, origin.lon_deg, ground_alt,
                                                ter.max_home_offset_m):
            raise ConfigError(f"{where(src, 'origin.ground_alt_msl_m')}: {err}")
        else:
            mismatch = height_mismatch(dem, origin.lat_deg, origin.lon_deg, ground_alt,
                                       ter.check_margin_m, "origin.ground_alt_msl_m")
            warnings += [f"{src}: {mismatch}" if src else mismatch] if mismatch else []
    if not domain.has_free_cell(domain.grid_geometry(cell)):
        raise ConfigError(
            f"{where(src, 'domain')}: no free cell to cover: no centre of a {cell:g} m cell "
            f"lies in the free space ({domain.free_space.area:.3g} m^2 of the polygon's "
            f"{domain.boundary.area:.3g} m^2); the obstacles cover the polygon, or it is "
            "narrower than a cell (domain.cell_size_m)")

    terrain, searched = None, domain
    if dem is not None and ter is not None:
        g = domain.grid_geometry(cell)
        free = domain.free_mask(g)
        try:
            terrain = terrain_surface(dem, g, origin_value, free)
        except PdcovError as exc:
            raise ConfigError(f"{where(src, 'terrain.dem')}: {exc}") from None
        if ter.surface is not None:
            terrain, notes = cover_terrain(ter, src, base, terrain, dem, origin_value, free)
            warnings += notes
            assert terrain.cover is not None
            searched = searched_domain(ter, src, domain, terrain.cover, free)
    cameras = ([mission_camera(e, f"cameras[{i}].", str(e.get("name", f"camera{i + 1}")),
                               src, base) for i, e in enumerate(listed)]
               if listed else [mission_camera(doc, "", "camera", src, base)])

    thresholds = doc.get("thresholds", list(DEFAULT_THRESHOLDS))
    if (not isinstance(thresholds, list) or not thresholds or not all(
            isinstance(t, (int, float)) and not isinstance(t, bool) and 0 <= t <= 1
            for t in thresholds)):
        raise ConfigError(f"{where(src, 'thresholds')}: expected a non-empty list of "
                          f"probabilities in [0, 1], got {thresholds!r}")
    if len(thresholds) > MAX_THRESHOLDS:
        raise ConfigError(f"{where(src, 'thresholds')}: {len(thresholds)} thresholds, at "
                          f"most {MAX_THRESHOLDS} (every watcher refuses a status with more; "
                          "docs/protocol.md \"Validation and bounds\")")

    det = DetectionsSection.from_mapping(mapping(doc, "detections", src, required=False), src)
    search = SearchSection.from_mapping(mapping(doc, "search", src, required=False), src)
    log_doc = mapping(doc, "log", src, required=False)
    log = LogSection.from_mapping(log_doc, src)
    vehicle_id = doc.get("vehicle_id", "uav1")
    if not valid_vehicle_id(vehicle_id):
        raise ConfigError(f"{where(src, 'vehicle_id')}: expected {VEHICLE_ID_RULE}, "
                          f"got {vehicle_id!r}")
    looks = LooksConfig()
    for i, cam in enumerate(cameras):  # every camera's detector model serves the looks
        looks = cov.looks_config(cam.detector, src,
                                 f"cameras[{i}].detector" if listed else "coverage.looks")
    if listed:
        check_camera_ids(cameras, src)
    return Mission(
        vehicle_id=vehicle_id, origin_lat_deg=origin.lat_deg, origin_lon_deg=origin.lon_deg,
        ground_alt_msl_m=ground_alt, domain=searched, cell_size_m=cell, cameras=tuple(cameras),
        thresholds=tuple(float(t) for t in thresholds),
        max_range_m=cov.max_range_m, min_revisit_s=cov.min_revisit_s,
        min_height_m=cov.min_height_m, looks=looks,
        frame_source=log.frame_source, frame_source_set="frame_source" in log_doc,
        max_gap_s=log.max_gap_s, system_id=log.system_id,
        estimator_status=log.estimator_status, ground_alt_how=ground_how, terrain=terrain,
        dem=dem, configured_domain=None if searched is domain else domain,
        terrain_check_margin_m=ter.check_margin_m if ter else DEFAULT_TERRAIN_MARGIN_M,
        terrain_max_home_offset_m=(ter.max_home_offset_m if ter
                                   else dem_rules.DEFAULT_MAX_HOME_OFFSET_M),
        geolocation=det.geolocation(), gate_sigmas=det.gate_sigmas,
        prior_people_per_km2=search.prior_people_per_km2,
        warnings=tuple(warnings), source=src, raw=doc)
