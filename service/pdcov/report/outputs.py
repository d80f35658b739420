"""Offline evaluation: camera poses through the coverage grid, and the run's outputs.

Outputs in a run folder (docs/outputs.md): metrics.json, grid.npz, heatmap.png,
thresholds.png, pd.tif (GeoTIFF: P_D, P_FA), looks.tif, limiting.tif, pd_rgba_3857.tif
(the P_D overlay in Web Mercator), outline.geojson, with
a prior posterior.npy / posterior.tif, and for ``pdcov evaluate`` the exports for search
teams' tools (report/exports.py: detections.geojson, caltopo.geojson, pdcov.kml, ...).
Every file is written atomically. The figures need the plots extra, the GeoTIFF and GeoJSON
files the gis extra: without one, the rest is written and the run says what was not
(``RunOutputs.not_written``).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely

from pdcov import __version__
from pdcov.atomic import atomic_write, write_text_atomic
from pdcov.config.mission import Mission
from pdcov.core.camera import CameraModel
from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_metrics import Metrics
from pdcov.core.pose import CameraPose, FixedMount
from pdcov.core.search_theory import SearchOutcome, search_outcome
from pdcov.core.sweep_width import FlightSample, SearchEffort, lateral_range
from pdcov.errors import InputFileError
from pdcov.extras import GIS, PLOTS
from pdcov.npz_file import read_npy, read_npz
from pdcov.report.exports import Pin, VehicleDetections, VehicleTrack, write_exports
from pdcov.report.grid_file import GRID_NPZ, write_grid_file
from pdcov.report.output_extent import (
    CROP_ABOVE_CELLS,
    check_prior_fits,
    drawn_raster,
    grid_proportion_curve,
    output_extent,
)
from pdcov.report.search_areas import Coverage

if TYPE_CHECKING:
    from pdcov.report.gis import BandReader
    from pdcov.report.map_figure import BasemapTiles

METRICS_VERSION = 1
GRID_GEOTIFFS = ("pd.tif", "looks.tif", "limiting.tif")
"""The grid's GeoTIFFs (docs/outputs.md): P_D and P_FA (float32), looks (int32), limiting
factor (uint8; not written when the limiting factors are unknown)."""
RGBA_TIF = "pd_rgba_3857.tif"
_PRIOR_SUM_TOL = 1e-4  # float32 GeoTIFF priors normalised to 1 sum to 1 only to ~1e-6


def evaluate_poses(grid: CoverageGrid, poses: Iterable[CameraPose], progress: bool = False,
                   total: int | None = None,
                   cameras: Sequence[CameraModel | None] = ()) -> CoverageGrid:
    """``grid`` (e.g. ``Mission.new_grid()``) updated with every pose (each a camera frame);
    ``cameras``: per pose, the camera it was taken with (a zoomed lens; None or none given:
    the grid's own)."""
    if progress:
        from tqdm import tqdm
        poses = tqdm(poses, desc="frames", unit="frame", total=total, mininterval=0.5)
    for i, pose in enumerate(poses):
        grid.update_with(pose, cameras[i] if cameras else None)
    return grid


def threshold_key(t: float) -> str:
    """A threshold as it appears in metrics.json, e.g. 0.8 -> "0.8"."""
    return repr(float(t))


def metrics_document(metrics: Metrics, outcome: SearchOutcome | None = None) -> dict[str, Any]:
    """The metrics.json mapping (version 1)."""
    doc: dict[str, Any] = {
        "version": METRICS_VERSION,
        "frames": metrics.frames,
        "cells_free": metrics.cells_free,
        "cells_observed": metrics.cells_observed,
        "proportion_at_or_above": {threshold_key(t): p
                                   for t, p in metrics.proportion_at_or_above.items()},
        "mean_pd": metrics.mean_pd,
        "expected_false_alarms": metrics.expected_false_alarms,
        "limiting_cells": metrics.limiting_cells,
    }
    if outcome is not None:
        doc["probability_of_success"] = outcome.probability_of_success
        doc["prior_mass_in_grid"] = outcome.prior_mass
    return doc


def sweep_width_document(mission: Mission, flight: FlightSample
                         ) -> tuple[dict[str, Any] | None, str | None]:
    """metrics.json's sweep_width (docs/outputs.md) and None, or None and why not: the
    lateral range of the mission's first camera on its mount (a gimbal: pointing at nadir,
    its nominal attitude for a survey), detector and frame rate at the flight's median height
    above the ground and median search speed (FlightSample.search_speed_mps), with the track
    flown over the domain's free area (core/sweep_width.py)."""
    why = flight.unusable()
    if why is not None:
        return None, why
    cam = mission.first_camera
    mount = cam.mount if isinstance(cam.mount, FixedMount) else FixedMount(
        lever_arm_frd_m=cam.mount.lever_arm_frd_m)
    height, speed = float(np.median(flight.heights_agl_m)), flight.search_speed_mps
    try:
        curve = lateral_range(cam.camera, cam.detector, mount, altitude_m=height,
                              speed_mps=speed, frame_rate_hz=cam.frame_rate_hz,
                              cell_size_m=mission.cell_size_m,
                              min_revisit_s=mission.min_revisit_s, looks=mission.looks,
                              exposure_s=cam.exposure_s, max_range_m=mission.max_range_m)
    except ValueError as exc:
        return None, f"at {height:.1f} m and {speed:.2f} m/s {exc}"
    effort = SearchEffort(curve.sweep_width_m, flight.track_length_m,
                          float(mission.domain.free_space.area))
    return {"altitude_agl_m": height, "speed_mps": speed,
            "mount": "fixed" if isinstance(cam.mount, FixedMount) else "gimbal at nadir",
            "sweep_width_m": effort.sweep_width_m, "track_length_m": effort.track_length_m,
            "area_m2": effort.area_m2, "coverage_factor": effort.coverage_factor,
            "pod_random_search": effort.pod_random_search,
            "pod_parallel_sweeps": effort.pod_parallel_sweeps}, None


@dataclass(frozen=True, slots=True)
class Prior:
    """Probability of area per grid cell, and notes for the summary (e.g. the share of a
    segment's POA that lies outside the grid)."""

    poa: np.ndarray
    notes: tuple[str, ...] = ()


def read_prior(path: str | Path, geometry: GridGeometry, mask: np.ndarray,
               origin: Origin) -> Prior:
    """Probability of area per cell from a .npy or GeoTIFF aligned with the grid, or a
    GeoJSON of segments (Polygon or MultiPolygon, holes allowed, WGS84) each with a ``poa``
    property, spread over the segment's area: each cell gets the share of the segment's
    area inside it. The share of a segment outside the grid stays outside (named in the
    notes). Raises InputFileError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: prior file not found")
    suffix = path.suffix.lower()
    notes: tuple[str, ...] = ()
    try:
        if suffix == ".npy":
            poa = read_npy(path, ValueError).astype(float)
            if poa.shape != geometry.shape:
                raise ValueError(f"array shape {poa.shape} != grid shape {geometry.shape} "
                                 "(rows north, columns east)")
        elif suffix in (".tif", ".tiff"):
            GIS.require("a GeoTIFF prior needs")
            from pdcov.report.gis import read_geotiff_band
            poa = np.nan_to_num(read_geotiff_band(path, geometry), nan=0.0)
        elif suffix in (".geojson", ".json"):
            poa, notes = _prior_from_segments(json.loads(path.read_text()), geometry, mask,
                                              origin)
        else:
            raise ValueError("expected a .npy, .tif or .geojson prior")
    except (ValueError, OSError, KeyError, TypeError, shapely.errors.GEOSException) as exc:
        raise InputFileError(f"{path}: cannot use as a prior: {exc}") from None
    if not np.all(np.isfinite(poa)) or np.any(poa < 0) or poa.sum() <= 0:
        raise InputFileError(f"{path}: prior probabilities must be finite, >= 0, and not all 0")
    # A probability of area sums to at most 1 (the rest lies outside the grid); more would
    # give a probability of success above 1.
    if poa.sum() > 1.0 + _PRIOR_SUM_TOL:
        raise InputFileError(f"{path}: prior probabilities sum to {poa.sum():.6g} over the "
                             f"grid; a probability of area sums to at most 1 (normalise it)")
    return Prior(poa, tuple(f"{path.name}: {n}" for n in notes))


def _segment_enu(geometry_doc: Any, origin: Origin) -> shapely.Geometry:
    """A GeoJSON Polygon / MultiPolygon (lon, lat) as one ENU area, holes kept."""
    geom = shapely.geometry.shape(geometry_doc)
    parts = []
    for part in getattr(geom, "geoms", [geom]):
        if not isinstance(part, shapely.Polygon):
            raise ValueError(f"expected Polygon or MultiPolygon, got {part.geom_type}")

        def enu(ring: Any) -> np.ndarray:
            ll = np.asarray(ring.coords)
            return geodetic_to_enu(ll[:, 1], ll[:, 0], origin.ground_alt_msl_m, origin)[:, :2]

        parts.append(shapely.Polygon(enu(part.exterior), [enu(r) for r in part.interiors]))
    return shapely.make_valid(shapely.union_all(parts))


def _prior_from_segments(doc: Any, geometry: GridGeometry, mask: np.ndarray,
                         origin: Origin) -> tuple[np.ndarray, tuple[str, ...]]:
    features = doc.get("features") if isinstance(doc, dict) else None
    if not features:
        raise ValueError("expected a FeatureCollection of segments")
    c = geometry.cell_size_m
    poa = np.zeros(geometry.shape)
    notes = []
    for k, feature in enumerate(features):
        props = feature.get("properties") or {}
        if "poa" not in props:
            raise ValueError(f"feature {k}: missing property 'poa'")
        p = float(props["poa"])
        seg = _segment_enu(feature["geometry"], origin)
        if not seg.area > 0:
            raise ValueError(f"feature {k}: segment has no area")
        # Cells under the segment's bounding box, and the area of the segment in each.
        x0, y0, x1, y1 = seg.bounds
        c0 = max(0, int(np.floor((x0 - geometry.x0_m) / c)))
        c1 = min(geometry.n_cols, int(np.ceil((x1 - geometry.x0_m) / c)))
        r0 = max(0, int(np.floor((y0 - geometry.y0_m) / c)))
        r1 = min(geometry.n_rows, int(np.ceil((y1 - geometry.y0_m) / c)))
        share = np.zeros(geometry.shape)
        if c1 > c0 and r1 > r0:
            rows, cols = np.mgrid[r0:r1, c0:c1]
            boxes = shapely.box(geometry.x0_m + cols * c, geometry.y0_m + rows * c,
                                geometry.x0_m + (cols + 1) * c, geometry.y0_m + (rows + 1) * c)
            share[r0:r1, c0:c1] = shapely.area(shapely.intersection(boxes, seg)) / seg.area
        if not np.any(share[mask] > 1e-9):
            raise ValueError(f"feature {k}: segment covers no free cell of the grid")
        poa += p * share
        outside, unfree = 1.0 - float(share.sum()), float(share[~mask].sum())
        if outside > 1e-6 or unfree > 1e-6:
            notes.append(f"segment {k} (poa {p:g}): {outside:.1%} of it (POA "
                         f"{p * outside:.4g}) lies outside the grid and {unfree:.1%} (POA "
                         f"{p * unfree:.4g}) on cells that are not free (outside the domain "
                         f"or in obstacles); neither can be searched")
    return poa, tuple(notes)


@dataclass(frozen=True, slots=True)
class RunOutputs:
    """What a run wrote, and the numbers for the summary."""

    out_dir: Path
    files: tuple[str, ...]
    metrics: Metrics
    outcome: SearchOutcome | None
    not_written: tuple[str, ...] = ()  # "heatmap.png, ...: figures need ...", one a line
    limiting_unknown: str | None = None  # why the grid's limiting factors are unknown


def write_outputs(out_dir: str | Path, mission: Mission, grid: CoverageGrid, origin: Origin,
                  *, title: str, track_enu: np.ndarray | None = None,
                  plan_enu: np.ndarray | None = None, outline_threshold: float | None = None,
                  prior: np.ndarray | None = None, extra_metrics: dict[str, Any] | None = None,
                  figures: bool = True,
                  exports: Sequence[VehicleDetections] | None = None,
                  tracks: Sequence[VehicleTrack] = (),
                  limiting_unknown: str | None = None,
                  flight: FlightSample | None = None,
                  basemap: BasemapTiles | None = None,
                  progress: bool = False) -> RunOutputs:
    """Write the run's files into ``out_dir`` (created if needed): those whose extra is
    not installed are named in ``not_written`` instead. ``exports``: the detections to
    export with the coverage (report/exports.py; gaps below the outline threshold), None
    for no exports; ``tracks``: the flown tracks the exports carry (pdcov.gpx).
    ``limiting_unknown``: why the grid's limiting factors are unknown (None: they are
    known); metrics.json's limiting_cells is then null, with this reason under
    limiting_unknown, and grid.npz holds no limiting factor nor is limiting.tif written.
    ``flight``: the frames' heights, speeds and track (core/sweep_width.py) for
    metrics.json's sweep_width (``sweep_width_document``); None: no sweep_width.
    ``basemap``: the tiles map.png is drawn over (report/map_figure.py). ``progress``: a
    line on stderr as each kind of file is begun (a county's GeoTIFFs take a minute)."""
    def stage(what: str) -> None:
        if progress:
            print(f"writing {what} in {out_dir}", file=sys.stderr, flush=True)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    metrics = grid.metrics(mission.thresholds)
    extent = output_extent(grid)
    if prior is not None:
        check_prior_fits(grid.geometry)
    outcome = search_outcome(prior, grid.pd, grid.mask) if prior is not None else None
    doc = metrics_document(metrics, outcome)
    doc["motion_blur"] = {"effect": grid.blur_effect.name.lower(),
                          "exposure_s": grid.exposure_s, "frames_blurred": grid.frames_blurred}
    if limiting_unknown is not None:
        doc["limiting_cells"] = None
        doc["limiting_unknown"] = limiting_unknown
    doc["extent"] = extent.document(origin)
    if flight is not None:
        doc["time_on_scene_s"] = flight.time_on_scene_s
        doc["sweep_width"], reason = sweep_width_document(mission, flight)
        if reason is not None:
            doc["sweep_width_unknown"] = reason
    doc.update(extra_metrics or {})
    threshold = outline_threshold if outline_threshold is not None else max(mission.thresholds)
    files = ["metrics.json"]
    not_written = []
    stage("metrics.json and grid.npz")
    write_text_atomic(out / "metrics.json", json.dumps(doc, indent=2) + "\n")
    grid_file = write_grid_file(out, grid, with_limiting=limiting_unknown is None)
    files += [grid_file.name] if grid_file.name else []
    not_written += [grid_file.not_written] if grid_file.not_written else []
    drawn = drawn_raster(grid, extent, hidden=limiting_unknown is None, terrain=grid.terrain)
    g = drawn.geometry
    gis_missing = GIS.message()
    outline: list[list[list[list[float]]]] = []
    if gis_missing is None:
        stage("the GeoTIFFs and outline.geojson")
        from pdcov.report.gis import (
            array_band,
            threshold_outline,
            write_geotiff,
            write_outline_geojson,
            write_rgba_3857,
        )

        outline = threshold_outline(drawn.pd, drawn.mask, g, threshold)
        r0, _, c0, _ = extent.window

        def band(layer: Layer) -> BandReader:  # window cells -> grid cells
            return lambda w: grid.read(layer, (r0 + w[0], r0 + w[1], c0 + w[2], c0 + w[3]))

        tags = {"PDCOV_VERSION": __version__, "TITLE": title,
                "VEHICLE": mission.vehicle_id, "FRAMES": str(grid.frames)}
        files += _write_grid_geotiffs(out, band, extent.geometry, origin, tags,
                                      with_limiting=limiting_unknown is None)
        write_outline_geojson(out / "outline.geojson", outline, origin, threshold)
        files.append("outline.geojson")
        plots_missing = PLOTS.message("the RGBA GeoTIFF needs")
        if plots_missing is None:
            from pdcov.report.colours import pd_rgba
            from pdcov.report.kml import MAX_OVERLAY_SIDE

            rgba, stride = pd_rgba(drawn.pd, drawn.mask, MAX_OVERLAY_SIDE)
            write_rgba_3857(out / RGBA_TIF, rgba, GridGeometry(
                g.x0_m, g.y0_m, g.cell_size_m * stride, rgba.shape[0], rgba.shape[1]),
                origin, tags)
            files.append(RGBA_TIF)
        else:
            not_written.append(f"{RGBA_TIF}: {plots_missing}")
    if outcome is not None:
        with atomic_write(out / "posterior.npy", "wb") as f:
            np.save(f, outcome.posterior)
        files.append("posterior.npy")
        if gis_missing is None:
            write_geotiff(out / "posterior.tif",
                          {"posterior_poa": array_band(outcome.posterior)}, grid.geometry,
                          origin, array_band(np.ones(grid.geometry.shape, bool)),
                          exact_grid=True)  # a prior for the next search (read_prior)
            files.append("posterior.tif")
    if gis_missing is not None:
        gis_files = (*GRID_GEOTIFFS, "outline.geojson", RGBA_TIF) + (
            ("posterior.tif",) if outcome else ())
        not_written.append(f"{', '.join(gis_files)}: {gis_missing}")
    exported_pins: tuple[Pin, ...] = ()
    if exports is not None:
        stage("the exports")
        coverage = Coverage(drawn.pd, drawn.mask, g, origin, tuple(mission.thresholds),
                            threshold)
        exported = write_exports(out, coverage, exports, title=title, tracks=tracks)
        files += exported.files
        not_written += exported.not_written
        exported_pins = exported.pins
    if figures:
        stage("the figures")
        figure_files = ["heatmap.png", "thresholds.png", "map.png"]
        plots_missing = PLOTS.message()
        if plots_missing is None:
            from pdcov.report.map_figure import map_figure
            from pdcov.report.plots import heatmap_figure, thresholds_figure

            heatmap_figure(out / "heatmap.png", drawn.pd, drawn.mask, g, mission.domain,
                           title=title, outline_enu=outline, threshold=threshold,
                           track_enu=track_enu, plan_enu=plan_enu,
                           terrain_z_m=drawn.terrain_z_m, hidden=drawn.hidden, origin=origin)
            thresholds_figure(out / "thresholds.png", grid_proportion_curve(grid),
                              metrics.proportion_at_or_above, title=title)
            if not map_figure(out / "map.png", drawn.pd, drawn.mask, g, mission.domain,
                              origin, title=title, outline_enu=outline, threshold=threshold,
                              tracks=tracks, pins=exported_pins, basemap=basemap):
                not_written.append("map.png's basemap: it has no tile over the map")
            files += figure_files
        else:
            not_written.append(f"{', '.join(figure_files)}: {plots_missing}")
    return RunOutputs(out, tuple(files), metrics, outcome, tuple(not_written),
                      limiting_unknown)


def _write_grid_geotiffs(out: Path, band: Callable[[Layer], BandReader],
                         geometry: GridGeometry, origin: Origin, tags: dict[str, str], *,
                         with_limiting: bool) -> list[str]:
    """GRID_GEOTIFFS over ``geometry`` from ``band`` (a layer's cells by window of it), each
    with ``tags``; the names written."""
    from pdcov.report.gis import LIMITING_NODATA, LOOKS_NODATA, limiting_codes, write_geotiff

    pd_tif, looks_tif, limiting_tif = GRID_GEOTIFFS
    free = band(Layer.MASK)
    write_geotiff(out / pd_tif, {"pd": band(Layer.PD), "pfa": band(Layer.PFA)}, geometry,
                  origin, free, tags=tags)
    write_geotiff(out / looks_tif, {"n_obs": band(Layer.N_OBS)}, geometry, origin, free,
                  dtype="int32", nodata=LOOKS_NODATA, tags=tags)
    if not with_limiting:
        return [pd_tif, looks_tif]
    write_geotiff(out / limiting_tif, {"limiting": band(Layer.LIMITING)}, geometry, origin,
                  free, dtype="uint8", nodata=LIMITING_NODATA,
                  tags={**tags, "LIMITING_CODES": limiting_codes()})
    return [pd_tif, looks_tif, limiting_tif]


def summary_text(run: RunOutputs, lines: Sequence[str] = ()) -> str:
    """A one-screen summary of a run."""
    m = run.metrics
    out = [*lines,
           f"frames: {m.frames}   free cells: {m.cells_free}   observed: {m.cells_observed} "
           f"({m.cells_observed / max(m.cells_free, 1):.1%})",
           f"mean P_D: {m.mean_pd:.3f}   expected false alarms: {m.expected_false_alarms:.2f}",
           "proportion of free cells with P_D at or above: " + "   ".join(
               f"{t:g}: {p:.3f}" for t, p in m.proportion_at_or_above.items()),
           "limiting factor of free cells: " + (run.limiting_unknown or "   ".join(
               f"{name.replace('_', ' ')}: {n}" for name, n in m.limiting_cells.items()))]
    if run.outcome is not None:
        out.append(f"probability of success POS: {run.outcome.probability_of_success:.3f} "
                   f"(prior mass in grid {run.outcome.prior_mass:.3f}); posterior written")
    out.append(f"wrote {', '.join(run.files)} in {run.out_dir}")
    out += [f"not written: {line}" for line in run.not_written]
    return "\n".join(out)


def read_run(run_dir: str | Path) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """metrics.json, pd and mask of a run folder. Raises InputFileError naming the file."""
    run = Path(run_dir)
    try:
        doc = json.loads((run / "metrics.json").read_text())
        if not (run / GRID_NPZ).exists() and (doc.get("extent") or {}).get("cropped"):
            raise InputFileError(f"{run}: a run over more than {CROP_ABOVE_CELLS:,} cells has "
                                 f"no {GRID_NPZ} to compare (docs/outputs.md \"Extent\")")
        grid = read_npz(run / GRID_NPZ, ValueError)
        pd, mask = grid["pd"], grid["mask"].astype(bool)
    except (OSError, ValueError, KeyError) as exc:
        raise InputFileError(f"{run}: not a pdcov run folder ({exc})") from None
    if doc.get("version") != METRICS_VERSION:
        raise InputFileError(f"{run / 'metrics.json'}: version {doc.get('version')!r}, "
                             f"expected {METRICS_VERSION}")
    return doc, pd, mask


def finite_track(track_enu: np.ndarray | None) -> np.ndarray | None:
    """Drop non-finite rows of a track (N, 3); None stays None."""
    if track_enu is None:
        return None
    t = np.asarray(track_enu, dtype=float)
    return t[np.all(np.isfinite(t), axis=1)] if len(t) else t


