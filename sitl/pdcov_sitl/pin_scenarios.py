"""Scenarios that score pins by person identity (issue 35; docs/simulator.md "Pins scored
by identity"), in memory and in seconds: no JSBSim, no daemon.

A scenario is a square scene, its people (uniform, or groups of 3-5 standing 1.5 m apart),
a camera and mount flown as a lawnmower by pdcov's planner and kinematic model
(planning/trajectory.py: the true camera poses), and a detector model. Each frame, in time
order: the simulated detector (detector.py) draws its boxes from the true pose; the
vehicle's pose, with the GNSS error the autopilot reports (``gnss_sigma_m``, drawn per
frame, the reported ``PositionAccuracy`` beside it), goes to the coverage grid and then to
the tracker (``DetectionTracker.frame(pose, t, boxes, accuracy=..., grid=grid)``), and each
detection it returns is matched back to the person whose box it was. With ``restart`` the
tracker is replaced halfway by a new one loaded from its ``to_doc`` through JSON (the grid
goes on): every candidate must keep its uid and its place. The scores are pin_score.py's.

Pure: no I/O, no clock; a seed fixes the people, every draw and the GNSS error.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

import numpy as np
from shapely.geometry import box

from pdcov.core.camera import CameraModel
from pdcov.core.detections import Candidate
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.geolocate import Geolocation, PositionAccuracy
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose, FixedMount
from pdcov.detection.candidates import DetectionTracker
from pdcov.planning.patterns import lawnmower
from pdcov.planning.trajectory import camera_poses, fly

from .detector import DetectorOptions, SimulatedDetector
from .pin_score import (
    Calibration,
    DetectionOwners,
    FoundShare,
    Merges,
    calibration,
    found_people,
    found_share,
    merges,
    pin_people,
    true_pin_errors_m,
)
from .targets import Targets, on_ground, place_targets

__all__ = ["GROUP_SPACING_M", "RESTART_WITHIN_M", "FlightRecord", "PinScenario",
           "RestartCheck", "Scores", "fly_scenario", "group_people", "noisy", "pin_scenarios",
           "score_flights"]

RESTART_WITHIN_M = 0.5
"""After a restart every candidate lies within this distance of where it was (m)."""
GROUP_SPACING_M = 1.5
"""People of a group stand this far from their neighbours (m)."""
_GROUP_SIZES = (3, 4, 5)
_GROUP_CLEARANCE_M = 8.0  # least distance between two groups' centres (m)
_UID_PREFIX = "score."


@dataclass(frozen=True, slots=True)
class PinScenario:
    """One scene flown once per seed.

    side_m: the square domain's side (m), south-west corner at the ENU origin; cell_m: cell
    side (m); camera: (width_px, height_px, hfov_deg); alt_m: flight height above the flat
    ground; off_nadir_deg: the fixed mount's tilt forward from nadir; spacing_m, speed_mps:
    the lawnmower's tracks and ground speed; rate_hz: camera frames per second;
    min_revisit_s: the grid's and the detector's look interval (s); people: "uniform" or
    "groups"; n_people: people per flight (groups: at least, whole groups); detector: the
    detector model; gnss_sigma_m: (horizontal per axis, vertical) 1-sigma GNSS error, the
    reported accuracy; restart: replace the tracker halfway from its to_doc.
    """

    name: str
    side_m: float
    cell_m: float
    camera: tuple[int, int, float]
    alt_m: float
    off_nadir_deg: float
    spacing_m: float
    speed_mps: float
    rate_hz: float
    min_revisit_s: float
    people: str
    n_people: int
    detector: DetectorModel
    gnss_sigma_m: tuple[float, float] = (0.05, 0.10)
    restart: bool = False

    @property
    def domain(self) -> Domain:
        s = self.side_m
        return Domain.from_enu([[0, 0], [s, 0], [s, s], [0, s]])

    @property
    def camera_model(self) -> CameraModel:
        return CameraModel.from_fov(*self.camera)

    def new_grid(self) -> CoverageGrid:
        """An empty coverage grid of the scene (independent looks, the revisit interval)."""
        g = self.domain.grid_geometry(self.cell_m)
        return CoverageGrid(g, self.domain.free_mask(g), self.camera_model, self.detector,
                            min_revisit_s=self.min_revisit_s)

    def poses(self) -> list[CameraPose]:
        """True camera poses at the frame rate over the whole lawnmower."""
        plan = lawnmower(box(0.0, 0.0, self.side_m, self.side_m), self.spacing_m, 0.0,
                         self.alt_m, self.speed_mps)
        mount = FixedMount(pitch_rad=math.radians(self.off_nadir_deg - 90.0))
        return camera_poses(fly(plan, self.rate_hz), mount)

    def place(self, seed: int) -> Targets:
        """The flight's people for ``seed``."""
        if self.people == "groups":
            return group_people(self.n_people, self.side_m, seed)
        return place_targets(self.n_people, self.domain, None, seed)

    def new_tracker(self, people_per_m2: float) -> DetectionTracker:
        """The tracker as the daemon makes it, with the prior ``people_per_m2`` (the scene's
        true density); the configured GNSS sigmas are the default ones (each frame reports
        its own accuracy)."""
        return DetectionTracker(self.camera_model, Geolocation(), self.cell_m,
                                uid_prefix=_UID_PREFIX, prior_people_per_m2=people_per_m2)


