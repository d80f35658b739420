"""The handover report (docs/outputs.md "Handover report"): what the search manager reads at
the end of a sortie, built from a run folder's files (report/run_files.py), never from the
grid, as sections of text, tables and figures; report/handover_html.py writes it as
``report.html`` (one self-contained page) and report/handover_pdf.py as ``report.pdf`` (the
same content on A4 pages, the ``plots`` extra). ``write_report`` writes both."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pdcov.atomic import write_text_atomic
from pdcov.errors import OutputError
from pdcov.extras import PLOTS
from pdcov.report.run_files import RunFiles, read_run_files

if TYPE_CHECKING:
    from pdcov.report.outputs import RunOutputs

REPORT_HTML = "report.html"
REPORT_PDF = "report.pdf"
_FIGURES = (("mean_pd", "mean P_D of the free cells", "{:.3f}"),
            ("expected_false_alarms", "expected false alarms", "{:.2f}"),
            ("probability_of_success", "probability of success (POS)", "{:.3f}"),
            ("prior_mass_in_grid", "prior mass in the grid", "{:.3f}"),
            ("sweep_width_m", "effective sweep width", "{:.1f} m"))
"""metrics.json's figures the report shows, each only when its key is there."""
_NO_PLOTS = "the figures need the plots extra"


@dataclass(frozen=True, slots=True)
class Table:
    """Rows of cell texts under ``header``; columns ``numeric`` right-aligned."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    numeric: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Figure:
    """A PNG figure of the run and what it shows."""

    png: bytes
    alt: str


@dataclass(frozen=True, slots=True)
class Section:
    """A heading and what follows it, in this order: ``text`` paragraphs, ``items`` (a
    list), a ``table``, a ``figure``; ``missing``: why some piece is not there (a line)."""

    heading: str
    text: tuple[str, ...] = ()
    items: tuple[str, ...] = ()
    table: Table | None = None
    figure: Figure | None = None
    missing: str | None = None


@dataclass(frozen=True, slots=True)
class Handover:
    """The report: its ``title``, the ``summary`` (label, value) rows and the sections."""

    title: str
    summary: tuple[tuple[str, str], ...]
    sections: tuple[Section, ...]


def _number(value: Any, fmt: str) -> str:
    return fmt.format(value) if isinstance(value, (int, float)) else str(value)


def _features(doc: Mapping[str, Any] | None) -> list[Mapping[str, Any]]:
    feats = (doc or {}).get("features")
    return [f for f in feats if isinstance(f, Mapping)] if isinstance(feats, list) else []


def _props(feature: Mapping[str, Any]) -> Mapping[str, Any]:
    p = feature.get("properties")
    return p if isinstance(p, Mapping) else {}


def candidates(detections: Mapping[str, Any] | None) -> list[Mapping[str, Any]]:
    """detections.geojson's candidates by their rank (report/pin_rank.py: p_person
    descending); a run written before ranks, by p_person (none known last)."""
    feats = [f for f in _features(detections) if _props(f).get("kind") == "candidate"]

    def key(f: Mapping[str, Any]) -> tuple[float, float]:
        rank, p = _props(f).get("rank"), _props(f).get("p_person")
        return (rank if isinstance(rank, int) else math.inf,
                -float(p) if isinstance(p, (int, float)) else math.inf)
    return sorted(feats, key=key)


def _lon_lat(feature: Mapping[str, Any]) -> tuple[str, str]:
    coords = (feature.get("geometry") or {}).get("coordinates") or []
    if len(coords) >= 2 and all(isinstance(v, (int, float)) for v in coords[:2]):
        return f"{coords[1]:.7f}", f"{coords[0]:.7f}"
    return "-", "-"


def title_of(run: RunFiles) -> str:
    """The run's title (its exports', else the folder's name)."""
    return str(((run.caltopo or {}).get("pdcov") or {}).get("title") or run.name)


