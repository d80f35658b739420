"""``pdcov demo``: the paper's scene on the bundled example mission, live (simulator, daemon,
watcher on loopback) or ``--offline`` (planned lawnmower and spiral compared)."""

from __future__ import annotations

import argparse
from importlib import resources

from pdcov.atomic import replacing_dir
from pdcov.commands.args import output_dir, positive
from pdcov.config.load import load_mission
from pdcov.config.mission import Mission
from pdcov.extras import DEMO


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo", help="the whole system live on this machine (or --offline: compare plans)",
        description="Live (default): on loopback, a Zenoh router, the simulator flying a "
                    "spiral over the paper's 40 x 40 m scene at 10 m (5 frames/s camera, "
                    "the ILLUSTRATIVE detector model), the onboard daemon (`pdcov serve`) "
                    "and the watcher (`pdcov watch`) showing the coverage climbing; then "
                    "the report. --offline: plan a lawnmower and a spiral, fly them "
                    "kinematically, evaluate and compare them (the paper's Figs. 7 and 8).")
    p.add_argument("--out", type=output_dir, default="pdcov-demo",
                   help="output folder, replaced whole when the demo finishes (default "
                        "pdcov-demo)")
    p.add_argument("--altitude-m", type=positive, default=10.0, help="flight height")
    p.add_argument("--speed-mps", type=positive, default=5.0, help="flight speed")
    p.add_argument("--speed", type=positive, default=8.0, metavar="N",
                   help="live: simulate N times faster than real time (default 8: about a "
                        "minute)")
    p.add_argument("--vehicles", type=int, choices=(1, 2), default=1,
                   help="live: 1 drone (spiral) or 2 (a spiral over each half)")
    p.add_argument("--web", nargs="?", const="127.0.0.1:8080", metavar="HOST:PORT",
                   help="live: also show the map in the browser (default 127.0.0.1:8080; "
                        "open the address printed, its access token included)")
    p.add_argument("--plain", action="store_true",
                   help="live: print a line per change instead of the live table")
    p.add_argument("--offline", action="store_true",
                   help="compare a lawnmower and a spiral without flying (no processes)")
    p.set_defaults(func=run_demo)


def _bundled_mission() -> tuple[Mission, dict]:
    from pdcov.yaml_file import load_yaml

    ref = resources.files("pdcov") / "data" / "demo_mission.yaml"
    with resources.as_file(ref) as path:
        return load_mission(path), load_yaml(path, "mission config")


def run_demo(args: argparse.Namespace) -> int:
    return run_offline(args) if args.offline else run_live(args)


def run_live(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from shapely.geometry import box

    from pdcov.commands.plan import scenario_of
    from pdcov.ground.app import parse_web_address, stdout_is_terminal
    from pdcov.ground.demo import DemoVehicle, LiveDemo, run_live_demo
    from pdcov.planning.optimise import PlanParams, build_plan
    from pdcov.planning.plan import write_plan

    DEMO.require()
    web = parse_web_address(args.web) if args.web else None
    mission, doc = _bundled_mission()
    print(f"pdcov demo: live, {args.vehicles} vehicle(s), {args.speed:g}x real time; "
          "detector model is ILLUSTRATIVE, not measured; Ctrl-C stops everything",
          flush=True)
    scenario = scenario_of(mission)
    free = scenario.free_space
    x0, y0, x1, y1 = free.bounds
    if args.vehicles == 1:
        areas = [free]
    else:  # a west and an east half, one spiral each
        xm = 0.5 * (x0 + x1)
        areas = [free.intersection(box(x0, y0, xm, y1)), free.intersection(box(xm, y0, x1, y1))]
    # The children write into a fresh folder that replaces the previous one only when the
    # demo has finished (an error or Ctrl-C puts the previous one back).
    with replacing_dir(args.out) as replaced:
        vehicles = []
        for k, area in enumerate(areas, start=1):
            plan, _ = build_plan(replace(scenario, free_space=area),
                                 PlanParams("spiral", args.altitude_m, args.speed_mps))
            path = args.out / "plans" / f"uav{k}.plan"
            path.parent.mkdir(parents=True, exist_ok=True)
            write_plan(path, plan, mission.origin())
            vehicles.append(DemoVehicle(f"uav{k}", k, path))
        run_live_demo(LiveDemo(args.out, doc, tuple(vehicles), speed=args.speed, web=web,
                               plain=args.plain or not stdout_is_terminal()))
    if replaced:
        print(f"replaced the previous outputs in {args.out}")
    return 0


def run_offline(args: argparse.Namespace) -> int:
    from pdcov.commands.plan import scenario_of, write_prediction
    from pdcov.planning.optimise import PlanParams, build_plan, predict
    from pdcov.report.plots import compare_figure

    mission, _ = _bundled_mission()
    print(f"pdcov demo: mission demo_mission.yaml ({mission.vehicle_id}); detector model is "
          "ILLUSTRATIVE, not measured")
    scenario = scenario_of(mission)
    runs = []
    with replacing_dir(args.out) as replaced:
        for pattern in ("lawnmower", "spiral"):
            params = PlanParams(pattern, args.altitude_m, args.speed_mps)
            plan, spacing = build_plan(scenario, params)
            pred = predict(scenario, plan, params)
            print()
            print(write_prediction(args.out / pattern, mission, pred, pred.grid,
                                   f"{pattern} at {args.altitude_m:g} m, {args.speed_mps:g} "
                                   "m/s (predicted)", spacing))
            runs.append((pattern, pred.grid.pd, pred.grid.mask))
        compare_figure(args.out / "compare.png", runs, mission.thresholds)
    print(f"\ncompare: {args.out / 'compare.png'}")
    if replaced:
        print(f"replaced the previous outputs in {args.out}")
    return 0
