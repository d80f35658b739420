"""The ArduPilot parameter files of firmware_params/ and their reader."""

from __future__ import annotations

import re
from pathlib import Path

PARAMS_DIR = Path(__file__).resolve().parents[2] / "firmware_params"
AP_47 = PARAMS_DIR / "ardupilot-4.7.parm"
AP_NAME = re.compile(r"^[A-Z][A-Z0-9_]{0,15}$")  # AP_MAX_NAME_SIZE 16


def read_parm(path: Path) -> dict[str, float]:
    """An ArduPilot .parm file (NAME VALUE per line, '#' comments), refusing duplicates."""
    out: dict[str, float] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        assert len(fields) == 2, f"{path.name}:{n}: expected NAME VALUE, got {line!r}"
        name, value = fields
        assert AP_NAME.match(name), f"{path.name}:{n}: bad parameter name {name!r}"
        assert name not in out, f"{path.name}:{n}: {name} set twice"
        out[name] = float(value)
    return out
