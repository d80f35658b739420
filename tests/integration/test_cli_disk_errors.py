"""A full disk and a read-only output folder are one-line errors of `pdcov evaluate`
(tmpfs mounts: needs root, skipped otherwise)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from pdcov import cli
from tests.support.cli_inputs import evaluate, mount_tmpfs, usage_error


def test_full_disk_and_read_only_are_one_line_errors(tmp_path: Path, poses: Path,
                                                     capsys) -> None:
    full, ro = tmp_path / "full", tmp_path / "ro"
    mount_tmpfs(full, "size=48k")
    try:
        mount_tmpfs(ro, "ro,size=64k")
        try:
            assert "not writable" in usage_error(evaluate(str(ro / "run"), poses), capsys)
        finally:
            subprocess.run(["umount", str(ro)], timeout=10, check=False)
        assert cli.main(evaluate(str(full / "run"), poses)) == 2
        err = capsys.readouterr().err
        assert "No space left on device" in err and "Traceback" not in err
        assert not (full / "run").exists()  # a failed run writes nothing
    finally:
        subprocess.run(["umount", str(full)], timeout=10, check=False)
