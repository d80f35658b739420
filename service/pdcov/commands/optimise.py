"""``pdcov optimise``: predict every combination of plan parameters and report the Pareto
front of the share of cells at the target P_D against flight time (docs/planning.md);
writes candidates.csv, front.csv, pareto.png, optimise.json and the best plan."""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pdcov.atomic import atomic_write, replacing_dir, write_text_atomic
from pdcov.commands.args import finite, output_dir, overlap, positive, positive_int, probability
from pdcov.commands.mission_file import load_mission_warned
from pdcov.commands.plan_args import firmware_args, planning_overrides, terrain_args
from pdcov.commands.plan_output import replaced_note, terrain_warnings, write_prediction
from pdcov.commands.plan_vantage import write_vantage
from pdcov.errors import ConfigError
from pdcov.extras import ROUTING
from pdcov.planning.optimise import (
    PATTERNS,
    PlanParams,
    Score,
    best_index,
    build_plan,
    candidates,
    pareto_front,
    predict,
    sweep,
    with_spacing,
)
from pdcov.planning.scenario import scenario_of
from pdcov.planning.vantage import VantageSettings
from pdcov.planning.vantage_missions import plan_vantage_missions, vantage_score


def register(subparsers: argparse._SubParsersAction) -> None:
    o = subparsers.add_parser(
        "optimise", help="sweep plan parameters; Pareto front of P_D coverage vs flight time",
        description="Predict every combination of the given parameters on all cores and "
                    "report the plans on the Pareto front of the proportion of cells at or "
                    "above the target P_D against flight time.")
    o.add_argument("--config", required=True, type=Path, help="mission config YAML")
    o.add_argument("--target-pd", type=probability, required=True, help="P_D target per cell")
    o.add_argument("--min-proportion", type=probability, default=0.95,
                   help="proportion of cells that must reach the target (0.95); the best "
                        "plan is the shortest flight reaching it")
    o.add_argument("--patterns", nargs="+", choices=PATTERNS, default=["lawnmower", "spiral"],
                   help="patterns to try (vantage: planned for --target-pd on "
                        "--min-proportion of the cells at each altitude and speed)")
    o.add_argument("--altitudes-m", nargs="+", type=positive, default=[8.0, 10.0, 12.0],
                   help="altitudes above ground to try, m")
    o.add_argument("--speeds-mps", nargs="+", type=positive, default=[3.0, 5.0],
                   help="ground speeds to try, m/s")
    o.add_argument("--headings-deg", nargs="+", type=finite, default=[0.0, 90.0],
                   help="track directions to try, deg clockwise from north")
    o.add_argument("--spacings-m", nargs="+", type=positive,
                   help="track spacings (default: from the swath and --overlaps)")
    o.add_argument("--overlaps", nargs="+", type=overlap, default=[0.0, 0.2, 0.4],
                   help="side overlaps of the swath to try")
    o.add_argument("--zooms-hfov-deg", nargs="+", type=positive, metavar="DEG",
                   help="camera zooms to try with each altitude, as horizontal fields of view "
                        "(deg; needs camera.zoom fov_status; default: not zoomed)")
    o.add_argument("--processes", type=positive_int, help="worker processes (default: all cores)")
    terrain_args(o)
    firmware_args(o)
    o.add_argument("--out", required=True, type=output_dir, help="folder to write")
    o.set_defaults(func=run_optimise)

def _score_row(s: Score) -> dict[str, Any]:
    p = s.params
    vantage = p.pattern == "vantage"
    return {"pattern": p.pattern, "altitude_m": p.alt_agl_m, "speed_mps": p.speed_mps,
            "heading_deg": None if vantage else round(math.degrees(p.heading_rad), 3),
            "overlap": None if p.spacing_m is not None or vantage else p.overlap,
            "spacing_m": None if vantage else round(s.spacing_m, 3),
            "proportion": round(s.proportion, 4),
            **({} if p.zoom_hfov_deg is None else {"zoom_hfov_deg": p.zoom_hfov_deg}),
            "mean_pd": round(s.mean_pd, 4), "flight_time_s": round(s.flight_time_s, 1),
            "path_length_m": round(s.path_length_m, 1), "missions": s.missions}


def _optimise_vantage(args: argparse.Namespace, alt_m: float, speed_mps: float
                      ) -> VantageSettings:
    """The vantage plan ``optimise`` scores at one altitude and speed: the target on
    --min-proportion of the cells, hovers of 2, 4 or 8 s, a 5 s ILP."""
    return VantageSettings(args.target_pd, (alt_m,), (2.0, 4.0, 8.0), args.min_proportion,
                           speed_mps=speed_mps, exact_time_limit_s=5.0)


