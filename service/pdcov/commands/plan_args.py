"""The options ``pdcov plan``, ``optimise`` and ``refly`` share: track spacing or side
overlap, the ``--terrain-*`` flags over the mission config's ``planning`` section, and the
firmware the plan files are written for."""

from __future__ import annotations

import argparse
from typing import Any

from pdcov.commands.args import finite, overlap, positive
from pdcov.core.mission import AltitudeFrame, Firmware


def spacing_args(p: argparse.ArgumentParser) -> None:
    """--spacing-m (m) or --overlap (share of the swath), one of them."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--spacing-m", type=positive, help="track spacing (default: from the camera "
                                                   "swath and --overlap)")
    g.add_argument("--overlap", type=overlap, help="side overlap of the swath (default 0.2)")


def terrain_args(p: argparse.ArgumentParser) -> None:
    """Flags overriding the planning section's terrain keys (docs/planning.md)."""
    p.add_argument("--terrain-frame", choices=list(AltitudeFrame),
                   help="over the mission's terrain: amsl (waypoints along the terrain, "
                        "MSL), terrain_alt (heights above terrain, the autopilot follows) "
                        "or relative (a constant altitude above home); default "
                        "planning.terrain_frame, else amsl with a terrain")
    p.add_argument("--terrain-tolerance-m", type=positive,
                   help="height above terrain kept within this (default "
                        "planning.terrain_tolerance_m, 2)")
    p.add_argument("--terrain-clearance-m", type=finite,
                   help="warn where terrain plus this rises into the path (default "
                        "planning.terrain_clearance_m, 10)")


def firmware_args(p: argparse.ArgumentParser) -> None:
    """--firmware: the autopilot the plan files are for (no vehicle is connected to ask)."""
    p.add_argument("--firmware", type=Firmware, choices=list(Firmware),
                   default=Firmware.ARDUPILOT,
                   help="the vehicle's autopilot: the .plan's firmwareType, and PX4 refuses "
                        "terrain-frame waypoints (default ardupilot)")


def planning_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The planning keys the ``--terrain-*`` flags set."""
    given = {"terrain_frame": args.terrain_frame,
             "terrain_tolerance_m": args.terrain_tolerance_m,
             "terrain_clearance_m": args.terrain_clearance_m}
    return {k: v for k, v in given.items() if v is not None}


def side_overlap(args: argparse.Namespace) -> float:
    """--overlap, 0.2 when not given."""
    return 0.2 if args.overlap is None else args.overlap
