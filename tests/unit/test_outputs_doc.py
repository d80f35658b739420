"""docs/outputs.md names every metrics.json key a run writes, where it writes it."""

from __future__ import annotations

import json
import re
from importlib import resources
from pathlib import Path

import numpy as np

from pdcov.cli import main
from pdcov.core.search_theory import search_outcome
from pdcov.report.outputs import metrics_document

DOC = Path(__file__).resolve().parents[2] / "docs" / "outputs.md"


def documented_metrics_keys() -> tuple[set[str], set[str], set[str]]:
    """(top-level keys, keys added with --prior, keys of the plan section) as documented."""
    row = next(line for line in DOC.read_text().splitlines()
               if line.startswith("| `metrics.json` |"))
    top, rest = row.split("}`", 1)
    prior_part, plan_part = rest.split('"plan": {', 1)
    prior_part = prior_part.split("with `--prior` also", 1)[1].split(";", 1)[0]
    return (set(re.findall(r'"(\w+)"', top)), set(re.findall(r"`(\w+)`", prior_part)),
            set(re.findall(r'"(\w+)"', plan_part.split("}", 1)[0])))


def test_documented_metrics_keys_are_the_written_ones(tmp_path):
    top, prior, plan = documented_metrics_keys()
    assert {"version", "frames", "mean_pd"} <= top and "spacing_m" in plan  # parsed at all
    cfg = resources.files("pdcov") / "data" / "demo_mission.yaml"
    out = tmp_path / "plan"
    assert main(["plan", "--config", str(cfg), "--pattern", "lawnmower", "--altitude-m", "12",
                 "--speed-mps", "8", "--out", str(out), "--no-figures"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert set(doc) == top | {"plan"}
    assert set(doc["plan"]) == plan
    assert doc["plan"]["spacing_m"] > 0
    # The prior's keys, from the same document builder the runs use.
    from pdcov.core.grid_metrics import Metrics
    m = Metrics(frames=1, cells_free=4, cells_observed=4, proportion_at_or_above={0.5: 1.0},
                mean_pd=0.5, expected_false_alarms=0.0)
    with_prior = metrics_document(m, search_outcome(np.full((2, 2), 0.25), np.full((2, 2), 0.5),
                                                    np.ones((2, 2), bool)))
    assert set(with_prior) - set(metrics_document(m)) == prior
