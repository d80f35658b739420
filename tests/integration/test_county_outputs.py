"""`pdcov evaluate` on a county (issue 37): the same short flight over a 200 x 200 m domain
and a 30 x 30 km one at 1 m (9 x 10^8 cells, the same south-west corner), each in a
process of its own. The county's outputs cover the extent its frames touched: its pd.tif
holds the small run's P_D on the same UTM pixels, its metrics are the whole
domain's, and its peak resident memory stays within 1.5x of the small run's
(docs/performance.md "County scale")."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr

from pdcov.cli import main
from pdcov.core.domain import GridGeometry
from tests.support.evaluate_inputs import (
    ORIGIN,
    expected_poses,
    known_flight,
    mission_doc,
    write_config,
    write_pose_csv,
)
from tests.support.utm_cells import pixel_cells

rasterio = pytest.importorskip("rasterio")

SMALL_M, COUNTY_M = 200, 30_000
MEMORY_RATIO = 1.5
# The child's own peak resident set (kB), printed after the run: VmHWM, not getrusage's
# ru_maxrss, which Linux carries across fork and exec from the parent (pytest's).
_RUN = ("import sys\nfrom pathlib import Path\nfrom pdcov.cli import main\n"
        "rc = main(sys.argv[1:])\n"
        "print(next(x for x in Path('/proc/self/status').read_text().splitlines()\n"
        "           if x.startswith('VmHWM:')))\n"
        "sys.exit(rc)\n")


def evaluate_square(tmp_path: Path, side_m: int, poses_csv: Path) -> tuple[Path, str, int]:
    """The run folder, stdout and peak resident memory (kB) of `pdcov evaluate` over a
    square domain of ``side_m`` from ENU (0, 0), 1 m cells, no obstacle."""
    doc = mission_doc()
    doc["domain"] = {"polygon_enu_m": [[0, 0], [side_m, 0], [side_m, side_m], [0, side_m]],
                     "cell_size_m": 1.0}
    folder = tmp_path / f"d{side_m}"
    folder.mkdir()
    out = folder / "run"
    proc = subprocess.run(
        [sys.executable, "-c", _RUN, "evaluate", "--config", str(write_config(folder, doc)),
         "--poses", str(poses_csv), "--out", str(out), "--no-progress"],
        capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    found = re.search(r"^VmHWM:\s+(\d+) kB$", proc.stdout, re.MULTILINE)
    assert found is not None, proc.stdout
    return out, proc.stdout, int(found.group(1))


def read_bands(run: Path, *names: str) -> tuple[dict[str, np.ndarray], object]:
    """The bands of the GeoTIFFs ``names`` in ``run`` by description, and their transform."""
    bands, transforms = {}, set()
    for name in names:
        with rasterio.open(run / name) as src:
            bands.update(zip(src.descriptions, src.read(), strict=True))
            transforms.add(src.transform)
    assert len(transforms) == 1
    return bands, transforms.pop()


def test_county_outputs_equal_the_small_domains_on_its_cells(tmp_path):
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None))
    small, _, small_kb = evaluate_square(tmp_path, SMALL_M, csv)
    county, county_out, county_kb = evaluate_square(tmp_path, COUNTY_M, csv)
    print(f"peak resident memory: {SMALL_M} m domain {small_kb / 1024:.0f} MB, "
          f"{COUNTY_M // 1000} km domain {county_kb / 1024:.0f} MB "
          f"({county_kb / small_kb:.2f}x)")

    for name in ("metrics.json", "pd.tif", "outline.geojson", "heatmap.png",
                 "thresholds.png", "pdcov.kmz"):
        assert (county / name).is_file() and (small / name).is_file(), name
    assert (small / "grid.npz").is_file() and not (county / "grid.npz").exists()
    assert main(["compare", str(county), "--out", str(tmp_path / "c.png")]) == 2

    # grid.zarr: the county's grid store holds the small run's grid on its cells, and
    # only the tiles the flight touched.
    store = zarr.open_group(str(county / "grid.zarr"), mode="r")
    with np.load(small / "grid.npz") as z:
        r0 = round((float(z["y0_m"]) - store.attrs["y0_m"]) / store.attrs["cell_size_m"])
        c0 = round((float(z["x0_m"]) - store.attrs["x0_m"]) / store.attrs["cell_size_m"])
        for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
            np.testing.assert_array_equal(
                store[key][r0:r0 + SMALL_M, c0:c0 + SMALL_M], z[key], err_msg=key)
    assert 0 < int(np.asarray(store["tiles"][...]).sum()) <= 4
    chunk_files = list((county / "grid.zarr").rglob("c/*/*"))
    assert 0 < len(chunk_files) <= 4 * 4

    # pd.tif: the county's holds the small run's values on the same georeferenced cells.
    a, ta = read_bands(small, "pd.tif", "looks.tif", "limiting.tif")
    b, tb = read_bands(county, "pd.tif", "looks.tif", "limiting.tif")
    extent = json.loads((county / "metrics.json").read_text())["extent"]
    assert [e[1] - e[0] for e in (extent["rows"], extent["cols"])] == [512, 512]  # the
    # touched tile grown by one, clipped at 0
    with rasterio.open(county / "pd.tif") as src:  # a Cloud-Optimised GeoTIFF
        assert src.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert src.block_shapes[0] == (256, 256) and src.overviews(1)
        assert src.profile["compress"] == "deflate"
    with rasterio.open(county / "pd_rgba_3857.tif") as src:  # as large as the overlay
        assert src.crs.to_epsg() == 3857 and max(src.shape) <= 2 * 512
    # Both on the zone's 1 m lattice: a pixel of the small raster over its cells is the
    # county's pixel at the same place (UTM m), holding the same cell's values.
    rows, cols = np.mgrid[0:a["pd"].shape[0], 0:a["pd"].shape[1]]
    x, y = rasterio.transform.xy(ta, rows, cols)  # the small raster's pixel centres (m)
    rb, cb = rasterio.transform.rowcol(tb, x, y)
    rb, cb = np.reshape(rb, rows.shape), np.reshape(cb, cols.shape)
    with np.load(small / "grid.npz") as z, rasterio.open(small / "pd.tif") as src:
        geometry = GridGeometry(float(z["x0_m"]), float(z["y0_m"]), float(z["cell_size_m"]),
                                *z["mask"].shape)
        over = pixel_cells(src, geometry, ORIGIN).clear.reshape(rows.shape)  # not on an edge
    assert over.sum() > 0.95 * SMALL_M**2 and np.isfinite(a["pd"][over]).all()
    for band in ("pd", "pfa", "n_obs", "limiting"):
        np.testing.assert_array_equal(b[band][rb, cb][over], a[band][over], err_msg=band)
    assert np.nanmax(a["pd"]) > 0.5

    # metrics.json: the whole domain's; proportions scale by the free cells.
    ma = json.loads((small / "metrics.json").read_text())
    mb = json.loads((county / "metrics.json").read_text())
    assert ma["cells_free"] == SMALL_M**2 and mb["cells_free"] == COUNTY_M**2
    assert mb["cells_observed"] == ma["cells_observed"] > 500
    scale = SMALL_M**2 / COUNTY_M**2
    for t, p in ma["proportion_at_or_above"].items():
        assert mb["proportion_at_or_above"][t] == pytest.approx(p * scale, rel=1e-12)
    assert mb["mean_pd"] == pytest.approx(ma["mean_pd"] * scale, rel=1e-9)
    assert mb["expected_false_alarms"] == pytest.approx(ma["expected_false_alarms"],
                                                        rel=1e-12)
    never = "never_in_view"
    assert (mb["limiting_cells"][never] - ma["limiting_cells"][never]
            == COUNTY_M**2 - SMALL_M**2)
    assert ma["extent"]["cropped"] is False and ma["extent"]["rows"] == [0, SMALL_M]
    assert mb["extent"]["cropped"] is True and mb["extent"]["rows"] == [0, 512]
    assert mb["extent"]["x_enu_m"] == [0.0, 512.0] and mb["extent"]["cols"] == [0, 512]

    assert county_kb <= MEMORY_RATIO * small_kb, (small_kb, county_kb)
