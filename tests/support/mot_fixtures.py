"""Synthetic tracked sequences in the MOTChallenge layout, with a known per-person
detectability, for the tests of ``pdcov detector fit`` on tracks (detection/looks_fit.py).

People walk in their own slots of a 1920 x 1080 image (so that no two boxes overlap and the
matching is unambiguous), one after the other, each for 16-40 frames, their size in
detector-input pixels (640 px input) changing log-linearly between two sizes drawn across
the bins. Each person has a latent quantile u ~ U(0, 1); in size bin i their detectability is
the u-quantile of Beta(a_i, b_i) with the bin's mean and correlation (the same person hard at
every size), or the bin's mean exactly where the correlation is 0 (independent looks). A hit
gives a detection on the box with a few per cent of box noise and a confidence in [0.5, 1); a
miss sometimes gives one below the 0.5 threshold; false alarms fall in a band below the
slots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

IMAGE_W, IMAGE_H, INPUT_PX = 1920, 1080, 640
_SCALE = IMAGE_W / INPUT_PX  # image px per input px
_COLS, _ROWS, _SLOT_W, _SLOT_H = 8, 4, 240, 216
_FA_TOP = _ROWS * _SLOT_H + 6


@dataclass(frozen=True, slots=True)
class TrueLooks:
    """The truth a set is drawn from: bin edges (input px), mean P_D and correlation per bin."""

    edges_px: tuple[float, ...]
    mean_pd: tuple[float, ...]
    correlation: tuple[float, ...]

    def detectability(self, u: float) -> np.ndarray:
        """A person's P_D per bin given their quantile u."""
        out = []
        for mu, rho in zip(self.mean_pd, self.correlation, strict=True):
            if rho == 0:
                out.append(mu)
            else:
                s = 1 / rho - 1
                out.append(float(stats.beta.ppf(u, mu * s, (1 - mu) * s)))
        return np.asarray(out)


def write_mot(root: Path, truth: TrueLooks, n_people: int, seed: int, fmt: str = "mot",
              n_sequences: int = 2, fa_per_frame: float = 0.5) -> Path:
    """Write ``root/<SEQ>/{seqinfo.ini, gt/gt.txt, det/det.txt}`` and return ``root``.
    ``fmt``: ``mot`` (MOT17 columns) or ``visdrone-mot``."""
    if truth.edges_px[-1] * math.sqrt(2) * _SCALE > _SLOT_H - 4:
        raise ValueError("largest size does not fit a slot")
    rng = np.random.default_rng(seed)
    lo, hi = math.log(truth.edges_px[0] * 1.01), math.log(truth.edges_px[-1] * 0.99)
    edges = np.asarray(truth.edges_px)
    for q in range(n_sequences):
        seq = root / f"SYN-{q + 1:02d}"
        (seq / "gt").mkdir(parents=True)
        (seq / "det").mkdir()
        gt: list[tuple[int, int, str]] = []  # (id, frame, line): written sorted by id
        det: dict[int, list[str]] = {}
        quota = n_people // n_sequences + (q < n_people % n_sequences)
        slot_t = np.ones(_COLS * _ROWS, int)
        for pid in range(1, quota + 1):
            slot = (pid - 1) % (_COLS * _ROWS)
            x0, y0 = (slot % _COLS) * _SLOT_W, (slot // _COLS) * _SLOT_H
            length = int(rng.integers(16, 41))
            s0, s1 = np.exp(rng.uniform(lo, hi, 2))
            p_bin = truth.detectability(float(rng.uniform()))
            t0 = int(slot_t[slot])
            slot_t[slot] = t0 + length + int(rng.integers(0, 6))
            for i in range(length):
                frame = t0 + i
                s = s0 * (s1 / s0) ** (i / (length - 1))
                w, h = round(s / math.sqrt(2) * _SCALE, 2), round(s * math.sqrt(2) * _SCALE, 2)
                cx = x0 + _SLOT_W / 2 + 8 * math.sin(i / 5)
                left, top = round(cx - w / 2, 2), round(y0 + (_SLOT_H - h) / 2, 2)
                size = math.sqrt(w * h) / _SCALE
                b = int(np.searchsorted(edges, size, side="right")) - 1
                gt.append((pid, frame, _gt_line(fmt, frame, pid, (left, top, w, h))))
                if rng.uniform() < p_bin[b]:
                    box = (left + rng.normal(0, 0.03 * w), top + rng.normal(0, 0.03 * h),
                           w * (1 + rng.normal(0, 0.03)), h * (1 + rng.normal(0, 0.03)))
                    det.setdefault(frame, []).append(
                        _det_line(fmt, frame, box, rng.uniform(0.5, 1.0)))
                elif rng.uniform() < 0.3:
                    det.setdefault(frame, []).append(
                        _det_line(fmt, frame, (left, top, w, h), rng.uniform(0.01, 0.49)))
        n_frames = int(slot_t.max())
        for frame in range(1, n_frames + 1):
            for _ in range(rng.poisson(fa_per_frame)):
                s = math.exp(rng.uniform(lo, hi))
                w, h = s / math.sqrt(2) * _SCALE, s * math.sqrt(2) * _SCALE
                box = (rng.uniform(0, IMAGE_W - w), rng.uniform(_FA_TOP, IMAGE_H - h), w, h)
                det.setdefault(frame, []).append(_det_line(fmt, frame, box,
                                                           rng.uniform(0.5, 1.0)))
        (seq / "gt" / "gt.txt").write_text("".join(line + "\n" for *_, line in sorted(gt)))
        (seq / "det" / "det.txt").write_text(
            "".join(line + "\n" for f in sorted(det) for line in det[f]))
        (seq / "seqinfo.ini").write_text(
            f"[Sequence]\nname={seq.name}\nimDir=img1\nframeRate=30\nseqLength={n_frames}\n"
            f"imWidth={IMAGE_W}\nimHeight={IMAGE_H}\nimExt=.jpg\n")
    return root


def _gt_line(fmt: str, frame: int, pid: int, box: tuple[float, ...]) -> str:
    xywh = ",".join(f"{v:.2f}" for v in box)
    return (f"{frame},{pid},{xywh},1,1,1.0" if fmt == "mot" else f"{frame},{pid},{xywh},1,1,0,0")


def _det_line(fmt: str, frame: int, box: tuple[float, ...], conf: float) -> str:
    xywh = ",".join(f"{v:.2f}" for v in box)
    return (f"{frame},-1,{xywh},{conf:.4f},-1,-1,-1" if fmt == "mot"
            else f"{frame},-1,{xywh},{conf:.4f},1,-1,-1")
