"""The keys of pdcov's configuration files, declared once per section and checked before the
values are read, so that a misspelt key is an error instead of a silently used default.

A ``Section`` names the keys one mapping may hold. Each key maps to ``None`` (any value: the
section's reader checks it), to a nested ``Section`` (checked here when the value is a
mapping; another value, such as the path a ``detector`` key may hold instead, is left to the
reader), or to ``Variants`` (a nested mapping whose keys depend on one of its values, as
``mount.type`` chooses the fixed or the gimbal mount's keys). ``Section(open=True)`` accepts
any keys but still requires a mapping. ``check_keys`` walks a parsed document and raises, for
the first unknown key, the caller's error naming the file and the key path with the closest
known key (difflib) as a suggestion.

Each module declares the section it reads beside its reader, where it can as the frozen
dataclass that holds the section's values, its fields the keys (``Section.of_dataclass``):
the mission's sections in config/ (``origin.OriginSection``, ``log.LogSection``, ...),
``CameraConfig`` in core/camera_config.py, ``GimbalMount`` in core/mount.py, the daemon's
``LinkConfig``, ``ServiceConfig`` and ``BusConfig``. Files whose keys are not one
dataclass's fields keep a key list: ROS's camera_info (``CAMERA_INFO``), the detector model
(``MODEL_SCHEMA``: ``DetectorModel`` keeps the fit's metadata in ``extra``). A file's schema
is composed of them (``config.keys.mission_schema``).
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Union

from pdcov.errors import ConfigError, where


@dataclass(frozen=True, slots=True)
class Variants:
    """A mapping whose keys depend on the value of its key ``key`` (``default`` when absent):
    ``sections[value]``. An unknown value is left to the reader to refuse."""

    key: str
    default: str
    sections: Mapping[str, Section]


@dataclass(frozen=True, slots=True)
class Section:
    """The keys one mapping may hold (see the module docstring); ``open``: any keys."""

    keys: Mapping[str, Section | Variants | None] = field(default_factory=dict)
    open: bool = False

    @classmethod
    def of(cls, *names: str, **nested: Section | Variants | None) -> Section:
        """A section of leaf keys ``names`` and of ``nested`` sections (or leaves: None)."""
        return cls({**dict.fromkeys(names), **nested})

    @classmethod
    def of_dataclass(cls, dc: type, **more: Section | Variants | None) -> Section:
        """The keys of a dataclass's init fields (private ones, starting with _, excluded);
        a field whose type is a dataclass (or an optional one) is a nested section. ``more``
        adds keys, e.g. ``type=None``."""
        hints = typing.get_type_hints(dc)
        keys: dict[str, Section | Variants | None] = {}
        for f in dataclasses.fields(dc):
            if f.init and not f.name.startswith("_"):
                inner = _dataclass_in(hints.get(f.name))
                keys[f.name] = cls.of_dataclass(inner) if inner is not None else None
        return cls({**keys, **more})

    def extended(self, **more: Section | Variants | None) -> Section:
        """This section with more keys."""
        return Section({**self.keys, **more}, self.open)


def _dataclass_in(hint: Any) -> type | None:
    """The dataclass of a type hint ``D`` or ``D | None``, else None."""
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return hint
    if typing.get_origin(hint) in (Union, types.UnionType):
        found = [a for a in typing.get_args(hint) if isinstance(a, type)
                 and dataclasses.is_dataclass(a)]
        return found[0] if len(found) == 1 else None
    return None


def check_keys(doc: Any, schema: Section, source: str | None, path: str = "",
               error: type[ConfigError] = ConfigError) -> None:
    """Raise ``error`` for the first key of ``doc`` (a parsed file) or of its nested
    sections that ``schema`` does not declare, e.g. ``mission.yaml: domain.cell_size: unknown
    key; did you mean 'cell_size_m'?``. ``path``: the key path of ``doc`` in its file."""
    if not isinstance(doc, dict):
        raise error(f"{where(source, path) if path else source or 'config'}: expected a "
                    f"mapping, got {doc!r}")
    if schema.open:
        return
    for key, value in doc.items():
        full = f"{path}.{key}" if path else str(key)
        if key not in schema.keys:
            raise error(f"{where(source, full)}: unknown key; {_suggest(key, schema.keys)}")
        sub = schema.keys[key]
        if isinstance(sub, Variants):
            kind = value.get(sub.key, sub.default) if isinstance(value, dict) else None
            sub = sub.sections.get(kind) if isinstance(kind, str) else None
        if sub is None or value is None:
            continue
        if isinstance(value, dict) or sub.open:
            check_keys(value, sub, source, full, error)


def _suggest(key: Any, known: Mapping[str, Any]) -> str:
    names = sorted(known)
    close = difflib.get_close_matches(str(key), names, n=1, cutoff=0.6)
    if not close:  # e.g. a different case or separator: MIN-REVISIT-S
        folded = {n.lower().replace("-", "_"): n for n in names}
        close = difflib.get_close_matches(str(key).lower().replace("-", "_"), list(folded),
                                          n=1, cutoff=0.6)
        close = [folded[c] for c in close]
    hint = f"did you mean {close[0]!r}? " if close else ""
    return f"{hint}expected some of: {', '.join(names)}"
