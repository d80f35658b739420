"""The handover report, ``report.html`` (docs/outputs.md "Handover report"): one
self-contained page for the search manager built from a run folder's files
(report/run_files.py), never from the grid. No reference leaves the file: the figures are
inline ``data:`` URIs, the style is inline, there is no script, and a Content-Security-Policy
forbids any load but those. Every string from a file is escaped (``html.escape``)."""

from __future__ import annotations

import base64
import html
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from pdcov.atomic import write_text_atomic
from pdcov.errors import OutputError
from pdcov.report.run_files import PNG_SIGNATURE, RunFiles, read_run_files

REPORT_HTML = "report.html"
_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"
_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 60em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: left; }
td.n { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; height: auto; }
p.missing { color: #8a6d3b; font-style: italic; }
"""
_FIGURES = (("mean_pd", "mean P_D of the free cells", "{:.3f}"),
            ("expected_false_alarms", "expected false alarms", "{:.2f}"),
            ("probability_of_success", "probability of success (POS)", "{:.3f}"),
            ("prior_mass_in_grid", "prior mass in the grid", "{:.3f}"),
            ("sweep_width_m", "effective sweep width", "{:.1f} m"))
"""metrics.json's figures the report shows, each only when its key is there."""


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _table(header: Sequence[str], rows: Iterable[Sequence[Any]], numeric: Sequence[int] = ()
           ) -> str:
    """A table of escaped cells; columns ``numeric`` right-aligned."""
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(
        f'<td class="n">{_e(c)}</td>' if i in numeric else f"<td>{_e(c)}</td>"
        for i, c in enumerate(row)) + "</tr>\n" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>\n{body}</tbody></table>\n"


def _missing(text: str) -> str:
    return f'<p class="missing">{_e(text)}</p>\n'


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG from its IHDR chunk."""
    if not data.startswith(PNG_SIGNATURE) or len(data) < 24:
        raise ValueError("not a PNG")
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


def _image(data: bytes | None, name: str, alt: str, why_missing: str) -> str:
    if data is None:
        return _missing(f"{name} is not in this run ({why_missing}).")
    w, h = png_size(data)
    uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
    return f'<p><img src="{uri}" width="{w}" height="{h}" alt="{_e(alt)}"></p>\n'


def _number(value: Any, fmt: str) -> str:
    return fmt.format(value) if isinstance(value, (int, float)) else str(value)


def _features(doc: Mapping[str, Any] | None) -> list[Mapping[str, Any]]:
    feats = (doc or {}).get("features")
    return [f for f in feats if isinstance(f, Mapping)] if isinstance(feats, list) else []


def _props(feature: Mapping[str, Any]) -> Mapping[str, Any]:
    p = feature.get("properties")
    return p if isinstance(p, Mapping) else {}


def candidates(detections: Mapping[str, Any] | None) -> list[Mapping[str, Any]]:
    """detections.geojson's candidates, by p_person descending (none known last)."""
    feats = [f for f in _features(detections) if _props(f).get("kind") == "candidate"]

    def key(f: Mapping[str, Any]) -> float:
        p = _props(f).get("p_person")
        return -float(p) if isinstance(p, (int, float)) else float("inf")
    return sorted(feats, key=key)


def _lon_lat(feature: Mapping[str, Any]) -> tuple[str, str]:
    coords = (feature.get("geometry") or {}).get("coordinates") or []
    if len(coords) >= 2 and all(isinstance(v, (int, float)) for v in coords[:2]):
        return f"{coords[1]:.7f}", f"{coords[0]:.7f}"
    return "-", "-"


def _summary(run: RunFiles) -> str:
    m = run.metrics
    title = ((run.caltopo or {}).get("pdcov") or {}).get("title") or run.name
    fleet = m.get("vehicles")  # a watch --record fleet's metrics.json
    vehicles = sorted({str(_props(f)["vehicle"]) for f in _features(run.detections)
                       if "vehicle" in _props(f)})
    rows: list[tuple[str, Any]] = [("run", title)]
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
    warnings = m.get("warnings")
    body = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>\n" for k, v in rows)
    out = f"<h1>pdcov handover: {_e(title)}</h1>\n<table>\n{body}</table>\n"
    if isinstance(warnings, list) and warnings:
        out += "<h2>Warnings</h2>\n<ul>" + "".join(f"<li>{_e(w)}</li>" for w in warnings) \
            + "</ul>\n"
    return out


def _thresholds(m: Mapping[str, Any]) -> str:
    shares = m.get("proportion_at_or_above")
    out = "<h2>Coverage by threshold</h2>\n"
    if not isinstance(shares, Mapping) or not shares:
        return out + _missing("metrics.json gives no thresholds.")
    return out + _table(("P_D at or above", "proportion of free cells", "share"),
                        ((t, f"{p:.4f}", f"{p:.1%}") for t, p in shares.items()), (1, 2))


def _limiting(m: Mapping[str, Any]) -> str:
    out = "<h2>Limiting factor of the free cells</h2>\n"
    cells = m.get("limiting_cells")
    if not isinstance(cells, Mapping):
        return out + _missing(str(m.get("limiting_unknown") or "not known for this run"))
    return out + _table(("limiting factor", "free cells"),
                        ((str(k).replace("_", " "), n) for k, n in cells.items()), (1,))


def _pins(run: RunFiles) -> str:
    out = "<h2>Pins (candidates by p_person)</h2>\n"
    if run.detections is None:
        return out + _missing("No detections.geojson: this run exported no detections "
                              "(a log without detector boxes, or a pose CSV).")
    pins = candidates(run.detections)
    if not pins:
        return out + _missing("No candidates in detections.geojson.")
    rows = []
    for f in pins:
        p = _props(f)
        lat, lon = _lon_lat(f)
        rows.append((p.get("uid", "-"), _number(p.get("p_person", "-"), "{:.3f}"),
                     f"detected {p.get('hits', '?')} of {p.get('looks', '?')} looks", lat, lon,
                     p.get("mgrs") or "-", p.get("utm") or "-"))
    return out + _table(("uid", "p_person", "looks", "lat", "lon", "MGRS", "UTM"), rows,
                        (1, 3, 4))


def _gaps(caltopo: Mapping[str, Any] | None) -> str:
    out = "<h2>Gaps and re-fly proposal</h2>\n"
    if caltopo is None:
        return out + _missing("No caltopo.geojson: no gaps exported for this run.")
    meta = caltopo.get("pdcov") or {}
    if "gaps_total" not in meta:
        return out + _missing("caltopo.geojson holds no gaps (the gis extra was not "
                              "installed when the run was written).")
    out += (f"<p>{_e(meta['gaps_total'])} gap(s) below the target P_D "
            f"{_e(meta.get('target_pd', '?'))}; {_e(meta.get('gaps_exported', '?'))} "
            "exported.</p>\n")
    areas = [_props(f) for f in _features(caltopo) if _props(f).get("class") == "Assignment"]
    if not areas:
        return out + _missing("No re-fly areas proposed.")
    with_pod = any("pod" in a for a in areas)
    rows = [(a.get("letter", "-"), _number(a["area_m2"], "{:.0f}") if "area_m2" in a else "-",
             a.get("description", ""), *([_number(a.get("pod", "-"), "{:.2f}")]
                                         if with_pod else [])) for a in areas]
    header = ("letter", "area, m2", "description", *(("POD",) if with_pod else ()))
    return out + _table(header, rows, (1, 3))


def _files(files: Sequence[tuple[str, int]]) -> str:
    return "<h2>Handover package (the run's files)</h2>\n" + _table(
        ("file", "bytes"), ((n, "" if s < 0 else f"{s:,}") for n, s in files), (1,))


def handover_html(run: RunFiles) -> str:
    """The report's page for ``run``."""
    parts = [_summary(run), "<h2>Heat map</h2>\n",
             _image(run.heatmap_png, "heatmap.png", "P_D heat map",
                    "the figures need the plots extra"),
             _thresholds(run.metrics),
             _image(run.thresholds_png, "thresholds.png", "proportion at or above P_D",
                    "the figures need the plots extra"),
             _limiting(run.metrics), _pins(run), _gaps(run.caltopo), _files(run.files)]
    title = ((run.caltopo or {}).get("pdcov") or {}).get("title") or run.name
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n"
            f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">\n'
            f"<title>pdcov handover: {_e(title)}</title>\n<style>{_STYLE}</style>\n"
            "</head><body>\n" + "".join(parts) + "</body></html>\n")


def write_report(run_dir: str | Path, out_dir: str | Path) -> Path:
    """``out_dir``/report.html of the run folder ``run_dir`` (out_dir created if needed);
    the path written. Raises InputFileError naming a file it cannot use, OutputError when
    it cannot write."""
    run = read_run_files(run_dir)
    out = Path(out_dir)
    path = out / REPORT_HTML
    # The report is part of the package it lists (written into the run, or there already),
    # listed without a size: the same page whichever was written first.
    others = tuple(f for f in run.files if f[0] != REPORT_HTML)
    if len(others) < len(run.files) or out.resolve() == Path(run_dir).resolve():
        run = replace(run, files=tuple(sorted((*others, (REPORT_HTML, -1)))))
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, handover_html(run))
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return path
