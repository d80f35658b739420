"""The terminal view of a FleetReport (rich): the fleet's coverage at the target threshold
in large type, then one row per vehicle. ASCII only (box and large digits), so that it
reads the same in a plain 80-column terminal, over SSH and in a log file."""

from __future__ import annotations

import io
from typing import Any

from pdcov.bus.detections import LIKELY_P_PERSON
from pdcov.ground.fleet_report import FleetReport, VehicleReport

# 5-row glyphs for the large coverage figure, '#' on ' '.
_BIG = {
    "0": ("###", "# #", "# #", "# #", "###"), "1": (" # ", "## ", " # ", " # ", "###"),
    "2": ("###", "  #", "###", "#  ", "###"), "3": ("###", "  #", "###", "  #", "###"),
    "4": ("# #", "# #", "###", "  #", "  #"), "5": ("###", "#  ", "###", "  #", "###"),
    "6": ("###", "#  ", "###", "# #", "###"), "7": ("###", "  #", "  #", "  #", "  #"),
    "8": ("###", "# #", "###", "# #", "###"), "9": ("###", "# #", "###", "  #", "###"),
    ".": ("   ", "   ", "   ", "   ", " # "), "%": ("# #", "  #", " # ", "#  ", "# #"),
    "-": ("   ", "   ", "###", "   ", "   "), " ": ("   ",) * 5,
}


def big_text(text: str) -> str:
    """``text`` (digits, '.', '%', '-', ' ') in 5-row ASCII glyphs."""
    return "\n".join(" ".join(_BIG.get(ch, _BIG[" "])[row] for ch in text)
                     for row in range(5))


def percent(share: float | None) -> str:
    return "-" if share is None else f"{100.0 * share:.1f}%"


def _age(age_s: float | None) -> str:
    if age_s is None:
        return "-"
    return f"{age_s:.1f} s" if age_s < 60 else f"{age_s / 60:.0f} min"


def _link(v: VehicleReport) -> str:
    if v.alive is False:
        return "GONE"
    return v.link or ("alive" if v.alive else "?")


def headline(report: FleetReport) -> str:
    """One line: the fleet's share of free cells at or above the target P_D."""
    t = report.target
    if t is None or not report.merged:
        return "waiting for a vehicle's status and grid ..."
    share = report.proportion_at_or_above.get(t)
    who = ", ".join(report.merged)
    return (f"coverage {percent(share)} of free cells at P_D >= {t:g} "
            f"({len(report.merged)} vehicle{'s' if len(report.merged) > 1 else ''}: {who})")


def candidate_lines(report: FleetReport) -> list[str]:
    """One line per vehicle with detection candidates (pins): how many, how many likely,
    and the most probable one (its uid and p_person)."""
    return [f"pins {v.vehicle_id}: {v.candidates}, {v.candidates_likely} with p_person >= "
            f"{LIKELY_P_PERSON:g} (most probable: {v.best_candidate})"
            for v in report.vehicles if v.candidates]


MAX_ID_SHOWN = 16
"""Characters of a vehicle id on one line of the table."""


def render(report: FleetReport) -> Any:
    """A rich renderable of the whole report."""
    from rich.console import Group
    from rich.text import Text

    parts: list[Any] = [Text(headline(report), style="bold")]
    t = report.target
    if t is not None and report.merged:
        parts.append(Text(big_text(percent(report.proportion_at_or_above.get(t))),
                          style="bold green"))
        parts.append(Text("fleet: " + "  ".join(
            f">={th:g} {percent(p)}" for th, p in report.proportion_at_or_above.items())
            + (f"  mean P_D {report.mean_pd:.3f}" if report.mean_pd is not None else "")
            + f"  free cells {report.cells_free}"))
    parts.append(VehicleTable(report))
    if any(not v.grid_ready for v in report.vehicles):
        parts.append(Text("* grid not yet received: figures from its status"))
    parts += [Text(line) for line in candidate_lines(report)]
    parts += [Text(line, style="dim") for line in report.notes]
    parts += [Text(f"! {line}", style="bold yellow") for line in report.warnings]
    return Group(*parts)


class VehicleTable:
    """One row per vehicle, as wide as the console allows and never cut: a column per
    threshold while they fit, else the target's and the highest others that do (those left
    out named under it). Columns are split by '|' with no padding: at 80 columns the
    target and two other thresholds fit beside an id of MAX_ID_SHOWN characters (a longer
    one folds onto a second line)."""

    def __init__(self, report: FleetReport) -> None:
        self.report = report

    def __rich_console__(self, console: Any, options: Any) -> Any:
        from rich.text import Text

        r = self.report
        shown = list(r.thresholds)
        table = self._table(shown)
        natural = options.update_width(1 << 16)  # measured at the width it wants, not cut
        while console.measure(table, options=natural).maximum > options.max_width:
            others = [th for th in shown if th != r.target]
            if not others:
                break
            shown.remove(min(others))
            table = self._table(shown)
        yield table
        left_out = [th for th in r.thresholds if th not in shown]
        if left_out:
            yield Text("per vehicle, not shown (the terminal is too narrow): "
                       + ", ".join(f">={th:g}" for th in left_out), style="dim")

    def _table(self, thresholds: list[float]) -> Any:
        from rich import box
        from rich.table import Table

        r = self.report
        table = Table(box=box.ASCII, padding=(0, 0), expand=False)
        table.add_column("vehicle", max_width=MAX_ID_SHOWN, overflow="fold")
        for th in thresholds:
            table.add_column(f">={th:g}", justify="right", no_wrap=True,
                             style="bold" if th == r.target else "")
        for name in ("mean", "frames", "skip", "cand", "link", "age"):
            table.add_column(name, justify="left" if name == "link" else "right",
                             no_wrap=True)
        for v in r.vehicles:
            table.add_row(
                v.vehicle_id + ("" if v.grid_ready else "*"),
                *(percent(v.proportion_at_or_above.get(th)) for th in thresholds),
                "-" if v.mean_pd is None else f"{v.mean_pd:.3f}",
                "-" if v.frames_used is None else str(v.frames_used),
                "-" if v.frames_skipped is None else str(v.frames_skipped),
                str(v.candidates), _link(v), _age(v.age_s))
        return table


def plain_lines(report: FleetReport) -> list[str]:
    """The report as plain text lines (for --once and non-terminal output)."""
    from rich.console import Console

    console = Console(width=80, no_color=True, force_terminal=False, record=True,
                      file=io.StringIO())
    console.print(render(report))
    return console.export_text().rstrip("\n").split("\n")
