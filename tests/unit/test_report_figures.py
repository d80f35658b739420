"""thresholds.png: the configured thresholds' shares are each labelled once, and no two
labels overlap, however close their markers (read back from the drawn figure); heatmap.png:
the latitude and longitude lines of the origin's place, exact (pymap3d)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")
from matplotlib.text import Text

import pdcov.report.plots as plots


def drawn_labels(tmp_path, monkeypatch, shares):
    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: figures.append(fig))
    t = np.linspace(0.0, 1.0, 101)
    plots.thresholds_figure(tmp_path / "t.png", (t, 1.0 - 0.55 * t), shares, title="x")
    (fig,) = figures
    fig.canvas.draw()  # the Agg renderer lays out the text
    renderer = fig.canvas.get_renderer()
    texts = [a for a in fig.findobj(Text) if " at " in a.get_text()
             and "proportion" not in a.get_text()]
    boxes = [a.get_window_extent(renderer) for a in texts]
    plots.pyplot().close(fig)
    return [a.get_text() for a in texts], boxes


def test_labels_of_close_thresholds_with_similar_shares_do_not_overlap(tmp_path,
                                                                       monkeypatch):
    texts, boxes = drawn_labels(tmp_path, monkeypatch, {0.5: 0.4539, 0.7: 0.447, 0.8: 0.445})
    assert sorted(t.split(" at ")[0] for t in texts) == ["0.445", "0.447", "0.454"]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not boxes[i].overlaps(boxes[j]), (texts[i], texts[j])


def test_heatmap_has_the_latitude_and_longitude_lines(tmp_path, monkeypatch):
    import pymap3d
    from matplotlib.contour import ContourSet
    from shapely.geometry import box

    from pdcov.core.domain import Domain, GridGeometry
    from pdcov.core.geodesy import Origin

    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: figures.append(fig))
    geometry = GridGeometry(-60.0, -60.0, 1.0, 40, 40)
    origin = Origin(39.35, -76.33, 5.0)
    pd = np.full(geometry.shape, 0.5)
    plots.heatmap_figure(tmp_path / "h.png", pd, np.ones(geometry.shape, bool), geometry,
                         Domain(box(-60.0, -60.0, -20.0, -20.0)), title="x", origin=origin)
    (fig,) = figures
    fig.canvas.draw()
    ax = fig.axes[0]
    contours = [c for c in ax.get_children() if isinstance(c, ContourSet)]
    labels = [t.get_text() for t in ax.texts]
    plots.pyplot().close(fig)
    assert len(contours) == 2  # latitude, longitude
    lat_levels, lon_levels = (list(c.levels) for c in contours)
    assert lat_levels and lon_levels
    assert any(t.endswith("°N") for t in labels) and any(t.endswith("°W") for t in labels)
    # Each latitude line passes where pymap3d puts that latitude over the domain.
    for lat in lat_levels:
        _, n, _ = pymap3d.geodetic2enu(lat, -76.3305, 5.0, origin.lat_deg, origin.lon_deg,
                                       origin.ground_alt_msl_m)
        assert -62.0 <= n <= -18.0  # within the drawn extent
    assert ax.get_xlabel() == "east of the origin (m)"
