"""The detector figure stays readable: bins spanning 0 to 1e9 are not slivers, the "no data"
legend entry is a hatched box with an edge, and long titles and paths fit in the figure."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.core.detector import DetectorModel
from pdcov.core.detector_sections import BinCounts
from pdcov.detection.figures import detector_figure, plot_detector_model
from pdcov.detection.validation import BinTest, RateTest, ValidationReport

pytest.importorskip("matplotlib")


def model(edges, n_true=None) -> DetectorModel:
    n = len(edges) - 1
    counts = None
    if n_true is not None:
        counts = BinCounts(tuple(n_true), tuple(min(k, 1) for k in n_true), tuple(n_true))
    return DetectorModel(tuple(edges), (0.5,) * n, (0.1,) * n, counts=counts,
                         extra={"model": "binned", "interval_method": "wilson",
                                "p_detect_ci95": [[0.4, 0.6]] * n,
                                "p_false_alarm_ci95": [[0.05, 0.2]] * n})


def bar_shares(fig) -> np.ndarray:
    """Each drawn bar's width as a share of the axis width, in display units."""
    fig.canvas.draw()
    ax = fig.axes[0]
    width = ax.get_window_extent().width
    return np.array([p.get_window_extent().width / width for p in ax.patches])


@pytest.mark.parametrize("edges", [(0, 8, 16, 32, 64, 1e9), (1, 8, 16, 32, 64, 1e9),
                                   (4, 8, 16, 32, 64, 128)])
def test_no_bin_is_a_sliver(edges):
    shares = bar_shares(detector_figure(model(edges)))
    assert len(shares) == len(edges) - 1
    assert shares.min() > 0.04, shares


def test_edges_label_an_index_axis_when_the_range_is_huge():
    fig = detector_figure(model((0, 8, 16, 32, 64, 1e9)))
    fig.canvas.draw()
    labels = [t.get_text() for t in fig.axes[1].get_xticklabels()]
    assert labels == ["0", "8", "16", "32", "64", "1e+09"]


def test_no_data_legend_entry_is_a_visible_hatched_box():
    fig = detector_figure(model((4, 8, 16, 32), n_true=(10, 0, 5)))
    legend = fig.axes[0].get_legend()
    (handle,) = legend.legend_handles
    assert [t.get_text() for t in legend.get_texts()] == ["no data"]
    assert handle.get_hatch() and handle.get_linewidth() > 0
    assert handle.get_edgecolor()[3] > 0 and handle.get_facecolor()[3] > 0


def test_long_title_and_report_path_stay_inside_the_figure(tmp_path):
    m = model((4, 8, 16, 32))
    long_path = "/data/" + "/".join(f"level_{i:02d}_of_a_deep_tree" for i in range(12)) + \
        "/groundtruth_second_split.json"
    report = ValidationReport(m.bin_edges_px, tuple(BinTest(10, 3, 2.0, 0.2) for _ in range(3)),
                              tuple(BinTest(10, 3, 2.0, 0.2) for _ in range(3)), "binomial",
                              model={"ground_truth": long_path})
    fig = detector_figure(m, report, title="Detector YOLOv8m on " + "a long dataset name " * 10)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    fig_box = fig.bbox
    for text in (fig._suptitle, fig.axes[0].title, fig.axes[0]._left_title):
        if text.get_text():
            box = text.get_window_extent(renderer)
            assert box.x0 >= fig_box.x0 - 1 and box.x1 <= fig_box.x1 + 1, text.get_text()
    subtitle = fig.axes[0]._left_title.get_text()
    assert "groundtruth_second_split.json" in subtitle and "level_00" not in subtitle
    plot_detector_model(m, tmp_path / "f.png", report)
    assert (tmp_path / "f.png").stat().st_size > 10_000


def test_the_false_box_rate_is_drawn_beside_the_papers_precision():
    m = model((4, 8, 16, 32))
    m = DetectorModel(m.bin_edges_px, m.p_detect, m.p_false_alarm, (0.2, 0.6, 1.3),
                      extra={**m.extra, "fa_rate_per_mpx_ci95": [[0.1, 0.3], [0.4, 0.9],
                                                                  [1.0, 1.7]]})
    tests = tuple(BinTest(10, 3, 2.0, 0.2) for _ in range(3))
    report = ValidationReport(m.bin_edges_px, tests, tests, "binomial", fa_rate=(
        RateTest(4, 0.25, (0.07, 0.6), 3.2, 0.8), RateTest(30, 1.9, (1.3, 2.7), 9.6, 1e-6),
        RateTest(0, 0.0, (0.0, 0.3), None, None)))
    fig = detector_figure(m, report)
    assert len(fig.axes) == 3
    ax = fig.axes[2]
    assert "false boxes / frame / Mpx" in ax.get_ylabel()
    assert "1 − P_FA" in fig.axes[1].get_ylabel()
    np.testing.assert_allclose([p.get_height() for p in ax.patches], [0.2, 0.6, 1.3])
    assert ax.get_ylim()[1] == pytest.approx(3 * 1.3)  # 2.7 measured: the axis to 3
    texts = [t for t in ax.texts]
    assert [t.get_text() for t in texts] == ["0.8", "1e-06"]  # untested bin: no p-value
    assert texts[1].get_color() == "tab:red"
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["measured on the split"]
    assert len(detector_figure(model((4, 8, 16, 32))).axes) == 2  # no rate: two panels
