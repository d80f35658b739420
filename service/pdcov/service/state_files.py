"""The daemon's small files in service.state_dir, read and written for the asyncio shell
(daemon.py): ``StateFiles``, the epoch token in every candidate uid (EPOCH_NAME), the
re-tasking nonces seen (NONCES_NAME, service/retask_auth.py) and the candidates journal
(candidate_store.JOURNAL_NAME). I/O only: what they hold is decided by ``ServiceCore``.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

from pdcov.atomic import atomic_write
from pdcov.errors import ConfigError, PdcovError
from pdcov.ids import EPOCH_RULE, new_epoch, valid_epoch
from pdcov.service.candidate_store import JOURNAL_NAME, MAX_JOURNAL_BYTES
from pdcov.service.retask_auth import NonceBook

__all__ = ["EPOCH_NAME", "NONCES_NAME", "StateFiles", "check_state_dir"]

log = logging.getLogger("pdcov.serve")
NONCES_NAME = "retask_nonces.json"
"""The re-tasking nonces seen, in service.state_dir (service/retask_auth.py)."""
EPOCH_NAME = "epoch"
"""The state dir's epoch token (ids.EPOCH_RULE) in every candidate uid: made once, when
missing, and read back at every start."""


def check_state_dir(state_dir: Path) -> str | None:
    """``pdcov serve --check``'s look at the state dir, creating and changing nothing: None
    when it is a folder this user may write in, a warning when it does not exist yet, a
    ConfigError when it is no folder or not writable."""
    where = f"service.state_dir {state_dir}"
    try:
        exists = state_dir.exists()
        parent = next(p for p in state_dir.absolute().parents if p.exists())
    except OSError as exc:  # a folder on the way this user may not look into
        raise ConfigError(f"{where}: cannot look at it ({exc.strerror or exc})") from None
    if exists:
        if not state_dir.is_dir():
            raise ConfigError(f"{where}: not a folder")
        if not os.access(state_dir, os.W_OK | os.X_OK):
            raise ConfigError(f"{where}: not writable by this user (its owner, its mode or "
                              "a read-only file system): chown it to the daemon's user, or "
                              "give another --state-dir")
        return None
    if not parent.is_dir():
        raise ConfigError(f"{where}: cannot be made: {parent} is not a folder")
    if os.access(parent, os.W_OK | os.X_OK):
        return f"{where} does not exist: the daemon makes it at start (--check makes nothing)"
    return (f"{where} does not exist, and this user may not make it in {parent}: the "
            "daemon starts only once it is made (systemd's StateDirectory= does, as in "
            "the shipped unit; or sudo install -d -o USER)")


class StateFiles:
    """The epoch, nonces and candidates journal files of ``state_dir``."""

    def __init__(self, state_dir: Path) -> None:
        self.state_dir = state_dir
        self.journal = state_dir / JOURNAL_NAME

    def read_epoch(self) -> str:
        """The state dir's epoch token, made (atomically) when the file is missing; a file
        that does not hold one is refused: a new token would change every restored
        candidate's uid."""
        path = self.state_dir / EPOCH_NAME
        try:
            text = path.read_text(encoding="ascii").strip()
        except FileNotFoundError:
            text = new_epoch()
            with atomic_write(path, "w") as f:
                f.write(text + "\n")
            log.info("%s: new epoch %s (in every candidate uid)", path, text)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{path}: cannot read the epoch ({exc})") from None
        if not valid_epoch(text):
            raise ConfigError(f"{path}: {text[:40]!r} is not an epoch ({EPOCH_RULE}); remove "
                              "the file to start a new one (the candidates' uids then change)")
        return text

    def read_nonces(self) -> NonceBook:
        """The re-tasking nonces seen before this start (none when the file is missing; a
        damaged file is logged and set aside: its nonces are older than a restart, and a
        request older than the window is refused anyway)."""
        path = self.state_dir / NONCES_NAME
        try:
            return NonceBook.from_bytes(path.read_bytes())
        except FileNotFoundError:
            return NonceBook()
        except (OSError, ValueError) as exc:
            log.warning("%s: not read (%s); re-tasking nonces start empty", path, exc)
            return NonceBook()

    def write_nonces(self, data: bytes) -> None:
        try:
            with atomic_write(self.state_dir / NONCES_NAME, "wb") as f:
                f.write(data)
        except PdcovError as exc:
            log.error("re-tasking nonces not written: %s", exc)

    def read_journal(self) -> tuple[bytes | None, bool]:
        """(the candidates journal's bytes, at most MAX_JOURNAL_BYTES + 1; None: no file,
        whether it could not be read)."""
        try:
            with self.journal.open("rb") as f:
                return f.read(MAX_JOURNAL_BYTES + 1), False
        except FileNotFoundError:
            return None, False
        except OSError as exc:
            log.error("%s: cannot read (%s): the candidates are the checkpoint's",
                      self.journal, exc)
            return None, True

    def settle_journal(self, journal: bytes | None, keep_bytes: int, set_aside: bool) -> None:
        """After the restore at start: the journal set aside, or cut to its first
        ``keep_bytes`` (a torn last line: the next append goes after it)."""
        path = self.journal
        try:
            if set_aside:
                aside = path.with_name(f"candidates-{time.strftime('%Y%m%dT%H%M%S')}"
                                       ".set-aside.journal")
                path.replace(aside)
                log.warning("%s set aside as %s", path, aside.name)
            elif journal is not None and keep_bytes < len(journal):
                os.truncate(path, keep_bytes)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot set it right ({exc})") from None

    def append_journal(self, line: bytes) -> str | None:
        """Append to the candidates journal, flushed and fsynced; a failed write is cut
        back off (the file keeps whole lines). Returns why it failed, or None."""
        try:
            with self.journal.open("ab") as f:
                before = f.tell()
                try:
                    f.write(line)
                    f.flush()
                    os.fsync(f.fileno())
                except OSError:
                    f.truncate(before)
                    raise
        except OSError as exc:
            return f"{self.journal}: {exc.strerror or exc}"
        return None

    def reset_journal(self) -> None:
        """Empty the candidates journal (atomically: a kill leaves it whole or empty)."""
        try:
            with atomic_write(self.journal, "wb"):
                pass
        except PdcovError as exc:  # its lines are in the checkpoint: replayed, skipped
            log.error("candidates journal not emptied: %s", exc)