def group_people(n_people: int, side_m: float, seed: int) -> Targets:
    """Groups of 3-5 people (sizes drawn) until at least ``n_people`` stand in a square of
    ``side_m``: a group's centre uniform at least _GROUP_CLEARANCE_M from the others' and
    3 m inside the edges, one person there and the others on the ring of GROUP_SPACING_M
    around it, 60 degrees apart from a random start (neighbours 1.5 m apart)."""
    rng = np.random.default_rng([seed, 0x6A0095])
    centres: list[np.ndarray] = []
    xy: list[np.ndarray] = []
    tries = 0
    while len(xy) < n_people:
        tries += 1
        if tries > 100_000:
            raise ValueError(f"{n_people} people in groups do not fit a {side_m:g} m square")
        c = rng.uniform(3.0, side_m - 3.0, 2)
        if any(np.hypot(*(c - o)) < _GROUP_CLEARANCE_M for o in centres):
            continue
        centres.append(c)
        k = int(rng.choice(_GROUP_SIZES))
        a0 = rng.uniform(0.0, 2 * math.pi)
        xy.append(c)
        for j in range(k - 1):
            angle = a0 + j * math.pi / 3
            xy.append(c + GROUP_SPACING_M * np.array([math.cos(angle), math.sin(angle)]))
    xy_m = np.array(xy)
    return on_ground(xy_m[:, 0], xy_m[:, 1], None)


def noisy(detector: DetectorModel, fa_factor: float, pd_factor: float) -> DetectorModel:
    """``detector`` with its false-alarm rates times ``fa_factor`` and its P_D times
    ``pd_factor``."""
    if detector.fa_rate_per_mpx is None:
        raise ValueError("noisy: the detector model has no fa_rate_per_mpx")
    return dataclasses.replace(
        detector, fa_rate_per_mpx=tuple(r * fa_factor for r in detector.fa_rate_per_mpx),
        p_detect=tuple(min(1.0, p * pd_factor) for p in detector.p_detect))


@dataclass(frozen=True, slots=True)
class RestartCheck:
    """The tracker replaced halfway: ``n_candidates`` it held, ``n_kept`` of them restored
    with the same uid within RESTART_WITHIN_M of where they were, ``max_move_m`` the
    furthest any moved (m); ``n_kept_at_end``: of those candidates, still there at the end of
    the flight with their uid within RESTART_WITHIN_M of where they were at the restart."""

    n_candidates: int
    n_kept: int
    max_move_m: float
    n_kept_at_end: int

    @property
    def ok(self) -> bool:
        return self.n_kept == self.n_candidates