def _summary(run: RunFiles) -> tuple[tuple[str, str], ...]:
    m = run.metrics
    fleet = m.get("vehicles")  # a watch --record fleet's metrics.json
    vehicles = sorted({str(_props(f)["vehicle"]) for f in _features(run.detections)
                       if "vehicle" in _props(f)})
    rows: list[tuple[str, Any]] = [("run", title_of(run))]
    if isinstance(fleet, (list, Mapping)) and fleet:
        rows.append(("vehicles", ", ".join(str(v) for v in fleet)))
    if vehicles:
        rows.append(("vehicles with detections", ", ".join(vehicles)))
    logs = m.get("logs")
    if isinstance(logs, list) and logs:
        rows.append(("flight logs", ", ".join(
            f"{Path(str(lg.get('log', '?'))).name} ({lg.get('frames', '?')} frames)"
            for lg in logs if isinstance(lg, Mapping))))
    rows.append(("frames", m.get("frames", "-")))
    flight_s = (m.get("plan") or {}).get("flight_time_s") if isinstance(m.get("plan"),
                                                                       Mapping) else None
    time_s = m.get("time_on_scene_s", flight_s)
    rows.append(("time on scene", f"{time_s / 60:.1f} min" if isinstance(time_s, (int, float))
                 else "not recorded in this run's files"))
    free, seen = m.get("cells_free"), m.get("cells_observed")
    if isinstance(free, int) and isinstance(seen, int):
        rows.append(("cells observed", f"{seen} of {free} free cells "
                                       f"({seen / max(free, 1):.1%})"))
    rows += [(label, _number(m[key], fmt)) for key, label, fmt in _FIGURES if key in m]
    sweep = m.get("sweep_width")  # search theory's figures, when the run has them
    if isinstance(sweep, Mapping):
        rows += [(str(k).replace("_", " "), _number(v, "{:.4g}")) for k, v in sweep.items()
                 if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return tuple((str(k), str(v)) for k, v in rows)


def _figure(data: bytes | None, name: str, alt: str) -> tuple[Figure | None, str | None]:
    if data is None:
        return None, f"{name} is not in this run ({_NO_PLOTS})."
    return Figure(data, alt), None


def _map(run: RunFiles) -> Section:
    fig, missing = _figure(run.map_png, "map.png",
                           "P_D map with the tracks and the numbered pins")
    return Section("Map", figure=fig, missing=missing)


def _pins(run: RunFiles) -> Section:
    heading = "Pins (numbered as on the map, by p_person)"
    if run.detections is None:
        return Section(heading, missing="No detections.geojson: this run exported no "
                                        "detections (a log without detector boxes, or a pose "
                                        "CSV).")
    pins = candidates(run.detections)
    if not pins:
        return Section(heading, missing="No candidates in detections.geojson.")
    rows = []
    for f in pins:
        p = _props(f)
        lat, lon = _lon_lat(f)
        rows.append(tuple(str(v) for v in (
            p.get("rank", "-"), p.get("uid", "-"), _number(p.get("p_person", "-"), "{:.3f}"),
            f"detected {p.get('hits', '?')} of {p.get('looks', '?')} looks", lat, lon,
            p.get("mgrs") or "-", p.get("utm") or "-")))
    return Section(heading, table=Table(("pin", "uid", "p_person", "looks", "lat", "lon",
                                         "MGRS", "UTM"), tuple(rows), (0, 2, 4, 5)))


def _heat_map(run: RunFiles) -> Section:
    fig, missing = _figure(run.heatmap_png, "heatmap.png", "P_D heat map")
    return Section("Heat map", figure=fig, missing=missing)


def _thresholds(run: RunFiles) -> Section:
    heading = "Coverage by threshold"
    shares = run.metrics.get("proportion_at_or_above")
    fig, fig_missing = _figure(run.thresholds_png, "thresholds.png",
                               "proportion at or above P_D")
    if not isinstance(shares, Mapping) or not shares:
        return Section(heading, figure=fig, missing="metrics.json gives no thresholds.")
    return Section(heading, table=Table(
        ("P_D at or above", "proportion of free cells", "share"),
        tuple((str(t), f"{p:.4f}", f"{p:.1%}") for t, p in shares.items()), (1, 2)),
        figure=fig, missing=fig_missing)


def _limiting(m: Mapping[str, Any]) -> Section:
    heading = "Limiting factor of the free cells"
    cells = m.get("limiting_cells")
    if not isinstance(cells, Mapping):
        return Section(heading, missing=str(m.get("limiting_unknown")
                                            or "not known for this run"))
    return Section(heading, table=Table(("limiting factor", "free cells"), tuple(
        (str(k).replace("_", " "), str(n)) for k, n in cells.items()), (1,)))


def _gaps(caltopo: Mapping[str, Any] | None) -> Section:
    heading = "Gaps and re-fly proposal"
    if caltopo is None:
        return Section(heading, missing="No caltopo.geojson: no gaps exported for this run.")
    meta = caltopo.get("pdcov") or {}
    if "gaps_total" not in meta:
        return Section(heading, missing="caltopo.geojson holds no gaps (the gis extra was "
                                        "not installed when the run was written).")
    text = (f"{meta['gaps_total']} gap(s) below the target P_D {meta.get('target_pd', '?')}; "
            f"{meta.get('gaps_exported', '?')} exported.",)
    areas = [_props(f) for f in _features(caltopo) if _props(f).get("class") == "Assignment"]
    if not areas:
        return Section(heading, text=text, missing="No re-fly areas proposed.")
    with_pod = any("pod" in a for a in areas)
    rows = tuple((str(a.get("letter", "-")),
                  _number(a["area_m2"], "{:.0f}") if "area_m2" in a else "-",
                  str(a.get("description", "")),
                  *([_number(a.get("pod", "-"), "{:.2f}")] if with_pod else []))
                 for a in areas)
    header = ("letter", "area, m2", "description", *(("POD",) if with_pod else ()))
    return Section(heading, text=text, table=Table(header, rows, (1, 3)))


def _files(files: Sequence[tuple[str, int]]) -> Section:
    return Section("Handover package (the run's files)", table=Table(
        ("file", "bytes"), tuple((n, "" if s < 0 else f"{s:,}") for n, s in files), (1,)))


def handover(run: RunFiles) -> Handover:
    """The report of ``run``."""
    warnings = run.metrics.get("warnings")
    sections = [Section("Warnings", items=tuple(str(w) for w in warnings))] \
        if isinstance(warnings, list) and warnings else []
    sections += [_map(run), _pins(run), _heat_map(run), _thresholds(run),
                 _limiting(run.metrics), _gaps(run.caltopo), _files(run.files)]
    return Handover(title_of(run), _summary(run), tuple(sections))


def write_report(run_dir: str | Path, out_dir: str | Path) -> tuple[list[Path], str | None]:
    """``out_dir``/report.html and, with the plots extra, report.pdf of the run folder
    ``run_dir`` (out_dir created if needed): the paths written, and why report.pdf was not
    (None when it was). Raises InputFileError naming a file it cannot use, OutputError when
    it cannot write."""
    from pdcov.report.handover_html import handover_html

    run = read_run_files(run_dir)
    out = Path(out_dir)
    pdf_missing = PLOTS.message(f"{REPORT_PDF} needs")
    made = (REPORT_HTML,) if pdf_missing else (REPORT_HTML, REPORT_PDF)
    # The reports are part of the package they list (written into the run, or there
    # already), listed without a size: the same pages whichever was written first.
    others = tuple(f for f in run.files if f[0] not in made)
    if len(others) < len(run.files) or out.resolve() == Path(run_dir).resolve():
        run = replace(run, files=tuple(sorted((*others, *((name, -1) for name in made)))))
    report = handover(run)
    paths = [out / REPORT_HTML]
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(paths[0], handover_html(report))
        if pdf_missing is None:
            from pdcov.report.handover_pdf import write_handover_pdf

            paths.append(write_handover_pdf(out / REPORT_PDF, report))
    except OSError as exc:
        raise OutputError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    return paths, pdf_missing


def with_report(run: RunOutputs) -> RunOutputs:
    """Write the report into the run's folder, last (it lists the files written): ``run``
    with the reports among its files, and report.pdf among those not written when the
    plots extra is missing."""
    paths, pdf_missing = write_report(run.out_dir, run.out_dir)
    return replace(run, files=(*run.files, *(p.name for p in paths)),
                   not_written=run.not_written + ((f"{REPORT_PDF}: {pdf_missing}",)
                                                  if pdf_missing else ()))
