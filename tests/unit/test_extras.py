"""Installs that fit where they run (pdcov/extras.py): without an extra's modules,
``pdcov evaluate`` still writes its numbers and names what it did not write and the extra
that would; ``pdcov watch``, ``pdcov demo`` and a GeoTIFF prior exit 2 with one line naming
the extra; pyproject.toml's extras install what extras.py says they do. A module is made
missing by setting it to None in sys.modules, which makes its import fail as when it is not
installed."""

from __future__ import annotations

import re
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from pdcov.cli import main
from pdcov.extras import (
    CLUSTER,
    COT,
    DEMO,
    GIS,
    GPX,
    GRID_REFERENCES,
    GROUND,
    PLOTS,
    ROUTING,
    SITL,
    Extra,
)

tomllib = pytest.importorskip("tomllib")  # Python 3.11
ROOT = Path(__file__).resolve().parents[2]
POSES = Path(__file__).resolve().parents[1] / "data" / "poses_nadir_10m.csv"
MISSION = str(resources.files("pdcov") / "data" / "demo_mission.yaml")


def without(monkeypatch: pytest.MonkeyPatch, *modules: str) -> None:
    for m in modules:
        monkeypatch.setitem(sys.modules, m, None)


def evaluate(out: Path, *more: str) -> int:
    return main(["evaluate", "--config", MISSION, "--poses", str(POSES), "--out", str(out),
                 "--no-progress", *more])


def test_evaluate_without_plots_and_gis_writes_the_numbers_and_says_what_is_missing(
        tmp_path, monkeypatch, capsys):
    without(monkeypatch, "matplotlib", "rasterio", "gpxpy", "mgrs")
    assert evaluate(tmp_path / "run") == 0
    out = capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "run").glob("[!.]*")) == [
        "caltopo.geojson", "detections.geojson", "grid.npz", "metrics.json", "pdcov.kml",
        "pin_candidate.png", "pin_detection.png", "report.html"]
    assert ("wrote metrics.json, grid.npz, detections.geojson, caltopo.geojson, "
            "pin_candidate.png, pin_detection.png, pdcov.kml, report.html in") in out
    assert ("not written: caltopo.geojson, pdcov.kml without outlines: P_D outlines, gaps "
            "and re-fly areas need rasterio: pip install 'pdcov[gis]'") in out
    assert ("not written: pd_overlay.png, pdcov.kmz, pdcov_atak.zip: the P_D overlay needs "
            "matplotlib: pip install 'pdcov[plots]'") in out
    assert ("not written: heatmap.png, thresholds.png, map.png: figures need matplotlib: "
            "pip install 'pdcov[plots]'") in out
    assert "not written: report.pdf: report.pdf needs matplotlib: pip install " \
        "'pdcov[plots]'" in out
    assert ("not written: pd.tif, looks.tif, limiting.tif, outline.geojson, "
            "pd_rgba_3857.tif: GeoTIFF and GeoJSON outputs need rasterio: "
            "pip install 'pdcov[gis]'") in out
    assert "not written: pdcov.gpx: the GPX export needs gpxpy: pip install 'pdcov[gis]'" \
        in out
    assert "mgrs" not in out  # no pin, so no reference missing


def test_the_grid_does_not_depend_on_the_extras(tmp_path, monkeypatch, capsys):
    assert evaluate(tmp_path / "all") == 0
    assert {"heatmap.png", "thresholds.png", "pd.tif", "outline.geojson"} <= {
        p.name for p in (tmp_path / "all").iterdir()}
    assert "not written" not in capsys.readouterr().out
    without(monkeypatch, "matplotlib", "rasterio")
    assert evaluate(tmp_path / "base") == 0
    with np.load(tmp_path / "all" / "grid.npz") as a, np.load(tmp_path / "base" / "grid.npz") as b:
        assert a.files == b.files
        assert all(np.array_equal(a[k], b[k]) for k in a.files)
    assert (tmp_path / "all" / "metrics.json").read_text() == \
        (tmp_path / "base" / "metrics.json").read_text()


