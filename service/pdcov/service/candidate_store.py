"""The candidates across restarts, with no I/O (docs/service.md "Durability"): what goes
into the checkpoint and the journal, and how a start restores them from what the daemon
read. The daemon (daemon.py) reads and writes the files; ``ServiceCore`` decides when.

- The checkpoint's member ``pdcov_candidates.json`` holds the tracker's whole state
  (``DetectionTracker.to_doc``) and ``journal_seq``, the last journal line it includes.
- Before each detections publish, the candidates it touches and the next id are one line
  of ``STATE/candidates.journal`` (``journal_line``: JSON, ``\\n``-terminated, with the
  mission hash and a sequence number ``seq`` that keeps counting across restarts), flushed
  and fsynced before the payload goes: an id published is never given again after a
  kill -9. After each checkpoint written the journal is emptied.
- A start (``restore``): the checkpoint's candidates, then the journal's lines in order
  (those at or below the checkpoint's ``journal_seq`` are in it already: a kill between
  the checkpoint's rename and the journal's emptying). A torn last line (a kill during
  an append: never published) is ignored with a warning and cut off; any other bad line
  (not JSON, another mission's, a field not what pdcov writes) stops the replay, is
  logged with its line number, and the journal is set aside. A journal over
  MAX_JOURNAL_BYTES is refused whole (set aside): the checkpoint's candidates only.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from pdcov.detection.candidates import DetectionTracker

JOURNAL_NAME = "candidates.journal"
"""The journal's file in service.state_dir."""
MAX_JOURNAL_BYTES = 64 << 20
"""The longest journal read (and written): a checkpoint empties it every period, so only a
daemon failing to checkpoint for a long time comes near."""
STORE_VERSION = 1
"""The version of the checkpoint member's and the journal lines' documents."""


def checkpoint_doc(tracker: DetectionTracker, journal_seq: int) -> dict[str, Any]:
    """The checkpoint member's document: the tracker's state, which includes the journal's
    lines up to ``journal_seq``."""
    return {"version": STORE_VERSION, "journal_seq": journal_seq, "tracker": tracker.to_doc()}


def journal_line(tracker: DetectionTracker, ids: Iterable[int], seq: int,
                 mission_hash: str) -> bytes:
    """The journal line of candidates ``ids`` (their states now) and the next id."""
    return (json.dumps({"version": STORE_VERSION, "seq": seq, "mission_hash": mission_hash,
                        "next_id": tracker.next_id,
                        "candidates": tracker.candidate_docs(ids)},
                       separators=(",", ":"), allow_nan=False) + "\n").encode()


@dataclass(slots=True)
class Restored:
    """What a start restored: candidates held after the checkpoint and after the journal,
    distinct candidates the journal's lines carried, lines applied, the last journal
    ``seq`` in the state; what to do with the journal file: keep its first ``keep_bytes``
    (its valid lines), or set it aside (lines not applied); lines to log (level, text)."""

    from_checkpoint: int = 0
    candidates: int = 0
    from_journal: int = 0
    lines: int = 0
    journal_seq: int = 0
    keep_bytes: int = 0
    set_aside: bool = False
    logs: list[tuple[int, str]] = field(default_factory=list)


def restore(tracker: DetectionTracker, mission_hash: str, *, resumed: bool,
            checkpoint: Any, checkpoint_error: str | None, checkpoint_path: str,
            journal: bytes | None, journal_path: str) -> Restored:
    """Restore ``tracker`` (new) from a resumed checkpoint's member (``checkpoint``: its
    parsed JSON, None when absent; ``checkpoint_error``: why it could not be read) and the
    journal's bytes (None: no file; at most MAX_JOURNAL_BYTES + 1 read), as the module
    docstring says. The paths name the files in the log lines."""
    out = Restored()
    if resumed:
        member = f"{checkpoint_path}: pdcov_candidates.json"
        if checkpoint_error is not None:
            out.logs.append((logging.ERROR, f"{member}: {checkpoint_error}; the grid is "
                             "resumed, the candidates start empty"))
        elif checkpoint is None:
            out.logs.append((logging.INFO, f"{checkpoint_path} holds no candidates (written "
                             "by an older pdcov): the candidates start empty"))
        else:
            try:
                out.journal_seq = _load_checkpoint(tracker, checkpoint)
            except ValueError as exc:
                out.logs.append((logging.ERROR, f"{member}: {exc}; the grid is resumed, the "
                                 "candidates start empty"))
    out.candidates = out.from_checkpoint = len(tracker)
    if journal is not None:
        _replay(tracker, mission_hash, journal, journal_path, out)
        out.candidates = len(tracker)
    return out


def _load_checkpoint(tracker: DetectionTracker, doc: Any) -> int:
    """Load the member's ``doc`` into ``tracker``; its journal_seq. ValueError naming the
    field (the tracker then unchanged)."""
    if not isinstance(doc, dict) or doc.get("version") != STORE_VERSION:
        raise ValueError(f"version: expected {STORE_VERSION}")
    seq = doc.get("journal_seq")
    if not (isinstance(seq, int) and not isinstance(seq, bool) and seq >= 0):
        raise ValueError(f"journal_seq = {seq!r}: expected an integer >= 0")
    try:
        tracker.load_doc(doc.get("tracker"))
    except ValueError as exc:
        raise ValueError(f"tracker.{exc}") from None
    return seq


def _replay(tracker: DetectionTracker, mission_hash: str, journal: bytes, path: str,
            out: Restored) -> None:
    if len(journal) > MAX_JOURNAL_BYTES:
        out.set_aside = True
        out.logs.append((logging.ERROR, f"{path}: over {MAX_JOURNAL_BYTES} bytes, not read "
                         "(set aside): the candidates are the checkpoint's"))
        return
    *lines, torn = journal.split(b"\n")
    offset, carried = 0, set()
    for n, line in enumerate(lines, 1):
        try:
            seq, next_id, docs = _line(line, mission_hash)
            if seq > out.journal_seq:
                tracker.apply_candidate_docs(docs, next_id)
                out.journal_seq = seq
                out.lines += 1
                carried |= {d["id"] for d in docs}
        except ValueError as exc:
            out.set_aside = True
            out.logs.append((logging.ERROR, f"{path}: line {n}: {exc}; the {len(lines) - n} "
                             "lines from it are not applied (the journal is set aside)"))
            break
        offset += len(line) + 1
    else:
        if torn:
            out.logs.append((logging.WARNING, f"{path}: its last line is torn ({len(torn)} "
                             "bytes without an end: a kill during a write, never "
                             "published): ignored"))
    out.keep_bytes = offset
    out.from_journal = len(carried)


def _line(line: bytes, mission_hash: str) -> tuple[int, Any, list[Any]]:
    """A journal line's (seq, next_id, candidate docs); ValueError saying what is wrong."""
    try:
        doc = json.loads(line)
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("version") != STORE_VERSION:
        raise ValueError(f"version: expected {STORE_VERSION}")
    if doc.get("mission_hash") != mission_hash:
        raise ValueError(f"written for mission hash {doc.get('mission_hash')!r}, this "
                         f"daemon's is {mission_hash!r}")
    seq, docs = doc.get("seq"), doc.get("candidates")
    if not (isinstance(seq, int) and not isinstance(seq, bool) and seq > 0):
        raise ValueError(f"seq = {seq!r}: expected an integer > 0")
    if not (isinstance(docs, list) and all(isinstance(d, dict) and "id" in d for d in docs)):
        raise ValueError("candidates: expected a list of candidates")
    return seq, doc.get("next_id"), docs
