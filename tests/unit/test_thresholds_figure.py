"""thresholds.png: the configured thresholds' shares are each labelled once, and no two
labels overlap, however close their markers (read back from the drawn figure)."""

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
