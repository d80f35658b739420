"""`pdcov demo`, the README's first command, runs end to end and writes both runs."""

import json

from pdcov.cli import main


def test_demo_writes_both_runs_and_the_comparison(tmp_path, capsys):
    assert main(["demo", "--offline", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "ILLUSTRATIVE" in out
    for pattern in ("lawnmower", "spiral"):
        metrics = json.loads((tmp_path / pattern / "metrics.json").read_text())
        assert metrics["cells_free"] == 1600 and metrics["frames"] > 100
        assert 0.0 < metrics["mean_pd"] <= 1.0
        for name in ("heatmap.png", "thresholds.png", "grid.npz", "pd.tif", "plan.plan"):
            assert (tmp_path / pattern / name).stat().st_size > 0
    assert (tmp_path / "compare.png").stat().st_size > 0
