"""Files that hold a secret (a web map token, a key's password): one rule for all of them,
as ssh asks of a private key."""

from __future__ import annotations

import stat
from pathlib import Path

from pdcov.errors import ConfigError


def read_secret_file(path: Path, flag: str) -> str:
    """The text of ``path`` (UTF-8, as written). ConfigError naming ``flag`` and the file
    when it is missing, not a regular file, readable or writable by group or others
    (chmod 600) or not text."""
    try:
        st = path.stat()
    except OSError as exc:
        raise ConfigError(f"{flag} {path}: cannot read it ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{flag} {path}: not a regular file")
    if st.st_mode & 0o077:
        raise ConfigError(f"{flag} {path}: permissions "
                          f"{stat.S_IMODE(st.st_mode):04o} are too open: group and others "
                          f"must have no access to it (chmod 600 {path})")
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{flag} {path}: cannot read it ({exc})") from None
