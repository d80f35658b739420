"""``pdcov evaluate``, ``pdcov compare`` and ``pdcov footprint``."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Mapping, Sequence
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
from pdcov.errors import ConfigError, InputFileError, PdcovError

if TYPE_CHECKING:
    from pdcov.config.mission import Mission
    from pdcov.core.grid import CoverageGrid
    from pdcov.core.pose import CameraPose
    from pdcov.telemetry.logs import FlightLog


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="coverage of a flown (or simulated) flight",
                       description="Replay camera poses (a pose CSV) or a flight log through "
                                   "the coverage grid and write the run's maps and metrics.")
    p.add_argument("--config", required=True, type=Path, help="mission config YAML")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--poses", type=Path,
                     help="pose CSV: t_s,x_m,y_m,z_m,qw,qx,qy,qz (camera centre ENU m, "
                          "R_enu_cam quaternion)")
    src.add_argument("--log", type=Path, help="flight log: .tlog, DataFlash .bin, PX4 .ulg")
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
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
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
    from pdcov.core.combine_cameras import combine_cameras
    from pdcov.core.mount import GimbalMount
    from pdcov.flight.frame_decision import framing_of
    from pdcov.flight.log_frames import poses_of_log
    from pdcov.report.exports import VehicleDetections
    from pdcov.report.output_extent import check_prior_fits
    from pdcov.report.outputs import (
        evaluate_poses,
        finite_track,
        metrics_document,
        read_prior,
        summary_text,
        write_outputs,
    )
    from pdcov.telemetry.frame_policy import below_min_height
    from pdcov.telemetry.logs import read_flight_log
    from pdcov.telemetry.pose_csv import read_pose_csv, write_pose_csv
    from pdcov.telemetry.terrain_check import terrain_check_for

    mission = load_mission_warned(args.config, "evaluate")
    frame_source = mission.cameras_frame_source(
        args.frame_source or mission.chosen_frame_source,
        "--frame-source" if args.frame_source else
        "log.frame_source" if mission.frame_source_set else "service.frame_source")
    terrain_check = None
    progress = not args.no_progress
    lines = [f"pdcov evaluate: {args.config}"]
    log_warnings: tuple[str, ...] = ()
    flight_log: FlightLog | None = None
    # The first camera's frames are the run's (its track, boxes and summary lines); every
    # camera's grid is evaluated, and several combined (Mission.several_cameras).
    first = mission.first_camera
    if args.poses is not None:
        if args.export_poses:
            raise PdcovError("--export-poses needs --log (a pose CSV already is one)")
        zoom = mission.only_camera(
            args.poses, f"the mission lists {len(mission.cameras)} cameras; a pose CSV holds "
            "one camera's poses: give the flight log (--log)").zoom
        if zoom is not None:
            raise PdcovError(f"{args.poses}: camera.zoom {zoom.lens.quantity} follows "
                             "the camera's zoom reports, which a pose CSV does not hold: give "
                             "the flight log (--log), or set camera.zoom none")
        log_poses = None
        poses: Sequence[CameraPose] = read_pose_csv(args.poses)
        origin = mission.origin()
        track = np.array([p.r_cam_enu for p in poses]) if poses else None
        lines.append(f"poses: {args.poses} ({len(poses)} frames)")
        if mission.ground_alt_msl_m is None:
            lines.append("origin.ground_alt_msl_m not set: ENU heights in the CSV are taken "
                         "as heights above the ground")
    else:
        terrain_check = terrain_check_for(mission)
        mount = first.mount
        flight_log = read_flight_log(  # once, for every camera
            args.log, system_id=mission.system_id,
            gimbal_instance=mount.instance if isinstance(mount, GimbalMount) else 1)
        log_poses = poses_of_log(
            flight_log, framing_of(first, mission, frame_source),
            origin_lat_deg=mission.origin_lat_deg, origin_lon_deg=mission.origin_lon_deg,
            ground_alt_msl_m=mission.ground_alt_msl_m, progress=progress,
            ground_alt_how=mission.ground_alt_how, terrain_check=terrain_check)
        poses, origin, track = log_poses.poses, log_poses.origin, log_poses.track_enu
        lines += list(log_poses.summary_lines)  # its warnings among them
        log_warnings = log_poses.warnings
        if terrain_check is not None:  # the daemon's terrain_check, over the same samples
            refusal = terrain_check.home_refusal()
            if refusal is not None:  # the daemon counts no frame over this DEM either
                raise ConfigError(f"{args.log}: {refusal}")
            lines.append(terrain_check.summary_line())
            if terrain_check.mismatches:
                log_warnings += (terrain_check.summary_line(),)
    lines.append(f"looks: {mission.looks.summary}")
    _check_near_origin(poses, args.poses or args.log, mission.source)
    n_read = len(poses)
    top_m = max((float(p.r_cam_enu[2]) for p in poses), default=math.nan)
    # The daemon's filter: the log's frames marked by frame_selection, a CSV's poses by
    # frame_policy.below_min_height.
    high = (~log_poses.low if log_poses is not None else
            ~np.array([below_min_height(p.r_cam_enu[2], mission.min_height_m)
                       for p in poses], bool))
    low = int((~high).sum())
    cameras = log_poses.cameras if log_poses is not None else ()
    accuracies = log_poses.accuracies if log_poses is not None else ()
    if low:
        poses = [p for p, h in zip(poses, high, strict=True) if h]
        cameras = tuple(c for c, h in zip(cameras, high, strict=False) if h)
        accuracies = tuple(a for a, h in zip(accuracies, high, strict=False) if h)
        lines.append(f"{low} frames with the camera below coverage.min_height_m = "
                     f"{mission.min_height_m:g} m not evaluated (on the ground or taking off)")
    if not poses:
        print("\n".join(lines))
        raise InputFileError(f"{args.poses or args.log}: no camera frame to evaluate: "
                             + _why_no_frame(n_read, top_m, mission.min_height_m))
    plan_enu = None
    if args.plan is not None:
        from pdcov.planning.plan_files import read_plan
        # Only drawn: a file without a speed command still gives its waypoints.
        plan_enu = read_plan(args.plan, origin, default_speed_mps=1.0).xy_enu_m
    grid = mission.new_mission_grid()
    per_camera = mission.camera_grids(grid)
    if args.prior is not None:
        check_prior_fits(grid.geometry)
    prior = (read_prior(args.prior, grid.geometry, grid.mask, origin)
             if args.prior is not None else None)
    if prior is not None:
        lines.extend(prior.notes)
    own = per_camera[first.name]
    evaluate_poses(own, poses, progress=progress, total=len(poses), cameras=cameras)
    lines.append(describe_blur(own.blur_effect, own.exposure_s, own.frames_blurred,
                               own.frames))
    if flight_log is not None:
        _other_cameras(flight_log, mission, per_camera, frame_source, lines)
    # Each camera's looks in the same cells, by the one rule the daemon applies too.
    combine_cameras(grid, list(per_camera.values()))
    detections = None
    if log_poses is not None and log_poses.frame_boxes:
        from pdcov.ids import candidate_uid_prefix
        from pdcov.report.detections import flight_detections, log_epoch
        detections = flight_detections(
            mission, grid, origin, poses, log_poses.frame_boxes, cameras, accuracies,
            uid_prefix=candidate_uid_prefix(mission.vehicle_id, log_epoch(args.log)),
            poa=None if prior is None else prior.poa)
        lines.append(f"detections: {len(detections['detections'])} of the boxes pdcov serve "
                     f"recorded, in {len(detections['candidates'])} candidates")
    warnings = _unseen_domain_warnings(grid, mission, poses)
    for w in (*log_warnings, *warnings):  # the mission's were shown when it was loaded
        print(f"pdcov evaluate: WARNING: {w}", file=sys.stderr)
    warnings = [*mission.warnings, *warnings]
    # The per-frame poses are done with: free them before writing the outputs (the peak).
    del poses
    source = (args.poses or args.log).name
    extra: dict[str, Any] = {}
    if log_warnings or warnings:
        extra["warnings"] = [*log_warnings, *warnings]
    if terrain_check is not None:
        extra["terrain_check"] = terrain_check.as_dict()
    if log_poses is not None:  # the bad telemetry counted, as the daemon's status faults
        extra["telemetry_faults"] = dict(log_poses.faults)
        extra["frames_skipped"] = dict(log_poses.frames_skipped)
    if mission.several_cameras:  # each camera's outputs beside the combined grid's
        extra["cameras"] = {name: metrics_document(g.metrics(mission.thresholds))
                            for name, g in per_camera.items()}
    with replacing_dir(args.out) as replaced:
        run = write_outputs(args.out, mission, grid, origin,
                            title=f"{mission.vehicle_id}: {source}",
                            track_enu=finite_track(track), plan_enu=plan_enu,
                            outline_threshold=args.outline_threshold,
                            prior=None if prior is None else prior.poa,
                            extra_metrics=extra or None,
                            exports=() if detections is None
                            else [VehicleDetections.from_doc(detections)])
        if detections is not None:
            from pdcov.report.detections import write_detections
            write_detections(args.out, detections)
        if mission.several_cameras:  # each camera's outputs beside the combined grid's
            for name, g in per_camera.items():
                write_outputs(args.out / "cameras" / name, mission, g, origin,
                              title=f"{mission.vehicle_id} {name}: {source}",
                              track_enu=finite_track(track), plan_enu=plan_enu,
                              outline_threshold=args.outline_threshold)
    if replaced:
        lines.append(f"replaced the previous outputs in {args.out}")
    if log_poses is not None and args.export_poses:
        write_pose_csv(args.export_poses, log_poses)
        lines.append(f"camera poses written to {args.export_poses}")
    print(summary_text(run, lines + [f"WARNING: {w}" for w in warnings]))
    return 0


def _other_cameras(log: FlightLog, mission: Mission, grids: Mapping[str, CoverageGrid],
                   frame_source: str | None, lines: list[str]) -> None:
    """Evaluate into ``grids`` (by name) the mission's cameras after the first, each from
    the frames of the ``log`` read once (its own gimbal device's reports) at its own rate,
    with its own mount, zoom and detector (the mission's frame rules)."""
    from pdcov.core.mount import GimbalMount
    from pdcov.flight.frame_decision import framing_of
    from pdcov.flight.log_frames import poses_of_log
    from pdcov.report.outputs import evaluate_poses
    from pdcov.telemetry.logs import for_gimbal

    for cam in mission.cameras:
        if cam is mission.first_camera:
            continue
        lp = poses_of_log(
            for_gimbal(log, cam.mount.instance) if isinstance(cam.mount, GimbalMount) else log,
            framing_of(cam, mission, frame_source), origin_lat_deg=mission.origin_lat_deg,
            origin_lon_deg=mission.origin_lon_deg, ground_alt_msl_m=mission.ground_alt_msl_m,
            ground_alt_how=mission.ground_alt_how)
        grid = grids[cam.name]
        evaluate_poses(grid, [p for p, low in zip(lp.poses, lp.low, strict=True) if not low],
                       cameras=[c for c, low in zip(lp.cameras, lp.low, strict=False)
                                if not low])
        lines.append(f"camera {cam.name}: {grid.frames} frames "
                     f"({next((x for x in lp.summary_lines if x.startswith('frames:')), '')})")


def _why_no_frame(n_read: int, top_m: float, min_height_m: float) -> str:
    """Why no frame is left to evaluate, in words."""
    if n_read == 0:
        return "the input gave no camera pose (see the frames line above for what was skipped)"
    return (f"all {n_read} frames below coverage.min_height_m = {min_height_m:g} m (the "
            f"highest camera was {top_m:.2f} m above the ground; check "
            "origin.ground_alt_msl_m, or lower coverage.min_height_m)")


def _unseen_domain_warnings(grid: CoverageGrid, mission: Mission,
                            poses: Sequence[CameraPose]) -> list[str]:
    """A warning when no frame saw a free cell of the domain, with the horizontal distance
    from the camera track to the domain (the usual cause: a wrong origin)."""
    if grid.metrics(()).cells_observed:  # tile by tile: a county's grid is never read whole
        return []
    import shapely

    track = shapely.MultiPoint([p.r_cam_enu[:2] for p in poses])
    dist_m = float(shapely.distance(mission.domain.free_space, track))
    if dist_m > 0:
        where_ = (f"the camera came no closer than {dist_m:,.0f} m (horizontally) to the "
                  f"domain; check origin.lat_deg / origin.lon_deg in {mission.source} and "
                  "the input's positions")
    else:
        where_ = ("the camera passed over the domain but saw none of it: check the camera "
                  "attitude (mount), the heights, and coverage.max_range_m "
                  f"({grid.max_range_m:.0f} m)")
    return [f"no frame observed any of the {grid.n_free} free cells of the domain: "
            f"{where_}"]


def _check_near_origin(poses, source: Path, config: str | None) -> None:
    """A flight tens of km from the origin is a wrong origin, not a survey: say so."""
    if not poses:
        return
    xy = np.array([p.r_cam_enu[:2] for p in poses])
    dist_km = float(np.median(np.hypot(xy[:, 0], xy[:, 1]))) / 1000
    if dist_km > 50:
        raise InputFileError(
            f"{source}: the camera is {dist_km:,.0f} km from the mission origin; "
            f"check origin.lat_deg / origin.lon_deg in {config}")


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
