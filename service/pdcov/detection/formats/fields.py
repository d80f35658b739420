"""The lines and fields of the text formats of labelled sets (YOLO, VisDrone,
Object-Detection-Metrics, and the track formats of detection/tracks.py), read with errors
that name the file and line; the checks of a detection's score and a class id; and the
image sizes (in pixels) the normalised formats need, from a sizes file or the images."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

from pdcov.errors import InputFileError

__all__ = ["IMAGE_SUFFIXES", "class_id_of", "detection_score", "file_lines", "image_sizes",
           "is_number", "labels_dir", "line_numbers", "read_sizes"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


def labels_dir(path: Path) -> Path:
    """A VisDrone-DET split directory holds its labels in ``annotations/``."""
    return path / "annotations" if (path / "annotations").is_dir() else path


def file_lines(path: Path, commas: bool = True) -> Iterator[tuple[str, list[str]]]:
    """(``file:line``, fields) of each non-empty line; fields split at blanks (and commas,
    unless ``commas`` is False)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: cannot read ({exc})") from None
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.strip().rstrip(",") if commas else line.strip()
        if line:
            yield f"{path}:{n}", (line.replace(",", " ") if commas else line).split()


def line_numbers(where: str, fields: list[str], counts: tuple[int, ...], layout: str
                 ) -> list[float]:
    """The numbers of one line's ``fields`` (InputFileError at ``where`` naming ``layout``
    when there are not ``counts`` of them or one is not a finite number)."""
    if len(fields) not in counts:
        raise InputFileError(f"{where}: expected {layout}, got {len(fields)} fields")
    try:
        values = [float(v) for v in fields]
    except ValueError:
        raise InputFileError(f"{where}: expected numbers ({layout}), got "
                             f"{' '.join(fields)!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputFileError(f"{where}: non-finite number in {' '.join(fields)!r}")
    return values


def is_number(text: str) -> bool:
    """Whether ``text`` reads as a number."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def detection_score(where: str, value: float) -> float:
    """A detection's confidence, which must be a probability."""
    if not 0 <= value <= 1:
        raise InputFileError(f"{where}: detection score {value:g} outside [0, 1] (a "
                             "confidence is a probability; logits or percentages must be "
                             "converted)")
    return value


def class_id_of(where: str, value: float) -> int:
    """A class id read as a number at ``where``: an integer >= 0."""
    if value != int(value) or value < 0:
        raise InputFileError(f"{where}: class must be an integer >= 0, got {value:g}")
    return int(value)


def image_sizes(labels: Path, images_dir: str | Path | None,
                sizes_path: str | Path | None) -> dict[str, tuple[int, int]] | None:
    """Image sizes (width, height px) by stem: from ``sizes_path``, else the images in
    ``images_dir`` or, None, beside the labels ``labels`` (None: no images there)."""
    if sizes_path is not None:
        return read_sizes(Path(sizes_path))
    if images_dir is None:
        candidates = [labels.parent / "images"]
        if "labels" in labels.parts:  # Ultralytics layout: .../labels/val beside .../images/val
            i = len(labels.parts) - 1 - labels.parts[::-1].index("labels")
            candidates.append(Path(*labels.parts[:i], "images", *labels.parts[i + 1:]))
        images_dir = next((c for c in candidates if c.is_dir()), None)
        if images_dir is None:
            return None
    return _sizes_from_images(Path(images_dir))


def read_sizes(path: Path) -> dict[str, tuple[int, int]]:
    """A sizes file: lines ``image width height`` (image file name or stem)."""
    if not path.is_file():
        raise InputFileError(f"{path}: no such sizes file")
    sizes = {}
    for where, fields in file_lines(path):
        try:
            w, h = int(fields[1]), int(fields[2])
            if len(fields) != 3 or w <= 0 or h <= 0:
                raise ValueError
        except (ValueError, IndexError):
            raise InputFileError(f"{where}: expected 'image width height' with positive "
                                 f"integer sizes, got {' '.join(fields)!r}") from None
        name = Path(fields[0])
        sizes[name.stem if name.suffix.lower() in IMAGE_SUFFIXES else fields[0]] = (w, h)
    return sizes


def _sizes_from_images(images_dir: Path) -> dict[str, tuple[int, int]]:
    if not images_dir.is_dir():
        raise InputFileError(f"{images_dir}: no such images directory")
    try:
        from PIL import Image  # opening reads only the header
    except ImportError:
        raise InputFileError(f"{images_dir}: reading image sizes needs Pillow; install it or "
                             f"pass --sizes FILE") from None
    sizes = {}
    for p in sorted(images_dir.iterdir()):
        if p.suffix.lower() in IMAGE_SUFFIXES:
            try:
                with Image.open(p) as im:
                    sizes[p.stem] = im.size
            except OSError as exc:
                raise InputFileError(f"{p}: cannot read image size ({exc})") from None
    return sizes
