"""Whole `pdcov evaluate` runs with a DEM: the terrain check's finding in the summary and
metrics, and a DEM off the home refused with nothing written."""

from __future__ import annotations

import json
from pathlib import Path

from pdcov.telemetry.terrain_check import TerrainCheck


class FlatDem:
    """Ground at ``alt_msl_m`` everywhere."""

    def __init__(self, alt_msl_m: float) -> None:
        self.alt_msl_m = alt_msl_m

    def height_msl_m(self, lat_deg, lon_deg):
        import numpy as np
        return np.full(np.shape(lat_deg), self.alt_msl_m)


def test_evaluate_says_it_in_the_summary_and_metrics(tmp_path: Path, monkeypatch, capsys
                                                      ) -> None:
    import pdcov.telemetry.terrain_check as terrain_check
    from tests.support.evaluate_inputs import ORIGIN, known_flight, mission_doc, run, write_config
    from tests.support.mavlink_fixtures import samples_from_flight, write_tlog

    dem = FlatDem(ORIGIN.ground_alt_msl_m + 12.0)  # the home is 12 m below it
    monkeypatch.setattr(terrain_check, "terrain_check_for", lambda mission: TerrainCheck(dem))
    tlog = write_tlog(tmp_path / "flight.tlog", samples_from_flight(known_flight()))
    config = write_config(tmp_path, mission_doc())
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out",
               str(tmp_path / "run"), "--no-progress") == 0
    out, err = capsys.readouterr()
    line = ("terrain check: 1 of 1 measurements (1 home) disagree with the DEM by more than "
            "10 m, largest +12.0 m (home at 39.350000, -76.330000")
    assert line in out and line in err
    doc = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert doc["terrain_check"]["checked"] == {"terrain_report": 0, "rangefinder": 0,
                                               "home": 1}
    assert doc["terrain_check"]["largest"]["difference_m"] == 12.0
    assert any(w.startswith("terrain check: 1 of 1") for w in doc["warnings"])


def test_evaluate_refuses_a_dem_off_the_home_and_writes_nothing(tmp_path: Path, monkeypatch,
                                                                capsys) -> None:
    import pdcov.telemetry.terrain_check as terrain_check
    from tests.support.evaluate_inputs import ORIGIN, known_flight, mission_doc, run, write_config
    from tests.support.mavlink_fixtures import samples_from_flight, write_tlog

    dem = FlatDem(ORIGIN.ground_alt_msl_m + 188.0)
    monkeypatch.setattr(terrain_check, "terrain_check_for",
                        lambda mission: TerrainCheck(dem, max_home_offset_m=30.0))
    tlog = write_tlog(tmp_path / "flight.tlog", samples_from_flight(known_flight()))
    config = write_config(tmp_path, mission_doc())
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out",
               str(tmp_path / "run"), "--no-progress") == 2
    _out, err = capsys.readouterr()
    assert "-188.0 m from the DEM" in err and "raise terrain.max_home_offset_m" in err
    assert not (tmp_path / "run" / "metrics.json").exists()
