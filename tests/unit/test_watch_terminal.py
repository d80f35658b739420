"""`pdcov watch`'s terminal view fits 80 columns, ASCII only, with no share cut short."""

from __future__ import annotations

import io

from rich.console import Console

from pdcov.ground.fleet_report import FleetReport, VehicleReport
from pdcov.ground.terminal import MAX_ID_SHOWN, render


def report(thresholds: tuple[float, ...]) -> FleetReport:
    """Three vehicles with the widest figures a flight gives: 100.0% shares, six-digit
    frame counts, the longest link state and an id of MAX_ID_SHOWN characters."""
    shares = {t: 1.0 - 0.1 * i for i, t in enumerate(thresholds)}
    vehicles = tuple(
        VehicleReport(vid, True, ready, thresholds, shares, 0.456, 123_456, 6_789, link,
                      75.5, {}, 0, 1, 0, candidates=123)
        for vid, ready, link in (("s" * MAX_ID_SHOWN, True, "connected"),
                                 ("uav2", False, "connecting"), ("u3", True, "")))
    return FleetReport(vehicles, tuple(v.vehicle_id for v in vehicles), thresholds,
                       max(thresholds), dict.fromkeys(thresholds, 0.5), 0.45, 100_000)


def text_at(width: int, thresholds: tuple[float, ...]) -> list[str]:
    console = Console(width=width, file=io.StringIO(), record=True, no_color=True)
    console.print(render(report(thresholds)))
    return console.export_text().splitlines()


def table_rows(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("|")]


def test_the_vehicle_table_fits_80_columns_with_every_share_whole():
    lines = text_at(80, (0.5, 0.7, 0.8))
    assert max(len(line) for line in lines) <= 80
    assert all(line.isascii() for line in lines)
    rows = table_rows(lines)
    assert rows[0].split("|")[1:-1] == ["vehicle" + " " * (MAX_ID_SHOWN - 7), " >=0.5",
                                        ">=0.7", ">=0.8", " mean", "frames", "skip", "cand",
                                        "link      ", "  age"]
    assert rows[2].split("|")[1:-1] == ["s" * MAX_ID_SHOWN, "100.0%", "90.0%", "80.0%",
                                        "0.456", "123456", "6789", " 123", "connected ",
                                        "1 min"]
    assert rows[3].startswith("|uav2* ") and "connecting" in rows[3]


def test_more_thresholds_than_fit_keep_the_target_and_say_which_are_left_out():
    thresholds = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95)
    lines = text_at(80, thresholds)
    assert max(len(line) for line in lines) <= 80
    header = table_rows(lines)[0]
    assert ">=0.95" in header and ">=0.9|" in header and ">=0.5|" not in header
    assert "per vehicle, not shown (the terminal is too narrow): >=0.5, >=0.6, >=0.7" \
        in lines
    wide = text_at(120, thresholds)
    assert all(f">={t:g}|" in table_rows(wide)[0] for t in thresholds)
    assert not any("not shown" in line for line in wide)
