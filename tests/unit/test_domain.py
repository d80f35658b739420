"""Search domain, cells and free-space mask."""

import json

import numpy as np
import pytest

from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.errors import DomainError


def test_grid_aligned_to_bounding_box_and_mask():
    dom = Domain.from_enu([[0, 0], [10, 0], [10, 5], [0, 5]], [[[2, 2], [4, 2], [4, 4], [2, 4]]])
    g = dom.grid_geometry(1.0)
    assert (g.x0_m, g.y0_m, g.n_rows, g.n_cols) == (0, 0, 5, 10)
    mask = dom.free_mask(g)
    assert mask.sum() == 50 - 4
    assert not mask[2, 2] and not mask[3, 3] and mask[2, 4] and mask[0, 0]
    # rows grow north, columns east
    assert g.cell_of(9.5, 0.5) == (0, 9)
    assert g.cell_of(0.5, 4.5) == (4, 0)


def test_partial_cells_at_the_edge():
    dom = Domain.from_enu([[0, 0], [10.4, 0], [10.4, 3], [0, 3]])
    g = dom.grid_geometry(1.0)
    assert g.n_cols == 11
    assert dom.free_mask(g)[:, 10].sum() == 0  # centre 10.5 lies outside


def test_geodetic_and_geojson_agree(tmp_path):
    origin = Origin(-35.36, 149.16, 584.0)
    ring_enu = np.array([[0, 0], [40, 0], [40, 30], [0, 30.0]])
    lla = enu_to_geodetic(np.c_[ring_enu, np.zeros(4)], origin)
    dom_geo = Domain.from_geodetic(lla[:, :2].tolist(), [], origin)
    np.testing.assert_allclose(np.array(dom_geo.boundary.exterior.coords)[:4], ring_enu,
                               atol=1e-6)
    gj = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {},
          "geometry": {"type": "Polygon",
                       "coordinates": [[[lon, lat] for lat, lon, _ in lla] + [[lla[0][1],
                                                                               lla[0][0]]]]}}]}
    path = tmp_path / "area.geojson"
    path.write_text(json.dumps(gj))
    dom_gj = Domain.from_geojson(path, origin)
    assert dom_gj.boundary.area == pytest.approx(1200.0, rel=1e-6)


@pytest.mark.parametrize("ring", [[[0, 0], [1, 1]], [[0, 0], [1, 1], [1, 0], [0, 1]],
                                  [[0, 0], [1, "a"], [2, 0]], [[0, 0], [1, float("nan")], [2, 0]]])
def test_bad_polygon(ring):
    with pytest.raises(DomainError, match="domain.polygon_enu_m"):
        Domain.from_enu(ring, source="m.yaml")


def test_bad_geojson(tmp_path):
    p = tmp_path / "x.geojson"
    p.write_text("{not json")
    with pytest.raises(DomainError, match="not valid JSON"):
        Domain.from_geojson(p, Origin(0, 0))
    p.write_text(json.dumps({"type": "Point", "coordinates": [1, 2]}))
    with pytest.raises(DomainError, match="no Polygon"):
        Domain.from_geojson(p, Origin(0, 0))
