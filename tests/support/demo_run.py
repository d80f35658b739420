"""`pdcov demo` as a child process whose output lines are collected, for the live demo's
tests."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SPEED = "20"


class Run:
    """A child process in its own session whose output lines are collected by a thread;
    killed (whole group) in ``close``."""

    def __init__(self, args: list[str], cwd: Path) -> None:
        env = dict(os.environ, PYTHONPATH=str(ROOT / "sitl") + os.pathsep
                   + os.environ.get("PYTHONPATH", ""))
        self.p = subprocess.Popen(args, cwd=cwd, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, env=env,
                                  start_new_session=True)
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.p.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_line(self, pattern: str, timeout_s: float) -> re.Match:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            for line in list(self.lines):
                m = re.search(pattern, line)
                if m:
                    return m
            if self.p.poll() is not None and not self.reader.is_alive():
                break
            time.sleep(0.1)
        raise AssertionError(f"no line matching {pattern!r} in {timeout_s} s:\n"
                             + "\n".join(self.lines[-30:]))

    def wait(self, timeout_s: float) -> int:
        rc = self.p.wait(timeout=timeout_s)
        self.reader.join(timeout=10)
        return rc

    def close(self) -> None:
        if self.p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.p.pid, signal.SIGKILL)
            self.p.wait(timeout=10)


def demo_args(out: Path, *more: str, speed: str = SPEED) -> list[str]:
    return [sys.executable, "-m", "pdcov.cli", "demo", "--out", str(out), "--plain",
            "--speed", speed, *more]
