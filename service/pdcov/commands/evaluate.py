"""``pdcov evaluate``, ``pdcov compare`` and ``pdcov footprint``."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pdcov.atomic import replacing_dir
from pdcov.commands.args import (
    finite,
    output_dir,
    output_file,
    positive,
    positive_int,
    probability,
)
from pdcov.commands.mission_file import load_mission_warned
from pdcov.core.blur import describe_blur
from pdcov.errors import PdcovError

if TYPE_CHECKING:
    from pdcov.commands.input_run import InputRun
    from pdcov.core.geodesy import Origin
    from pdcov.core.grid import CoverageGrid


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="coverage of a flown (or simulated) flight",
                       description="Replay camera poses (a pose CSV) or a flight log through "
                                   "the coverage grid and write the run's maps and metrics.")
    p.add_argument("--config", required=True, type=Path, help="mission config YAML")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--poses", type=Path,
                     help="pose CSV: t_s,x_m,y_m,z_m,qw,qx,qy,qz (camera centre ENU m, "
                          "R_enu_cam quaternion)")
    src.add_argument("--log", type=Path, action="append",
                     help="flight log: .tlog, DataFlash .bin, PX4 .ulg; or a folder: every "
                          "such log in it, by name. Repeat it for several flights (the "
                          "sorties of a search): their grids merge into one map")
    p.add_argument("--out", required=True, type=output_dir, help="output folder")
    p.add_argument("--plan", type=Path, help="planned mission (.plan or WPL) to draw")
    p.add_argument("--prior", type=Path,
                   help="probability of area: .npy or GeoTIFF aligned with the grid, or a "
                        "GeoJSON of segments with a 'poa' property")
    p.add_argument("--frame-source", choices=("rate", "capture"),
                   help="frames at the camera rate or at the log's capture events "
                        "(default: the config's log.frame_source; if that is not set, the "
                        "detector frames pdcov serve recorded in the log, else rate)")
    p.add_argument("--export-poses", type=output_file, help="write the camera poses used (CSV)")
    p.add_argument("--outline-threshold", type=probability,
                   help="P_D threshold outlined in the heat map and GeoJSON (default: the "
                        "largest configured threshold)")
    p.add_argument("--basemap", type=Path, metavar="PATH",
                   help="offline basemap under map.png: a folder of XYZ tiles "
                        "({z}/{x}/{y}.png or .jpg) or an .mbtiles file (as watch --basemap)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    spread = p.add_mutually_exclusive_group()
    spread.add_argument("--jobs", type=positive_int,
                        help="several logs: evaluate this many at once, each in its own "
                             "process (default: the number of cores; 1: one after the "
                             "other in this process)")
    spread.add_argument("--dask", metavar="ADDRESS",
                        help="several logs: evaluate them on the Dask cluster whose scheduler "
                             "is at ADDRESS (e.g. tcp://10.0.0.5:8786; the logs and the "
                             "config at the same paths there; pip install 'pdcov[cluster]')")
    p.set_defaults(func=run_evaluate)

    c = sub.add_parser("compare", help="overlay several runs (paper Fig. 8)",
                       description="Compare the proportions of cells reaching each threshold "
                                   "across runs of `pdcov evaluate` or `pdcov plan`.")
    c.add_argument("runs", nargs="+", type=Path, help="run folders")
    c.add_argument("--out", type=output_file, default=Path("compare.png"),
                   help="figure to write")
    c.add_argument("--names", help="comma-separated labels (default: folder names)")
    c.set_defaults(func=run_compare)

    f = sub.add_parser("footprint", help="ray-count footprint of one pose (paper Fig. 5)",
                       description="Draw the per-pixel ray count of the configured camera "
                                   "for a vehicle pose given on the command line.")
    f.add_argument("--config", required=True, type=Path, help="mission config YAML")
    f.add_argument("--altitude-m", type=positive, required=True, help="height above ground")
    f.add_argument("--roll-deg", type=finite, default=0.0, help="vehicle roll")
    f.add_argument("--pitch-deg", type=finite, default=0.0, help="vehicle pitch")
    f.add_argument("--yaw-deg", type=finite, default=0.0, help="vehicle heading")
    f.add_argument("--camera-pitch-deg", type=finite,
                   help="camera pitch against the horizon for a gimbal (default -90: nadir); "
                        "a fixed mount uses the config's angles")
    f.add_argument("--cell-size-m", type=positive, help="cell size (default: the config's)")
    f.add_argument("--pixel-step", type=positive_int, default=1, help="use every n-th pixel")
    f.add_argument("--out", type=output_file, default=Path("footprint.png"),
                   help="figure to write")
    f.set_defaults(func=run_footprint)


def run_evaluate(args: argparse.Namespace) -> int:
    from pdcov.commands.input_run import InputJob, InputKind, run_input
    from pdcov.core.sweep_width import FlightSample
    from pdcov.report.exports import VehicleDetections, VehicleTrack
    from pdcov.report.outputs import metrics_document, summary_text, write_outputs

    mission = load_mission_warned(args.config, "evaluate")
    frame_source = mission.cameras_frame_source(
        args.frame_source or mission.chosen_frame_source,
        "--frame-source" if args.frame_source else
        "log.frame_source" if mission.frame_source_set else "service.frame_source")
    if args.poses is not None:
        if args.export_poses:
            raise PdcovError("--export-poses needs --log (a pose CSV already is one)")
        if args.jobs is not None or args.dask is not None:
            raise PdcovError("--jobs and --dask share out several flight logs (--log); a "
                             "pose CSV is one input")
        paths, kind = [args.poses], InputKind.POSES
    else:
        from pdcov.commands.many_logs import log_paths
        paths, kind = log_paths(args.log), InputKind.LOG
        if len(paths) > 1 and args.export_poses:
            raise PdcovError(f"--export-poses writes the camera poses of one log; "
                             f"{len(paths)} given")
    basemap = None  # opened before the flights: a wrong path fails at once
    if args.basemap is not None:
        from pdcov.ground.basemap import map_tiles, open_basemap
        basemap = map_tiles(open_basemap(args.basemap))
    progress = not args.no_progress
    lines = [f"pdcov evaluate: {args.config}", f"looks: {mission.looks.summary}"]
    jobs = [InputJob(p, kind, frame_source, args.prior, args.export_poses,
                     progress and len(paths) == 1) for p in paths]
    if len(jobs) == 1 and args.dask is None:
        run = run_input(jobs[0], mission)
        grids, runs = run.loaded, [run]
        lines += run.lines
    else:
        from pdcov.commands.many_logs import evaluate_logs
        workers = min(args.jobs or os.cpu_count() or 1, len(jobs))
        merged = evaluate_logs(mission, jobs, workers=workers, dask_address=args.dask,
                               meeting=args.out.with_name(f".{args.out.name}.logs"),
                               progress=progress)
        grids, runs = merged.grids, list(merged.runs)
        lines += _logs_lines(runs, f"on the Dask cluster at {args.dask}" if args.dask
                             else "in this process" if workers == 1
                             else f"in {workers} worker processes")
    grid, first = grids.grid, runs[0]
    if len(runs) > 1:  # the merged grid's frames and their blur
        lines.append(describe_blur(grid.blur_effect, grid.exposure_s, grid.frames_blurred,
                                   grid.frames))
    named = (lambda r, w: w) if len(runs) == 1 else (lambda r, w: f"{r.path.name}: {w}")
    input_warnings = [named(r, w) for r in runs for w in r.input_warnings]
    warnings = [named(r, w) for r in runs for w in r.warnings]
    for w in (*input_warnings, *warnings):  # the mission's were shown when it was loaded
        print(f"pdcov evaluate: WARNING: {w}", file=sys.stderr)
    warnings = [*mission.warnings, *warnings]
    source = (paths[0].name if len(paths) == 1
              else f"{len(paths)} logs ({paths[0].name} to {paths[-1].name})")
    extra: dict[str, Any] = {}
    if input_warnings or warnings:
        extra["warnings"] = [*input_warnings, *warnings]
    if kind is InputKind.LOG:
        extra.update(_logs_metrics(runs))
    if mission.several_cameras:  # each camera's outputs beside the combined grid's
        extra["cameras"] = {name: metrics_document(g.metrics(mission.thresholds))
                            for name, g in grids.cameras.items()}
    track = _joined_tracks([r.track_enu for r in runs])
    detections = _detections(runs, grid)
    plan_enu = _plan_enu(args.plan, first.origin)
    prior = None if first.prior is None else first.prior.poa
    with replacing_dir(args.out) as replaced:
        run_out = write_outputs(args.out, mission, grid, first.origin,
                                title=f"{mission.vehicle_id}: {source}", track_enu=track,
                                plan_enu=plan_enu,
                                outline_threshold=args.outline_threshold, prior=prior,
                                extra_metrics=extra or None,
                                exports=() if detections is None
                                else [VehicleDetections.from_doc(detections)],
                                tracks=[VehicleTrack.from_enu(  # a segment per log
                                    mission.vehicle_id, (r.track_enu for r in runs),
                                    first.origin, heights_msl=kind is InputKind.LOG
                                    or mission.ground_alt_msl_m is not None,
                                    flights_unix_s=[r.track_unix_s for r in runs])],
                                flight=FlightSample.joined(
                                    [r.flight for r in runs if r.flight is not None]),
                                basemap=basemap, progress=progress)
        if detections is not None:
            from pdcov.report.detections import write_detections
            write_detections(args.out, detections)
        for name, g in grids.cameras.items():  # each camera's outputs (several cameras)
            write_outputs(args.out / "cameras" / name, mission, g, first.origin,
                          title=f"{mission.vehicle_id} {name}: {source}", track_enu=track,
                          plan_enu=plan_enu,
                          outline_threshold=args.outline_threshold)
        from pdcov.report.handover import with_report
        run_out = with_report(run_out)
    if replaced:
        lines.append(f"replaced the previous outputs in {args.out}")
    if args.export_poses:
        lines.append(f"camera poses written to {args.export_poses}")
    print(summary_text(run_out, lines + [f"WARNING: {w}" for w in warnings]))
    return 0


def _logs_lines(runs: Sequence[InputRun], how: str) -> list[str]:
    """The summary of several logs merged: each log's lines under its name, then the
    totals of their telemetry faults and skipped frames."""
    from pdcov.flight.log_frames import describe_faults

    lines = []
    for k, run in enumerate(runs, 1):
        lines.append(f"log {k} of {len(runs)}: {run.path}")
        lines += [f"  {x}" for x in run.lines]
    totals = _logs_metrics(runs)
    skipped = totals["frames_skipped"]
    lines += [f"logs: {len(runs)} merged in log order ({how})",
              f"all logs: {describe_faults(totals['telemetry_faults'])}",
              f"all logs: frames skipped: {sum(skipped.values())}"
              + "".join(f", {why} {n}" for why, n in skipped.items())]
    return lines


def _logs_metrics(runs: Sequence[InputRun]) -> dict[str, Any]:
    """metrics.json's telemetry_faults, frames_skipped (every log's counts added), its
    terrain_check (one log's only) and ``logs``: each log's own."""
    faults: Counter[str] = Counter()
    skipped: Counter[str] = Counter()
    logs = []
    for r in runs:
        faults.update(r.telemetry_faults or {})
        skipped.update(r.frames_skipped or {})
        logs.append({"log": str(r.path), "frames": r.frames,
                     "telemetry_faults": r.telemetry_faults,
                     "frames_skipped": r.frames_skipped,
                     "warnings": list(r.input_warnings + r.warnings),
                     **({} if r.terrain_check is None
                        else {"terrain_check": r.terrain_check})})
    doc: dict[str, Any] = {}
    if len(runs) == 1 and runs[0].terrain_check is not None:
        doc["terrain_check"] = runs[0].terrain_check
    return {**doc, "telemetry_faults": dict(faults), "frames_skipped": dict(skipped),
            "logs": logs}


def _joined_tracks(tracks: Sequence[np.ndarray | None]) -> np.ndarray | None:
    """The flown tracks (each (M, 3) ENU m, finite) one after the other; None without any."""
    present = [t for t in tracks if t is not None]
    if len(present) <= 1:
        return present[0] if present else None
    return np.concatenate(present)


def _detections(runs: Sequence[InputRun], grid: CoverageGrid) -> dict[str, Any] | None:
    """The detections document of the run: one log's as it is, several logs' merged
    (report/detections.merged_detections) with ``grid``'s P_D and P_FA; None without any."""
    docs = [r.detections for r in runs]
    if len(runs) == 1 or not any(docs):
        return docs[0]
    from pdcov.report.detections import merged_detections
    return merged_detections([d for d in docs if d], grid)


def _plan_enu(plan: Path | None, origin: Origin) -> np.ndarray | None:
    """The planned mission's waypoints (ENU m, about ``origin``) to draw; None without."""
    if plan is None:
        return None
    from pdcov.planning.plan_files import read_plan
    # Only drawn: a file without a speed command still gives its waypoints.
    return read_plan(plan, origin, default_speed_mps=1.0).xy_enu_m


def run_compare(args: argparse.Namespace) -> int:
    from pdcov.report.outputs import read_run
    from pdcov.report.plots import compare_figure, proportions_at_or_above

    names = args.names.split(",") if args.names else [p.name or str(p) for p in args.runs]
    if len(names) != len(args.runs):
        raise PdcovError(f"--names: {len(names)} labels for {len(args.runs)} runs")
    runs: list = []
    thresholds: tuple[float, ...] = ()
    docs = []
    for name, run_dir in zip(names, args.runs, strict=True):
        doc, pd, mask = read_run(run_dir)
        t = tuple(float(k) for k in doc["proportion_at_or_above"])
        thresholds = thresholds or t
        runs.append((name, pd, mask))
        docs.append(doc)
    width = max(len(n) for n in names)
    print(f"{'run':<{width}}  frames  mean P_D  " + "  ".join(f">= {t:<5g}" for t in thresholds)
          + "  false alarms")
    for (name, pd, mask), doc in zip(runs, docs, strict=True):
        shares = proportions_at_or_above(pd, mask, thresholds)
        print(f"{name:<{width}}  {doc['frames']:>6}  {doc['mean_pd']:>7.3f}  "
              + "  ".join(f"{s:>8.3f}" for s in shares)
              + f"  {doc['expected_false_alarms']:>12.2f}")
    compare_figure(args.out, runs, thresholds)
    print(f"wrote {args.out}")
    return 0


def run_footprint(args: argparse.Namespace) -> int:
    from pdcov.core.domain import GridGeometry
    from pdcov.core.footprint import footprint_polygon, pixel_grid_rays, ray_count_map
    from pdcov.core.grid_camera import default_max_range_m
    from pdcov.core.pose import FixedMount, camera_pose, fixed_mount_pose
    from pdcov.core.rotations import R_from_euler_zyx, Rz
    from pdcov.report.plots import ray_count_figure

    mission = load_mission_warned(args.config, "footprint")
    cam = mission.first_camera
    R_ned_body = R_from_euler_zyx(*np.radians([args.roll_deg, args.pitch_deg, args.yaw_deg]))
    r = np.array([0.0, 0.0, args.altitude_m])
    if isinstance(cam.mount, FixedMount) and args.camera_pitch_deg is None:
        pose = fixed_mount_pose(R_ned_body, r, cam.mount)
        how = "fixed mount"
    else:
        pitch = math.radians(-90.0 if args.camera_pitch_deg is None else args.camera_pitch_deg)
        R_ned_gimbal = Rz(math.radians(args.yaw_deg)) @ R_from_euler_zyx(0.0, pitch, 0.0)
        pose = camera_pose(R_ned_body, r, R_ned_gimbal)
        how = f"camera pitch {math.degrees(pitch):g} deg"
    # The coverage grid's range, without building the grid (its free mask) just to read it.
    max_range_m = mission.max_range_m or default_max_range_m(cam.camera, cam.detector,
                                                             mission.cell_size_m)
    fp = footprint_polygon(cam.camera, pose, max_range_m)
    if fp.is_empty:
        raise PdcovError("the camera sees no ground from this pose")
    cell = args.cell_size_m or mission.cell_size_m
    x0, y0, x1, y1 = fp.bounds
    geometry = GridGeometry(math.floor(x0 / cell) * cell, math.floor(y0 / cell) * cell, cell,
                            math.ceil((y1 - y0) / cell) + 2, math.ceil((x1 - x0) / cell) + 2)
    counts = ray_count_map(pixel_grid_rays(cam.camera, args.pixel_step), pose, geometry,
                           max_range_m)
    outline = np.asarray(fp.exterior.coords)
    ray_count_figure(args.out, counts, geometry, outline, r[:2],
                     title=f"{cam.camera.distortion_model} camera "
                           f"{cam.camera.width_px}x{cam.camera.height_px} at "
                           f"{args.altitude_m:g} m, {how}")
    print(f"footprint area {fp.area:.1f} m^2, {int((counts > 0).sum())} cells hit, "
          f"max {int(counts.max())} rays per cell; wrote {args.out}")
    return 0
