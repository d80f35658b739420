"""``pdcov report RUN --out DIR``: the handover report of a run folder, DIR/report.html
(report/handover.py, docs/outputs.md "Handover report")."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    r = subparsers.add_parser("report", help="the handover report (one self-contained "
                                             "report.html) of a run folder",
                              description="Write report.html, the handover report of a "
                                          "run folder (pdcov evaluate --out), into --out.")
    r.add_argument("run", type=Path, help="the run folder (pdcov evaluate --out)")
    r.add_argument("--out", required=True, type=Path,
                   help="folder to write report.html in (created if needed; the run "
                        "folder itself is fine)")
    r.set_defaults(func=run_report)


def run_report(args: argparse.Namespace) -> int:
    from pdcov.report.handover import write_report

    print(f"wrote {write_report(args.run, args.out)}")
    return 0