@dataclass(frozen=True, slots=True)
class FlightRecord:
    """One flight of a scenario: its people (N, 3) ENU m, their predicted cumulative P_D
    (N,), the final candidates, which person each detection was (``owners``), whether each
    person was found, the frames flown and the restart check (None: no restart)."""

    scenario: str
    seed: int
    r_people_enu_m: np.ndarray
    p_predicted: np.ndarray
    candidates: list[Candidate]
    owners: DetectionOwners
    found: np.ndarray
    n_frames: int
    restart: RestartCheck | None


def _noisy_pose(pose: CameraPose, sigma_m: tuple[float, float], rng: np.random.Generator
                ) -> CameraPose:
    """``pose`` with its position off by a GNSS error of 1-sigma ``sigma_m`` (horizontal
    per axis, vertical)."""
    h, v = sigma_m
    err = rng.normal(0.0, 1.0, 3) * (h, h, v)
    return CameraPose(pose.R_enu_cam, pose.r_cam_enu + err, pose.t_s, pose.v_cam_enu_m_s,
                      pose.omega_enu_rad_s)


def _restart(tracker: DetectionTracker, fresh: DetectionTracker, grid: CoverageGrid
             ) -> tuple[DetectionTracker, dict[str, np.ndarray], RestartCheck]:
    """The ``fresh`` tracker loaded from ``tracker``'s document through JSON, the candidates'
    places at the restart (by uid) and the check of the restored ones."""
    before = {c.uid: c.r_enu_m[:2] for c in tracker.candidates(grid)}
    restored = fresh
    restored.load_doc(json.loads(json.dumps(tracker.to_doc())))
    after = {c.uid: c.r_enu_m[:2] for c in restored.candidates(grid)}
    moves = [float(np.hypot(*(after[u] - r))) if u in after else math.inf
             for u, r in before.items()]
    kept = sum(m <= RESTART_WITHIN_M for m in moves)
    return restored, before, RestartCheck(len(before), kept, max(moves, default=0.0), 0)


def fly_scenario(sc: PinScenario, seed: int, poses: list[CameraPose] | None = None
                 ) -> FlightRecord:
    """Fly ``sc`` once with ``seed`` (module docstring); ``poses``: its true camera poses,
    when already computed (``sc.poses()``)."""
    poses = sc.poses() if poses is None else poses
    people = sc.place(seed)
    grid = sc.new_grid()
    detector = SimulatedDetector(grid, people, DetectorOptions(look_interval_s=sc.min_revisit_s),
                                 seed)
    rho = len(people) / sc.side_m**2
    tracker = sc.new_tracker(rho)
    accuracy = PositionAccuracy(*sc.gnss_sigma_m)
    rng = np.random.default_rng([seed, 0x6E55])
    parts: list[DetectionOwners] = []
    halfway = len(poses) // 2 if sc.restart else -1
    at_restart: dict[str, np.ndarray] = {}
    check = None
    for k, true_pose in enumerate(poses):
        t = float(true_pose.t_s)
        sim = detector.frame(true_pose, t)
        pose = _noisy_pose(true_pose, sc.gnss_sigma_m, rng)
        grid.update(pose, t)
        person_of = {d.box: d.person_id for d in sim}
        found = tracker.frame(pose, t, [d.box for d in sim], accuracy=accuracy, grid=grid)
        if found:
            parts.append(DetectionOwners(np.array([d.candidate_id for d in found]),
                                         np.full(len(found), k),
                                         np.array([person_of[d.box] for d in found])))
        if k == halfway:
            tracker, at_restart, check = _restart(tracker, sc.new_tracker(rho), grid)
    candidates = tracker.candidates(grid)
    if check is not None:
        end = {c.uid: c.r_enu_m[:2] for c in candidates}
        n_end = sum(u in end and float(np.hypot(*(end[u] - r))) <= RESTART_WITHIN_M
                    for u, r in at_restart.items())
        check = dataclasses.replace(check, n_kept_at_end=n_end)
    owners = DetectionOwners.concat(parts)
    r = people.r_enu_m
    rows, cols = grid.geometry.cell_of(r[:, 0], r[:, 1])
    return FlightRecord(sc.name, seed, r, np.asarray(grid.pd[rows, cols], dtype=float),
                        candidates, owners, found_people(owners, candidates, r), len(poses),
                        check)


