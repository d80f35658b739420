"""``python -m benchmarks.pins``: pins scored by person identity (issue 35, "Done when").

Flies every scenario of ``pdcov_sitl.pin_scenarios`` (sparse, dense groups, oblique, a
restart halfway, a noisy detector) once per seed, in memory (the simulated detector on the
true poses, the grid and the tracker on the poses with their GNSS error), and prints each
scenario's figures beside the issue's targets: the share of people found against the
grid's prediction, pins holding two people or two boxes of one frame, hits <= looks, the
restart's candidates, p_person's calibration (per scenario, and over all pins: the target)
and the true pins' position error. ``--write-docs`` puts the table into docs/simulator.md
("Pins scored by identity").
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from pdcov_sitl.pin_scenarios import (
    RESTART_WITHIN_M,
    FlightRecord,
    PinScenario,
    Scores,
    fly_scenario,
    pin_scenarios,
    score_flights,
)
from pdcov_sitl.pin_score import (
    FOUND_WITHIN_M,
    HIGH_P,
    LOW_P,
    MAX_BRIER,
    MAX_LOW_PEOPLE,
    MAX_TWO_PEOPLE_SHARE,
    MIN_HIGH_PEOPLE,
    Z_MAX,
    Calibration,
)
from tests.support.marked_block import write_marked_block

from .report import Row, machine, markdown

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "simulator.md"
DOC_START, DOC_END = "<!-- pins:start -->", "<!-- pins:end -->"
SEEDS = (1, 2, 3, 4)


def describe(sc: PinScenario, n_frames: int) -> str:
    w, h, fov = sc.camera
    fa = sc.detector.fa_rate_per_mpx or ()
    return (f"{sc.side_m:g} m square at {sc.cell_m:g} m, {sc.n_people} people "
            f"({sc.people}), {w}x{h} {fov:g} deg at {sc.alt_m:g} m, {sc.off_nadir_deg:g} deg "
            f"off nadir, lawnmower {sc.spacing_m:g} m at {sc.speed_mps:g} m/s, "
            f"{sc.rate_hz:g} frames/s ({n_frames} frames), looks {sc.min_revisit_s:g} s "
            f"apart, GNSS sigma {sc.gnss_sigma_m[0]:g} / {sc.gnss_sigma_m[1]:g} m, "
            f"max P_D {max(sc.detector.p_detect):.2f}, max false boxes "
            f"{max(fa, default=0):.3g}/Mpx" + (", tracker restarted halfway"
                                               if sc.restart else ""))


def calibration_rows(name: str, c: Calibration, targets: bool) -> list[Row]:
    """p_person's calibration, with the targets' verdicts when ``targets``."""
    return [
        Row(name, f"p_person >= {HIGH_P:g}: share that are people",
            f"{c.people_high}/{c.n_high} = {c.high_share:.3f}",
            f">= {MIN_HIGH_PEOPLE:.0%}" if targets else "",
            not c.high_share < MIN_HIGH_PEOPLE if targets else None),
        Row(name, f"p_person <= {LOW_P:g}: share that are people",
            f"{c.people_low}/{c.n_low} = {c.low_share:.3f}",
            f"<= {MAX_LOW_PEOPLE:.0%}" if targets else "",
            not c.low_share > MAX_LOW_PEOPLE if targets else None),
        Row(name, "p_person Brier score", f"{c.brier:.4f} over {c.n} pins",
            f"<= {MAX_BRIER:g}" if targets else "", c.brier <= MAX_BRIER if targets else None),
    ]


def scenario_rows(sc: PinScenario, s: Scores, n_frames: int, seconds_per_flight: float
                  ) -> list[Row]:
    """One scenario's figures (module docstring) over its flights."""
    f, m, name = s.found, s.merges, sc.name
    rows = [
        Row(name, "setup", describe(sc, n_frames)),
        Row(name, f"people found (a pin holds a box of theirs, within {FOUND_WITHIN_M:g} m) "
            "vs predicted",
            f"{f.n_found}/{f.n_people} = {f.share:.3f} vs {f.predicted:.3f}, sd {f.sd:.3f} "
            f"(z = {f.z:+.2f})", f"within {Z_MAX:g} sd", f.as_predicted),
        Row(name, "pins holding two or more people",
            f"{m.n_two_people}/{m.n_pins} = {m.two_people_share:.1%} of the pins holding "
            "a person",
            f"<= {MAX_TWO_PEOPLE_SHARE:.0%}" if name == "dense groups" else "",
            m.two_people_share <= MAX_TWO_PEOPLE_SHARE if name == "dense groups" else None),
        Row(name, "pins holding two boxes of one frame", f"{m.n_two_boxes_one_frame}", "0",
            m.n_two_boxes_one_frame == 0),
        Row(name, "pins with hits > looks", f"{s.n_hits_over_looks} of {s.n_pins}", "0",
            s.n_hits_over_looks == 0),
    ]
    if s.restarts is not None:
        n = sum(r.n_candidates for r in s.restarts)
        kept = sum(r.n_kept for r in s.restarts)
        end = sum(r.n_kept_at_end for r in s.restarts)
        move = max(r.max_move_m for r in s.restarts)
        rows.append(Row(name, f"candidates kept by the restart (same uid, within "
                              f"{RESTART_WITHIN_M:g} m)",
                        f"{kept}/{n} (furthest moved {move:.3f} m); at the end of the flight "
                        f"{end}/{n} still within {RESTART_WITHIN_M:g} m of their place",
                        "all", kept == n))
    rows += calibration_rows(name, s.calibration, targets=False)
    rows += [
        Row(name, "true pins' position error p90", f"{s.error_p90_m:.3f} m over "
            f"{s.n_true_pins} pins that are people"),
        Row(name, "time per flight", f"{seconds_per_flight:.1f} s"),
    ]
    return rows


