"""Writing outputs: atomic files, output folders replaced whole, and checks made before any
work is done.

A file is written to a temp file beside the target, flushed and fsynced, then renamed over
it, so that a reader never sees a half-written file and an interrupted write leaves the old
one intact. It gets the mode a new file gets under the user's umask (0644 under 022), not
the temp file's 0600.

An output folder (``replacing_dir``) is written whole or not at all: a previous run's folder
is moved aside, the new run writes a fresh folder, and the old one is deleted only when the
new one is complete; on any failure, Ctrl-C included, the new folder is removed and the old
one put back. So a run never leaves a mixture of old and new files, nor files of an earlier
run that this one did not write (e.g. posterior files of an earlier ``--prior`` run).

Every failure to write (missing folder, a file in the way, no permission, a full disk) is an
``OutputError`` naming the path.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from pdcov.errors import OutputError

# Marks a folder pdcov wrote, which a later run may replace; a folder with other files and
# no marker is the user's and is never replaced.
MARKER = ".pdcov-output"


def _new_file_mode() -> int:
    """The mode open() gives a new file: 0o666 less the process umask."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def _cannot(path: Path, exc: OSError) -> OutputError:
    return OutputError(f"{path}: cannot write ({exc.strerror or exc})")


@contextmanager
def atomic_write(path: str | Path, mode: str = "w", **open_kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temp file for writing (``mode`` 'w' or 'wb'); on success it replaces ``path``."""
    with atomic_path(path) as tmp:
        try:
            f = open(tmp, mode, **open_kwargs)  # noqa: SIM115 - closed below
        except OSError as exc:
            raise _cannot(Path(path), exc) from None
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temp path for libraries that open files themselves; renamed over ``path`` on
    success, with the mode of a new file."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.fchmod(fd, _new_file_mode())
        os.close(fd)
    except OSError as exc:
        raise _cannot(path, exc) from None
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise _cannot(path, exc) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> None:
    with atomic_write(path) as f:
        f.write(text)


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _check_parent(path: Path, what: str) -> None:
    base = _nearest_existing(path.parent)
    if not base.is_dir():
        raise OutputError(f"{path}: cannot write {what}: {base} is a file, not a folder")
    if base != path.parent.absolute():
        raise OutputError(f"{path}: cannot write {what}: folder {path.parent} does not exist")
    if not os.access(base, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: cannot write {what}: folder {base} is not writable")


def check_output_file(path: str | Path) -> Path:
    """``path`` if a file can be written there (its folder exists and is writable, and it
    is not a folder); else OutputError. Called before any work is done."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; expected a file name to write")
    _check_parent(path, "the file")
    return path


def check_output_dir(path: str | Path) -> Path:
    """``path`` if it can become an output folder: missing (created, with missing parents,
    under a writable folder), empty, or a folder pdcov wrote before (replaced whole); else
    OutputError. Called before any work is done."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: is a file; expected an output folder")
    if path.is_dir():
        if any(path.iterdir()) and not (path / MARKER).exists():
            raise OutputError(f"{path}: a folder with files pdcov did not write (no {MARKER}); "
                              "choose a new or empty folder")
        if not os.access(path.parent.absolute(), os.W_OK | os.X_OK):
            raise OutputError(f"{path}: cannot replace it: folder {path.parent} is not "
                              "writable")
        return path
    base = _nearest_existing(path)
    if not base.is_dir():
        raise OutputError(f"{path}: cannot create the folder: {base} is a file")
    if not os.access(base, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: cannot create the folder: {base} is not writable")
    return path


@contextmanager
def replacing_dir(path: str | Path) -> Iterator[bool]:
    """Write an output folder whole or not at all (module docstring). Yields True when a
    previous folder is being replaced. The body writes into ``path`` itself."""
    path = Path(check_output_dir(path))
    old: Path | None = None
    try:
        if path.is_dir() and any(path.iterdir()):
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".pdcov-old",
                                        dir=path.parent))
            os.replace(path, old / path.name)
        path.mkdir(parents=True, exist_ok=True)  # mode 0777 less the umask
        (path / MARKER).write_text("written by pdcov; a later pdcov run may replace this "
                                   "folder whole\n")
    except OSError as exc:
        if old is not None and not path.exists():
            os.replace(old / path.name, path)
            old.rmdir()
        raise _cannot(path, exc) from None
    try:
        yield old is not None
    except BaseException as exc:
        shutil.rmtree(path, ignore_errors=True)
        if old is not None:
            os.replace(old / path.name, path)
            old.rmdir()
        if isinstance(exc, OSError):
            raise _cannot(path, exc) from None
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
