"""``pdcov demo``: the paper's scene, end to end, on the bundled example mission."""

from __future__ import annotations

import argparse
from importlib import resources
from pathlib import Path

from pdcov.config import load_mission


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="plan, fly and evaluate the paper's 40 x 40 m scene",
        description="On the bundled example mission (the paper's 40 x 40 m square, 640 x 480 "
                    "camera at 5 frames/s, the ILLUSTRATIVE detector model): plan a "
                    "lawnmower and a spiral at 10 m, fly them kinematically, evaluate the "
                    "coverage of each and compare them, as in the paper's Figs. 7 and 8.")
    p.add_argument("--out", type=Path, default=Path("pdcov-demo"), help="output folder")
    p.add_argument("--altitude-m", type=float, default=10.0, help="flight height")
    p.add_argument("--speed-mps", type=float, default=5.0, help="flight speed")
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    from pdcov.evaluate import summary_text, write_outputs
    from pdcov.optimise import PlanParams, Scenario, build_plan, predict
    from pdcov.plots import compare_figure

    ref = resources.files("pdcov") / "data" / "demo_mission.yaml"
    with resources.as_file(ref) as path:
        mission = load_mission(path)
    print(f"pdcov demo: mission {ref.name} ({mission.vehicle_id}); detector model is "
          "ILLUSTRATIVE, not measured")
    g = mission.domain.grid_geometry(mission.cell_size_m)
    scenario = Scenario(mission.domain.free_space, g, mission.domain.free_mask(g),
                        mission.camera, mission.detector, mission.mount,
                        mission.frame_rate_hz, mission.max_range_m, mission.min_revisit_s)
    runs = []
    for pattern in ("lawnmower", "spiral"):
        params = PlanParams(pattern, args.altitude_m, args.speed_mps)
        plan, spacing = build_plan(scenario, params)
        pred = predict(scenario, plan, params)
        run = write_outputs(
            args.out / pattern, mission, pred.grid, mission.origin(),
            title=f"{pattern} at {args.altitude_m:g} m, {args.speed_mps:g} m/s (predicted)",
            track_enu=pred.flight.r_body_enu, plan_enu=plan.xy_enu_m,
            extra_metrics={"flight_time_s": pred.flight.duration_s,
                           "path_length_m": pred.flight.path_length_m,
                           "track_spacing_m": spacing})
        print()
        print(summary_text(run, [f"{pattern}: track spacing {spacing:.1f} m, flight "
                                 f"{pred.flight.duration_s:.0f} s over "
                                 f"{pred.flight.path_length_m:.0f} m"]))
        runs.append((pattern, pred.grid.pd, pred.grid.mask))
    compare_figure(args.out / "compare.png", runs, mission.thresholds)
    print(f"\ncompare: {args.out / 'compare.png'}")
    return 0
