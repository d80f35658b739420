"""The cost of motion blur per frame: the same frames into a grid with P_D by size only and
into one with camera.exposure_s and a detector model with blur bins, side by side."""

from __future__ import annotations

from pdcov.core.detector import DetectorModel
from pdcov.core.grid import CoverageGrid

from .measure import time_updates
from .report import Row
from .scenarios import Scenario, strided


def blur_detector(edges_px: tuple[float, ...] = (0.0, 1.0, 2.0, 4.0, 64.0),
                  factors: tuple[float, ...] = (1.0, 0.8, 0.5, 0.2)) -> DetectorModel:
    """The illustrative model with blur bins ``edges_px`` (detector-input px) whose P_D is
    its own times ``factors`` (one per blur bin), P_FA unchanged."""
    doc = DetectorModel.illustrative().to_dict()
    doc.update(blur={
        "edges_px": list(edges_px),
        "p_detect": [[p * k for p in doc["p_detect"]] for k in factors],
        "p_false_alarm": [doc["p_false_alarm"]] * len(factors)})
    return DetectorModel.from_dict(doc)


def blur_rows(sc: Scenario, max_frames: int, exposure_s: float = 0.004) -> list[Row]:
    """Per-frame update time without and with blur over the same frames of ``sc``."""
    frames = strided(sc.poses(), max_frames)
    plain = sc.new_grid()
    blurred = CoverageGrid(plain.geometry, plain.mask, plain.camera, blur_detector(),
                           exposure_s=exposure_s)
    t_plain = time_updates(plain, frames)
    t_blur = time_updates(blurred, frames)
    t_plain_again = time_updates(sc.new_grid(), frames)  # the reference, after as before
    ref_s = 0.5 * (t_plain.mean_s + t_plain_again.mean_s)
    ok = blurred.frames_blurred == len(frames) and (blurred.n_obs == plain.n_obs).all()
    return [Row(sc.name, f"motion blur: update per frame, blur / size only (exposure "
                f"{exposure_s * 1e3:g} ms)",
                f"{t_blur.mean_s / ref_s:.2f}x ({t_blur.mean_s * 1e3:.3f} vs {ref_s * 1e3:.3f} "
                f"ms, {len(frames)} frames, {t_blur.cells.mean():,.0f} cells/frame); "
                f"blur applied to {blurred.frames_blurred} frames", "", bool(ok))]
