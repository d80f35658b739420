"""The results table: rows of (scenario, figure, target, measured, verdict), the machine they
were measured on, and the README block between the benchmark markers."""

from __future__ import annotations

import os
import platform
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tests.support.marked_block import write_marked_block

START_MARKER = "<!-- benchmarks:start -->"
END_MARKER = "<!-- benchmarks:end -->"


@dataclass(frozen=True)
class Row:
    """One figure. ``ok`` is None where no target applies."""

    scenario: str
    figure: str
    measured: str
    target: str = ""
    ok: bool | None = None

    @property
    def verdict(self) -> str:
        return "" if self.ok is None else ("pass" if self.ok else "falls short")


def machine() -> str:
    """CPU model, cores, Python, numpy and OpenCV versions."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {sys.version.split()[0]}, "
            f"numpy {np.__version__}, OpenCV {cv2.__version__}, {platform.system()}")


def markdown(rows: list[Row], machine_text: str, command: str) -> str:
    """The results as a Markdown table with the machine and the command that made it."""
    lines = [f"Measured on: {machine_text}. Regenerate with `{command}`.", "",
             "| scenario | figure | target | measured | |",
             "| --- | --- | --- | --- | --- |"]
    lines += [f"| {r.scenario} | {r.figure} | {r.target} | {r.measured} | {r.verdict} |"
              for r in rows]
    return "\n".join(lines)


def write_readme_block(readme: Path, block: str) -> None:
    """Replace the text between the benchmark markers of ``readme`` (appending the markers
    at its end when absent); nothing else in the file changes."""
    write_marked_block(readme, block, START_MARKER, END_MARKER)