def _table(rows: Sequence[dict[str, Any]]) -> str:
    keys = list(rows[0])
    cells = [[("" if r[k] is None else str(r[k])) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    lines = ["  ".join(k.rjust(w) for k, w in zip(keys, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in cells]
    return "\n".join(lines)


def run_optimise(args: argparse.Namespace) -> int:
    mission = load_mission_warned(args.config, "optimise")
    sc = scenario_of(mission, planning_overrides(args))
    swept = [p for p in args.patterns if p != "vantage"]
    params = candidates(swept, args.altitudes_m, args.speeds_mps,
                        [math.radians(h) for h in args.headings_deg], args.spacings_m,
                        args.overlaps, args.zooms_hfov_deg or (None,))
    t0 = time.monotonic()
    scores, failures = (sweep(sc, params, args.target_pd, args.processes, progress=True)
                        if params else ([], []))
    if "vantage" in args.patterns:
        ROUTING.require("pdcov optimise --patterns vantage needs")
        for alt, v in itertools.product(args.altitudes_m, args.speeds_mps):
            try:
                scores.append(vantage_score(sc, _optimise_vantage(args, alt, v)))
            except ConfigError as exc:
                failures.append(f"vantage at {alt:g} m, {v:g} m/s: {exc}")
            params.append(PlanParams("vantage", alt, v))
    elapsed = time.monotonic() - t0
    for msg in failures:
        print(f"skipped: {msg}", file=sys.stderr)
    if not scores:
        raise ConfigError("optimise: no candidate plan could be built (see the messages "
                          "above)")
    front = pareto_front(scores)
    best = best_index(scores, args.min_proportion)
    out: Path = args.out
    with replacing_dir(out) as replaced:
        rows = [_score_row(s) for s in scores]
        for name, idx in (("candidates.csv", range(len(scores))), ("front.csv", front)):
            with atomic_write(out / name, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=list(rows[0]) + ["on_front"])
                w.writeheader()
                for i in idx:
                    w.writerow({**rows[i], "on_front": i in front})
        _front_figure(out / "pareto.png", scores, front, best, args.target_pd)
        s = scores[best]
        if s.params.pattern == "vantage":
            t1 = time.monotonic()
            vm = plan_vantage_missions(sc, _optimise_vantage(args, s.params.alt_agl_m,
                                                             s.params.speed_mps))
            summary = write_vantage(out / "best", mission, sc, vm, time.monotonic() - t1, True,
                                    args.firmware)
            description = vm.missions[0].prediction.plan.description
        else:
            plan, spacing = build_plan(sc, with_spacing(s.params, s.spacing_m))
            pred = predict(sc, plan, s.params)
            summary = write_prediction(out / "best", mission, pred, pred.grid,
                                        f"best: {plan.description} at {s.params.alt_agl_m:g} m",
                                        spacing, terrain_warnings=terrain_warnings(sc, pred),
                                        firmware=args.firmware)
            description = plan.description
        write_text_atomic(out / "optimise.json", json.dumps({
            "target_pd": args.target_pd, "min_proportion": args.min_proportion,
            "candidates": len(params), "scored": len(scores), "elapsed_s": round(elapsed, 1),
            "front": [rows[i] for i in front], "best": rows[best]}, indent=2) + "\n")
    print(f"{len(scores)} plans in {elapsed:.1f} s "
          f"({60 * len(scores) / max(elapsed, 1e-9):.0f} plans/min); Pareto front of the "
          f"proportion of cells with P_D >= {args.target_pd:g} vs flight time:")
    print(_table([rows[i] for i in front]))
    reached = s.proportion >= args.min_proportion
    print(f"best ({'shortest flight reaching' if reached else 'none reaches'} "
          f"{args.min_proportion:g}): {description}, {s.params.alt_agl_m:g} m, "
          f"{s.params.speed_mps:g} m/s -> proportion {s.proportion:.3f}, "
          f"{s.flight_time_s:.0f} s")
    print(summary + replaced_note(replaced, out))
    return 0


def _front_figure(path: Path, scores: Sequence[Score], front: Sequence[int], best: int,
                  target_pd: float) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no pareto.png (pip install 'pdcov[plots]')",
              file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(7, 5))
    for pat in sorted({s.params.pattern for s in scores}):
        sel = [s for s in scores if s.params.pattern == pat]
        ax.scatter([s.flight_time_s for s in sel], [s.proportion for s in sel], s=18,
                   alpha=0.6, label=pat)
    f = sorted(front, key=lambda i: scores[i].flight_time_s)
    ax.step([scores[i].flight_time_s for i in f], [scores[i].proportion for i in f],
            where="post", color="k", lw=1, label="Pareto front")
    ax.scatter([scores[best].flight_time_s], [scores[best].proportion], s=120,
               facecolors="none", edgecolors="r", label="best")
    ax.set_xlabel("predicted flight time (s)")
    ax.set_ylabel(f"proportion of cells with P_D >= {target_pd:g}")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
