"""``python -m benchmarks.reliability``: run the scenarios (see the package's docstring)
and print or write docs/reliability.md's faults block."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from dataclasses import asdict, is_dataclass
from pathlib import Path

from tests.support.marked_block import write_marked_block

from . import __doc__ as _PACKAGE_DOC
from .crash import crash
from .doc_block import fuzz, report
from .outages import disk_full, router_outage
from .rig import DOC, ROOT
from .soak import SoakResult, soak

SCENARIOS = ("fuzz", "soak", "crash", "router", "disk")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reliability",
                                description=(_PACKAGE_DOC or "").split("\n\n")[0])
    p.add_argument("--write-docs", action="store_true", help=f"write {DOC.relative_to(ROOT)}")
    p.add_argument("--quick", action="store_true", help="CI sizes (figures mean little)")
    p.add_argument("--only", nargs="+", choices=SCENARIOS, default=list(SCENARIOS),
                   help="run only these scenarios (no report: see --json)")
    p.add_argument("--soak-s", type=float, help="simulated flight seconds (default 7200)")
    p.add_argument("--speed", type=float, default=8.0, help="simulator speed (default 8)")
    p.add_argument("--rss-every-s", type=float, default=2.0,
                   help="soak: wall seconds between RSS samples (default 2)")
    p.add_argument("--kills", type=int, help="kill -9 count (default 50)")
    p.add_argument("--outage-s", type=float, help="router outage, wall s (default 60)")
    p.add_argument("--disk-full-s", type=float, default=8.0,
                   help="disk: wall seconds the state directory stays full (default 8)")
    p.add_argument("--examples", type=int, help="fuzz examples per property (default 500)")
    p.add_argument("--keep", type=Path, help="run in this folder and keep it")
    p.add_argument("--json", type=Path, metavar="PATH",
                   help="also write each scenario's result to PATH as JSON")
    args = p.parse_args(argv)
    everything = set(args.only) == set(SCENARIOS)
    if args.write_docs and not everything:
        p.error("--write-docs needs every scenario (no --only)")
    q = args.quick
    soak_s = args.soak_s or (600 if q else 7200)
    kills = args.kills or (5 if q else 50)
    outage = args.outage_s or (10 if q else 60)
    examples = args.examples or (25 if q else 500)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="pdcov-reliability-"))
    results: dict[str, object] = {}
    try:
        if "fuzz" in args.only:
            print(f"fuzz: {examples} examples per property", flush=True)
            results["fuzz"] = fz = fuzz(examples)
            print(f"  {fz}", flush=True)
        if "soak" in args.only:
            print(f"soak: {soak_s:g} simulated s at --speed {args.speed:g}", flush=True)
            results["soak"] = sk = soak(folder / "soak", soak_s, args.speed,
                                        rss_every_s=args.rss_every_s)
            print(f"  frames {sk.frames_live}, differ {sk.differ_recording}/"
                  f"{sk.differ_watcher}, RSS growth {sk.rss_growth_mib:+.1f} MiB, "
                  f"{sk.wall_s:.0f} s", flush=True)
        if "crash" in args.only:
            print(f"crash: {kills} kills", flush=True)
            results["crash"] = cr = crash(folder / "crash", kills)
            print(f"  resumed {cr.resumed}/{cr.kills}, during write {cr.during_write}, "
                  f"failures {cr.failures}", flush=True)
        if "router" in args.only:
            print(f"router: {outage:g} s outage", flush=True)
            results["router"] = ro = router_outage(folder / "router", outage)
            print(f"  {ro}", flush=True)
        if "disk" in args.only:
            print("disk full", flush=True)
            results["disk"] = dk = disk_full(folder / "disk", args.disk_full_s)
            print(f"  {dk}", flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    if args.json:
        args.json.write_text(json.dumps({name: as_json(r) for name, r in results.items()},
                                        indent=1))
    if not everything:
        return 0
    text = report(sk, cr, ro, dk, fz, " ".join(["python -m benchmarks.reliability",
                                                *(sys.argv[1:] if argv is None else argv)]))
    if args.write_docs:
        # Only this block: the fleet and security block is benchmarks.fleet's.
        write_marked_block(DOC, text.rstrip("\n"), "<!-- faults:start -->", "<!-- faults:end -->")
        print(f"wrote {DOC}")
    else:
        print(text)
    return 0


def as_json(result: object) -> object:
    """A scenario's result as JSON values: a dataclass's fields (the soak's with its RSS
    growth, MiB), the fuzz summary as it is."""
    if isinstance(result, SoakResult):
        return {**asdict(result), "rss_growth_mib": result.rss_growth_mib}
    return asdict(result) if is_dataclass(result) and not isinstance(result, type) else result


if __name__ == "__main__":
    sys.exit(main())
