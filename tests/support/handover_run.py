"""A run folder for the handover report's tests: metrics.json, a blank heat map and the
exports of three candidates (tests/support/exports_fixtures.py), one of them with a title
and a warning that need escaping."""

from __future__ import annotations

import json

from PIL import Image

from pdcov.report.exports import VehicleDetections, write_exports
from tests.support.exports_fixtures import candidate, coverage, detections_doc

METRICS = {"version": 1, "frames": 101, "cells_free": 1584, "cells_observed": 727,
           "proportion_at_or_above": {"0.5": 0.4539, "0.7": 0.447, "0.8": 0.44507},
           "mean_pd": 0.45, "expected_false_alarms": 1.9,
           "limiting_cells": {"never_in_view": 857, "seen": 727},
           "warnings": ["<b>a warning</b>"]}


def run_folder(tmp_path, metrics=METRICS, exports=True, heatmap=(120, 80)):
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text(json.dumps(metrics))
    if heatmap:
        Image.new("RGB", heatmap, "white").save(run / "heatmap.png")
    if exports:
        doc = detections_doc()
        doc["candidates"].append(candidate(7, 3.0, -2.0, p_person=0.5, vehicle="alpha"))
        write_exports(run, coverage(), [VehicleDetections.from_doc(doc)],
                      title="alpha: <flight & 1>")
    return run
