"""``python -m benchmarks.reliability``: run the scenarios (see the package's docstring)
and print or write docs/reliability.md's faults block."""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from ..report import write_marked_block
from . import __doc__ as _PACKAGE_DOC
from .crash import crash
from .doc_block import fuzz, report
from .outages import disk_full, router_outage
from .rig import DOC, ROOT
from .soak import soak


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reliability",
                                description=(_PACKAGE_DOC or "").split("\n\n")[0])
    p.add_argument("--write-docs", action="store_true", help=f"write {DOC.relative_to(ROOT)}")
    p.add_argument("--quick", action="store_true", help="CI sizes (figures mean little)")
    p.add_argument("--soak-s", type=float, help="simulated flight seconds (default 7200)")
    p.add_argument("--speed", type=float, default=8.0, help="simulator speed (default 8)")
    p.add_argument("--kills", type=int, help="kill -9 count (default 50)")
    p.add_argument("--outage-s", type=float, help="router outage, wall s (default 60)")
    p.add_argument("--examples", type=int, help="fuzz examples per property (default 500)")
    p.add_argument("--keep", type=Path, help="run in this folder and keep it")
    args = p.parse_args(argv)
    q = args.quick
    soak_s = args.soak_s or (600 if q else 7200)
    kills = args.kills or (5 if q else 50)
    outage = args.outage_s or (10 if q else 60)
    examples = args.examples or (25 if q else 500)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="pdcov-reliability-"))
    try:
        print(f"fuzz: {examples} examples per property", flush=True)
        fz = fuzz(examples)
        print(f"  {fz}", flush=True)
        print(f"soak: {soak_s:g} simulated s at --speed {args.speed:g}", flush=True)
        sk = soak(folder / "soak", soak_s, args.speed)
        print(f"  frames {sk.frames_live}, differ {sk.differ_recording}/{sk.differ_watcher}, "
              f"RSS growth {sk.rss_growth_mib:+.1f} MiB, {sk.wall_s:.0f} s", flush=True)
        print(f"crash: {kills} kills", flush=True)
        cr = crash(folder / "crash", kills)
        print(f"  resumed {cr.resumed}/{cr.kills}, during write {cr.during_write}, "
              f"failures {cr.failures}", flush=True)
        print(f"router: {outage:g} s outage", flush=True)
        ro = router_outage(folder / "router", outage)
        print(f"  {ro}", flush=True)
        print("disk full", flush=True)
        dk = disk_full(folder / "disk")
        print(f"  {dk}", flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    text = report(sk, cr, ro, dk, fz, " ".join(["python -m benchmarks.reliability",
                                                *(sys.argv[1:] if argv is None else argv)]))
    if args.write_docs:
        # Only this block: the fleet and security block is benchmarks.fleet's.
        write_marked_block(DOC, text.rstrip("\n"), "<!-- faults:start -->", "<!-- faults:end -->")
        print(f"wrote {DOC}")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
