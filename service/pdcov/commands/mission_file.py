"""The mission config as the commands load it: ``load_mission`` with what loading found to
warn of (``Mission.warnings``: a DEM that disagrees with origin.ground_alt_msl_m) on stderr."""

from __future__ import annotations

import sys
from pathlib import Path

from pdcov.config.load import load_mission
from pdcov.config.mission import Mission


def load_mission_warned(path: str | Path, command: str) -> Mission:
    """``load_mission(path)``; each warning printed as ``pdcov COMMAND: WARNING: ...``."""
    mission = load_mission(path)
    for w in mission.warnings:
        print(f"pdcov {command}: WARNING: {w}", file=sys.stderr)
    return mission
