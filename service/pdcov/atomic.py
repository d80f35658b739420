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
run that this one did not write (e.g. posterior files of an earlier ``--prior`` run). A
run killed outright (kill -9, power loss) can leave the moved-aside folder behind; the next
run of the same folder puts things right first (``replacing_dir``).

Every failure to write (missing folder, a file in the way, no permission, a full disk) is an
``OutputError`` naming the path.
"""

from __future__ import annotations

import os
import re
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
            f = open(tmp, mode, **open_kwargs)  # closed below (``with f``)
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


_OLD, _DONE = ".pdcov-old", ".pdcov-done"


def _leftovers(path: Path) -> list[Path]:
    """The folders ``replacing_dir`` set aside beside ``path`` (``.NAME.XXXXXXXX.pdcov-old``
    from mkdtemp, renamed ``.pdcov-done`` once the new folder was complete)."""
    name = re.compile(rf"\.{re.escape(path.name)}\.[a-z0-9_]{{8}}"
                      rf"({re.escape(_OLD)}|{re.escape(_DONE)})")
    if not path.parent.is_dir():
        return []
    return sorted(p for p in path.parent.iterdir() if name.fullmatch(p.name) and p.is_dir())


def _recover(path: Path) -> None:
    """Undo what a killed run (kill -9, power loss) of ``replacing_dir(path)`` left.

    A ``.pdcov-done`` folder holds a previous folder whose replacement was complete: it is
    removed. A ``.pdcov-old`` folder holding ``NAME`` is the last complete folder, moved aside
    by a run that never finished: ``path``, if present, is that run's partial folder, so it is
    removed and the previous folder put back (as for an interrupted run); an empty one is
    removed. Refused (OutputError) when ``path`` is not a pdcov folder or when several
    moved-aside folders compete: which to keep is the user's choice."""
    held = []
    for leftover in _leftovers(path):
        if leftover.name.endswith(_DONE) or not (leftover / path.name).is_dir():
            shutil.rmtree(leftover)
        else:
            held.append(leftover)
    if not held:
        return
    if len(held) > 1:
        raise OutputError(f"{path}: several killed runs left previous outputs beside it "
                          f"({', '.join(str(p / path.name) for p in held)}): move the one "
                          "to keep to this path and remove the others")
    previous = held[0] / path.name
    if path.is_dir() and ((path / MARKER).exists() or not any(path.iterdir())):
        shutil.rmtree(path)
    elif path.exists():
        raise OutputError(f"{path}: a killed run left the previous outputs in {previous}, and "
                          f"{path} is not a pdcov folder: move one of them away")
    os.replace(previous, path)
    held[0].rmdir()


@contextmanager
def replacing_dir(path: str | Path) -> Iterator[bool]:
    """Write an output folder whole or not at all (module docstring). Yields True when a
    previous folder is being replaced. The body writes into ``path`` itself.

    The previous folder waits in ``.NAME.XXXXXXXX.pdcov-old`` beside ``path`` until the body
    has finished; that folder is then renamed ``.pdcov-done`` and deleted. A killed run
    (kill -9, power loss) can leave either behind, and the next ``replacing_dir`` of the same
    path starts by undoing it (``_recover``): a ``.pdcov-done`` one is deleted (the new
    folder was complete); from a ``.pdcov-old`` one the previous folder is put back in place
    of whatever the killed run had written, which may be partial: only a run whose body
    finished replaces the previous outputs, killed or not. One run per output folder at a
    time: a second run of the same path would take the first one's work for a killed run's."""
    path = Path(path)
    try:
        _recover(path)
    except OSError as exc:
        raise _cannot(path, exc) from None
    check_output_dir(path)
    old: Path | None = None
    try:
        if path.is_dir() and any(path.iterdir()):
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=_OLD,
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
        done = old.with_name(old.name[:-len(_OLD)] + _DONE)
        try:  # from here on a killed run's leftover is deleted, never put back
            os.replace(old, done)
        except OSError:
            done = old
        shutil.rmtree(done, ignore_errors=True)