def run(seeds: tuple[int, ...], smoke: bool) -> tuple[list[Row], dict[str, Scores]]:
    """Every scenario over ``seeds``: the table's rows and the scores by scenario."""
    rows: list[Row] = []
    scores: dict[str, Scores] = {}
    everything: list[FlightRecord] = []
    for name, sc in pin_scenarios(smoke).items():
        print(f"{name}: {len(seeds)} flights", file=sys.stderr)
        t0 = time.perf_counter()
        poses = sc.poses()
        records = [fly_scenario(sc, seed, poses) for seed in seeds]
        per_flight = (time.perf_counter() - t0) / len(seeds)
        scores[name] = score_flights(records)
        everything += records
        rows += scenario_rows(sc, scores[name], len(poses), per_flight)
    every = score_flights(everything)
    rows += calibration_rows("all", every.calibration, targets=True)
    scores["all"] = every
    return rows, scores


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.pins", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=len(SEEDS),
                        help=f"flights per scenario, seeds 1..N ({len(SEEDS)})")
    parser.add_argument("--smoke", action="store_true", help="small scenes (CI)")
    parser.add_argument("--write-docs", action="store_true",
                        help=f"write the table into {DOC.relative_to(ROOT)} (between its pins "
                             "markers)")
    args = parser.parse_args(argv)
    seeds = tuple(range(1, args.seeds + 1))
    rows, _ = run(seeds, args.smoke)
    command = ("python -m benchmarks.pins" + (f" --seeds {args.seeds}"
                                              if args.seeds != len(SEEDS) else "")
               + (" --smoke" if args.smoke else "") + " --write-docs")
    table = markdown(rows, machine(), command)
    print(table)
    if args.write_docs:
        write_marked_block(DOC, table, DOC_START, DOC_END)
        print(f"wrote {DOC}", file=sys.stderr)
    return 0 if all(r.ok is not False for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
