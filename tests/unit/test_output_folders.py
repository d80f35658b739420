"""Outputs: files get the normal mode under the umask; a run folder is replaced whole or not
at all (atomic.replacing_dir), so an interrupted run leaves the previous one intact and no
file of an earlier run stays beside a new one."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from pdcov.atomic import MARKER, atomic_path, replacing_dir, write_text_atomic
from pdcov.errors import OutputError
from tests.support.output_runs import mode, previous_run, snapshot


def test_files_get_the_mode_of_a_new_file(tmp_path: Path, umask) -> None:
    write_text_atomic(tmp_path / "a.json", "{}")
    with atomic_path(tmp_path / "b.bin") as tmp:
        tmp.write_bytes(b"x")
    assert mode(tmp_path / "a.json") == 0o644 and mode(tmp_path / "b.bin") == 0o644
    umask(0o027)
    write_text_atomic(tmp_path / "c.json", "{}")
    assert mode(tmp_path / "c.json") == 0o640


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, RuntimeError])
def test_interrupted_run_leaves_the_previous_one_intact(tmp_path: Path, interrupt) -> None:
    out = tmp_path / "run"
    before = previous_run(out)
    assert set(before) == {MARKER, "metrics.json", "heatmap.png"}
    with pytest.raises(interrupt), replacing_dir(out):
        write_text_atomic(out / "metrics.json", '{"frames": 186}')  # half of the new run
        raise interrupt("Ctrl-C mid-write")
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # nothing left beside


def test_new_run_replaces_the_old_whole(tmp_path: Path) -> None:
    out = tmp_path / "run"
    previous_run(out)
    (out / "posterior.npy").write_bytes(b"an earlier --prior run")
    with replacing_dir(out) as replaced:
        write_text_atomic(out / "metrics.json", '{"frames": 186}')
    assert replaced
    assert set(snapshot(out)) == {MARKER, "metrics.json"}


def killed_mid_run(out: Path, *, new_files: dict[str, str] | None, done: bool = False) -> Path:
    """The state a run killed at ``replacing_dir``'s worst moment leaves, made by hand: the
    previous folder moved aside into ``.NAME.XXXXXXXX.pdcov-old`` (``.pdcov-done`` once the
    new folder was complete) and, unless ``new_files`` is None, the new run's folder."""
    leftover = out.parent / f".{out.name}.k1ll3d_9.pdcov-{'done' if done else 'old'}"
    leftover.mkdir()
    os.replace(out, leftover / out.name)
    if new_files is not None:
        out.mkdir()
        (out / MARKER).write_text("")
        for name, text in new_files.items():
            (out / name).write_text(text)
    return leftover


@pytest.mark.parametrize("new_files", [None, {}, {"metrics.json": '{"frames": 1'}])
def test_next_run_puts_back_the_folder_a_killed_run_set_aside(tmp_path: Path,
                                                               new_files) -> None:
    """Killed before its body finished (no new folder yet, an empty one, a partial one):
    the previous folder is the last complete one; the next run starts from it, so an
    interrupted next run leaves exactly it, and a finished one replaces it."""
    out = tmp_path / "run"
    before = previous_run(out)
    killed_mid_run(out, new_files=new_files)
    with pytest.raises(KeyboardInterrupt), replacing_dir(out):
        raise KeyboardInterrupt
    assert snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    killed_mid_run(out, new_files=new_files)
    with replacing_dir(out) as replaced:
        write_text_atomic(out / "metrics.json", '{"frames": 186}')
    assert replaced and set(snapshot(out)) == {MARKER, "metrics.json"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_a_done_leftover_is_deleted_and_the_new_folder_kept(tmp_path: Path) -> None:
    """Killed while deleting the previous folder after the new one was complete."""
    out = tmp_path / "run"
    previous_run(out)
    new = {"metrics.json": '{"frames": 186}'}
    killed_mid_run(out, new_files=new, done=True)
    with pytest.raises(KeyboardInterrupt), replacing_dir(out):
        raise KeyboardInterrupt
    assert snapshot(out) == {MARKER: b"", **{k: v.encode() for k, v in new.items()}}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_leftovers_that_need_a_choice_are_refused(tmp_path: Path) -> None:
    out = tmp_path / "run"
    before = previous_run(out)
    leftover = killed_mid_run(out, new_files=None)
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    with pytest.raises(OutputError, match="not a pdcov folder") as err, replacing_dir(out):
        pass
    assert str(leftover / "run") in str(err.value)
    assert (out / "notes.txt").exists() and snapshot(leftover / "run") == before
    (out / "notes.txt").unlink()
    out.rmdir()
    second = tmp_path / ".run.s3c0nd__.pdcov-old"
    (second / "run").mkdir(parents=True)
    with pytest.raises(OutputError, match="several killed runs"), replacing_dir(out):
        pass
    assert snapshot(leftover / "run") == before and (second / "run").is_dir()
    # Names like a leftover's of another folder are not this folder's.
    (tmp_path / ".run2.abcdefgh.pdcov-old" / "run2").mkdir(parents=True)
    shutil.rmtree(second)
    with replacing_dir(out) as replaced:
        pass
    assert replaced and (tmp_path / ".run2.abcdefgh.pdcov-old" / "run2").is_dir()
