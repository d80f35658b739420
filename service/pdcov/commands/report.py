"""``pdcov report RUN --out DIR``: the handover report of a run folder, DIR/report.html and
DIR/report.pdf (report/handover.py, docs/outputs.md "Handover report")."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    r = subparsers.add_parser("report", help="the handover report (report.html, one "
                                             "self-contained page, and report.pdf) of a run "
                                             "folder",
                              description="Write report.html and report.pdf, the handover "
                                          "report of a run folder (pdcov evaluate --out), "
                                          "into --out.")
    r.add_argument("run", type=Path, help="the run folder (pdcov evaluate --out)")
    r.add_argument("--out", required=True, type=Path,
                   help="folder to write the report in (created if needed; the run "
                        "folder itself is fine)")
    r.set_defaults(func=run_report)


def run_report(args: argparse.Namespace) -> int:
    from pdcov.report.handover import write_report

    paths, pdf_missing = write_report(args.run, args.out)
    print(f"wrote {', '.join(str(p) for p in paths)}")
    if pdf_missing is not None:
        print(f"not written: report.pdf: {pdf_missing}")
    return 0