def pin_scenarios(smoke: bool = False) -> dict[str, PinScenario]:
    """The scenarios of issue 35's check: sparse, dense groups, oblique, restart and a
    noisy detector (``smoke``: smaller scenes, for CI)."""
    illustrative = DetectorModel.illustrative()
    demo_cam = (640, 480, 67.4)   # the demo's camera: f = 480 px; 2.1 cm/px at 10 m
    side = 40.0 if smoke else 80.0
    n = 30 if smoke else 150
    sparse = PinScenario("sparse", side, 1.0, demo_cam, 12.0, 0.0, 8.0, 4.0, 5.0, 1.0,
                         "uniform", n, illustrative)
    found = [
        sparse,
        PinScenario("dense groups", side, 1.0, demo_cam, 10.0, 0.0, 7.0, 3.0, 5.0, 1.0,
                    "groups", n, illustrative),
        PinScenario("oblique", side, 1.0, demo_cam, 15.0, 45.0, 12.0, 4.0, 5.0, 1.0,
                    "uniform", n, illustrative),
        dataclasses.replace(sparse, name="restart", restart=True),
        # Tracks closer and slower than sparse's: every place is looked at ~10 times, so a
        # false pin is seen again and again without a hit (p_person <= 0.1 gets pins).
        dataclasses.replace(sparse, name="noisy detector", spacing_m=6.0, speed_mps=3.0,
                            detector=noisy(illustrative, 30.0, 0.7)),
    ]
    return {s.name: s for s in found}


@dataclass(frozen=True, slots=True)
class Scores:
    """A scenario's figures pooled over its flights: people ``found`` against the
    prediction, ``merges``, ``n_pins`` and of them ``n_hits_over_looks`` with more hits than
    looks, the ``calibration`` of p_person, ``n_true_pins`` that are people and the 90th
    percentile of their distance to their person ``error_p90_m`` (m), and each flight's
    restart check (None: the scenario restarts nothing)."""

    found: FoundShare
    merges: Merges
    n_pins: int
    n_hits_over_looks: int
    calibration: Calibration
    n_true_pins: int
    error_p90_m: float
    restarts: list[RestartCheck] | None


def score_flights(records: list[FlightRecord]) -> Scores:
    """The figures of ``records`` (one scenario's flights), pooled."""
    found, p_pred, p_person, is_person, errors = [], [], [], [], []
    n_two, n_with, n_one_frame, over = 0, 0, 0, 0
    for rec in records:
        ids = np.array([c.candidate_id for c in rec.candidates], dtype=np.int64)
        yes, person, _ = pin_people(rec.owners, ids)
        m = merges(rec.owners, ids)
        n_two, n_with = n_two + m.n_two_people, n_with + m.n_pins
        n_one_frame += m.n_two_boxes_one_frame
        over += sum(c.hits > c.looks for c in rec.candidates)
        found.append(rec.found)
        p_pred.append(rec.p_predicted)
        p_person.append([c.p_person for c in rec.candidates])
        is_person.append(yes)
        errors.append(true_pin_errors_m(rec.candidates, person, yes, rec.r_people_enu_m))
    err = np.concatenate(errors)
    restarts = [r.restart for r in records if r.restart is not None]
    return Scores(found_share(np.concatenate(found), np.concatenate(p_pred)),
                  Merges(n_with, n_two, n_one_frame),
                  sum(len(r.candidates) for r in records), over,
                  calibration(np.concatenate(p_person), np.concatenate(is_person)),
                  len(err), float(np.percentile(err, 90)) if len(err) else math.nan,
                  restarts or None)
