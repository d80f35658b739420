"""The cost of motion blur per frame: the same frames into a grid with P_D by size only and
into one with camera.exposure_s and a detector model with blur bins, side by side."""

from __future__ import annotations

from pdcov.core.grid import CoverageGrid
from tests.support.blur_detector import blur_detector
from tests.support.scenarios import Scenario, strided

from .measure import time_updates
from .report import Row


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
