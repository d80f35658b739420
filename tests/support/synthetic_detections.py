"""A synthetic labelled set with known per-size detection and false-alarm rates, and its
writer to COCO files: for the detector-statistics tests and the detector CLI tests."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from pdcov.detection.truth_set import Boxes, ImageTruth

EDGES = (8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0, 96.0)  # detector-input px
P_D = (0.2, 0.45, 0.6, 0.75, 0.85, 0.7, 0.5)
P_FA = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4)
IMAGE_W, IMAGE_H, INPUT = 1280, 960, 640  # scale 0.5: detector px = image px / 2
CELL_W, CELL_H = 256, 240


def synthetic_set(seed: int, n_per_bin: int, p_d=P_D, p_fa=P_FA,
                  edges=EDGES) -> tuple[dict[str, ImageTruth], dict[str, Boxes]]:
    """Objects of class 'person', each in its own grid cell, sizes log-uniform inside each bin
    (5 % away from its edges); each detected (a jittered box, score >= 0.5) with the bin's
    P_D, else left alone or given a box below the threshold. False alarms (empty cells) per
    bin ~ Poisson with mean E[TP] q / (1 - q), so that E[FP] / E[all] = q = P_FA."""
    rng = np.random.default_rng(seed)
    scale = IMAGE_W / INPUT
    items = []  # (kind, size px in image, detected)
    for i, (pd, q) in enumerate(zip(p_d, p_fa, strict=True)):
        lo, hi = edges[i] * 1.05, edges[i + 1] / 1.05
        sizes = np.exp(rng.uniform(np.log(lo), np.log(hi), n_per_bin)) * scale
        items += [("object", s, rng.random() < pd) for s in sizes]
        n_fp = rng.poisson(n_per_bin * pd * q / (1 - q))
        sizes = np.exp(rng.uniform(np.log(lo), np.log(hi), n_fp)) * scale
        items += [("false", s, False) for s in sizes]
    rng.shuffle(items)
    per_image = (IMAGE_W // CELL_W) * (IMAGE_H // CELL_H)
    truth, dets = {}, {}
    for k in range(math.ceil(len(items) / per_image)):
        gt_rows, dt_rows, scores = [], [], []
        for c, (kind, s, detected) in enumerate(items[k * per_image:(k + 1) * per_image]):
            r = np.exp(rng.uniform(-0.2, 0.2))
            w, h = s * r, s / r
            x = (c % (IMAGE_W // CELL_W)) * CELL_W + rng.uniform(0, CELL_W - w)
            y = (c // (IMAGE_W // CELL_W)) * CELL_H + rng.uniform(0, CELL_H - h)
            if kind == "object":
                gt_rows.append((x, y, w, h))
            e = rng.uniform(-0.03, 0.03, 4)
            jittered = (x + e[0] * w, y + e[1] * h, w * (1 + e[2]), h * (1 + e[3]))
            if kind == "false" or detected:
                dt_rows.append(jittered)
                scores.append(rng.uniform(0.5, 1.0))
            elif rng.random() < 0.5:
                dt_rows.append(jittered)
                scores.append(rng.uniform(0.0, 0.49))
        image_id = f"img{k:04d}"
        truth[image_id] = ImageTruth(image_id, IMAGE_W, IMAGE_H,
                                     Boxes.from_rows(gt_rows, ["person"] * len(gt_rows)))
        dets[image_id] = Boxes.from_rows(dt_rows, ["person"] * len(dt_rows), scores)
    return truth, dets


def write_coco(truth: dict[str, ImageTruth], dets: dict[str, Boxes], gt_path: Path,
               dt_path: Path, categories=("person", "car")) -> None:
    """Write a set as a COCO instances file and a results list (image ids 1, 2, ...)."""
    cat_id = {name: i + 1 for i, name in enumerate(categories)}
    images, anns, results = [], [], []
    for n, (image_id, image) in enumerate(truth.items(), start=1):
        images.append({"id": n, "file_name": f"{image_id}.jpg", "width": image.width_px,
                       "height": image.height_px})
        b = image.boxes
        for xywh, lab, ign in zip(b.xywh.tolist(), b.labels, b.ignore.tolist(), strict=True):
            anns.append({"id": len(anns) + 1, "image_id": n, "category_id": cat_id[lab],
                         "bbox": xywh, "area": xywh[2] * xywh[3], "iscrowd": int(ign)})
        d = dets.get(image_id)
        if d is not None:
            for xywh, lab, s in zip(d.xywh.tolist(), d.labels, d.scores.tolist(), strict=True):
                results.append({"image_id": n, "category_id": cat_id[lab], "bbox": xywh,
                                "score": s})
    gt_path.write_text(json.dumps({"images": images, "annotations": anns, "categories": [
        {"id": i, "name": name} for name, i in cat_id.items()]}))
    dt_path.write_text(json.dumps(results))


BLUR_EDGES = (0.0, 1.0, 2.0, 4.0)  # detector-input px
P_D_BY_BLUR = (P_D, tuple(0.8 * p for p in P_D), tuple(0.4 * p for p in P_D))
P_FA_BY_BLUR = (P_FA, P_FA, tuple(p + 0.1 for p in P_FA))


def synthetic_blur_set(seed: int, n_per_bin: int
                       ) -> tuple[dict[str, ImageTruth], dict[str, Boxes], dict[str, float]]:
    """``synthetic_set`` per blur bin of BLUR_EDGES with that bin's P_D and P_FA rows
    (P_D_BY_BLUR, P_FA_BY_BLUR), and each image's blur in image px: uniform inside its
    bin, 5 % away from the edges (detector-input px = image px / 2)."""
    rng = np.random.default_rng(seed)
    truth, dets, blur = {}, {}, {}
    for j, (p_d, p_fa) in enumerate(zip(P_D_BY_BLUR, P_FA_BY_BLUR, strict=True)):
        t, d = synthetic_set(seed + 100 * j, n_per_bin, p_d, p_fa)
        lo, hi = BLUR_EDGES[j] + 0.05, BLUR_EDGES[j + 1] - 0.05
        for k in t:
            key = f"b{j}_{k}"
            truth[key] = ImageTruth(key, t[k].width_px, t[k].height_px, t[k].boxes)
            dets[key] = d[k]
            blur[key] = float(rng.uniform(lo, hi)) * IMAGE_W / INPUT
    return truth, dets, blur