def test_a_geotiff_prior_without_gis_names_the_extra(tmp_path, monkeypatch, capsys):
    prior = tmp_path / "prior.tif"
    prior.write_bytes(b"not read")
    without(monkeypatch, "rasterio")
    assert evaluate(tmp_path / "run", "--prior", str(prior)) == 2
    err = capsys.readouterr().err
    assert "a GeoTIFF prior needs rasterio: pip install 'pdcov[gis]'" in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(("argv", "missing", "line"), [
    (["watch", "--once"], ("rich",), "pdcov watch needs rich: pip install 'pdcov[ground]'"),
    (["watch", "--plain"], ("rich", "aiohttp"),
     "pdcov watch needs rich and aiohttp: pip install 'pdcov[ground]'"),
    (["demo", "--out", "OUT"], ("jsbsim",), "pdcov demo needs jsbsim: pip install 'pdcov[demo]'"),
])
def test_a_command_without_its_extra_exits_2_in_one_line(argv, missing, line, tmp_path,
                                                        monkeypatch, capsys):
    without(monkeypatch, *missing)
    assert main([a.replace("OUT", str(tmp_path / "demo")) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(line) and len(err.splitlines()) == 1, err
    assert not (tmp_path / "demo").exists()


def test_message_lists_every_missing_module(monkeypatch):
    extra = Extra("x", ("json", "nope_a", "nope_b", "nope_c"), "this needs")
    assert extra.missing() == ("nope_a", "nope_b", "nope_c")
    assert extra.message() == "this needs nope_a, nope_b and nope_c: pip install 'pdcov[x]'"
    assert Extra("x", ("json",), "this needs").message() is None


def _requirements(extras: dict[str, list[str]], name: str) -> set[str]:
    """Distribution names an extra installs, through pdcov[...] references."""
    names: set[str] = set()
    for req in extras[name]:
        m = re.match(r"([A-Za-z0-9_.-]+)(\[([^\]]+)\])?", req)
        assert m is not None, req
        if m.group(1) == "pdcov":
            for inner in m.group(3).split(","):
                names |= _requirements(extras, inner.strip())
        else:
            names.add(m.group(1).lower())
    return names


def test_pyproject_extras_install_what_extras_py_names():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    base = {re.match(r"[A-Za-z0-9_.-]+", r).group(0).lower() for r in project["dependencies"]}
    for extra in (PLOTS, GIS, GPX, GRID_REFERENCES, GROUND, COT, SITL, DEMO, ROUTING, CLUSTER):
        installs = _requirements(extras, extra.name)
        assert set(extra.modules) <= installs, extra.name  # module and distribution alike
        assert not set(extra.modules) & base, extra.name  # the companion computer's install
    assert set(DEMO.modules) <= _requirements(extras, "test")
    # .ci/run installs .[test]: the exports' readers in the tests need these
    assert set(GPX.modules + GRID_REFERENCES.modules + COT.modules) <= _requirements(
        extras, "test")
    assert set(ROUTING.modules) <= _requirements(extras, "test")
    assert set(CLUSTER.modules) <= _requirements(extras, "test")


def test_vantage_plans_without_ortools_exit_2_naming_the_routing_extra(tmp_path, monkeypatch,
                                                                      capsys):
    without(monkeypatch, "ortools")
    assert main(["plan", "--config", MISSION, "--pattern", "vantage", "--target-pd", "0.8",
                 "--out", str(tmp_path / "plan")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("pdcov plan --pattern vantage needs ortools: "
                        "pip install 'pdcov[routing]'"), err
    assert not (tmp_path / "plan").exists()


def test_the_simulator_without_jsbsim_exits_2_naming_the_sitl_extra(tmp_path, monkeypatch,
                                                                     capsys):
    from pdcov_sitl.cli import main as sitl_main

    without(monkeypatch, "jsbsim")
    assert sitl_main(["fly", "--config", MISSION, "--plan", str(tmp_path / "p.plan"),
                      "--out", str(tmp_path / "sim")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("the simulator needs jsbsim: pip install 'pdcov[sitl]'"), err


def test_without_plots_the_rgba_geotiff_is_named_and_the_grid_geotiffs_written(
        tmp_path, monkeypatch, capsys):
    without(monkeypatch, "matplotlib")
    assert evaluate(tmp_path / "run") == 0
    assert ("not written: pd_rgba_3857.tif: the RGBA GeoTIFF needs matplotlib: "
            "pip install 'pdcov[plots]'") in capsys.readouterr().out
    assert {"pd.tif", "looks.tif", "limiting.tif"} <= {p.name for p in (tmp_path / "run").iterdir()}
    assert not (tmp_path / "run" / "pd_rgba_3857.tif").exists()
