"""Reading .npz files (grid snapshots, checkpoints, snapshot payloads) so that a damaged one
fails with one exception the caller chooses, never with what numpy or zipfile raise inside.

A damaged .npz fails in many places (found by fuzzing, tests/unit/test_fuzz_state.py): zipfile
(BadZipFile, NotImplementedError for an unknown compression method, EOFError, OSError),
zlib while inflating a member (zlib.error), numpy's .npy header parser (ast.literal_eval:
SyntaxError, ValueError; for old-format headers its tokenize fallback: tokenize.TokenError),
the header's dtype or shape (TypeError, ValueError, OverflowError, MemoryError for a shape
too large to allocate), and a member cut short (ValueError, EOFError). All are caught here,
at the one place .npz files are read.
"""

from __future__ import annotations

import io
import tokenize
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

DAMAGED = (OSError, EOFError, ValueError, KeyError, TypeError, OverflowError, SyntaxError,
           MemoryError, RecursionError, NotImplementedError, tokenize.TokenError,
           zipfile.BadZipFile, zlib.error)


def read_npz(file: str | Path | bytes, error: Callable[[str], Exception]
             ) -> dict[str, np.ndarray]:
    """Every array of the .npz at path ``file`` (or of its bytes), read whole (no pickles).
    A file that cannot be read raises ``error(why)``."""
    try:
        z = np.load(io.BytesIO(file) if isinstance(file, bytes) else file, allow_pickle=False)
    except DAMAGED as exc:
        raise error(f"{type(exc).__name__}: {exc}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise error("a single .npy array, not an .npz file")
    try:
        with z:
            return {k: z[k] for k in z.files}
    except DAMAGED as exc:
        raise error(f"{type(exc).__name__}: {exc}") from None


def read_npy(path: str | Path, error: Callable[[str], Exception]) -> np.ndarray:
    """The array of the .npy file at ``path`` (no pickles); a file that cannot be read, or
    an .npz, raises ``error(why)``."""
    try:
        a = np.load(path, allow_pickle=False)
    except DAMAGED as exc:
        raise error(f"{type(exc).__name__}: {exc}") from None
    if not isinstance(a, np.ndarray):
        a.close()
        raise error("an .npz file, not a single .npy array")
    return a


def read_zip_member(file: str | Path | bytes, member: str,
                    error: Callable[[str], Exception]) -> bytes:
    """The bytes of zip member ``member`` of the file at path ``file`` (or of its bytes);
    a missing member or a damaged file raises ``error(why)``."""
    try:
        src = io.BytesIO(file) if isinstance(file, bytes) else file
        with zipfile.ZipFile(src) as zf:
            return zf.read(member)
    except DAMAGED as exc:
        raise error(f"{type(exc).__name__}: {exc}") from None
