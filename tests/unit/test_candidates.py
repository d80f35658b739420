"""The candidate (pin) rule of detection/candidates.py on a grid that takes the frames:
distinct candidates, the gate from the reported accuracy, hits per look, p_person and
durable state."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.geolocate import Geolocation, PositionAccuracy
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import LooksConfig, LooksRule
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.detection.association import GATE_FLOOR_M
from pdcov.detection.candidates import DetectionTracker

F_PX = 500.0
CAMERA = CameraModel(640, 480, np.array([[F_PX, 0, 319.5], [0, F_PX, 239.5], [0, 0, 1]]))
H_M = 10.0
PX_PER_M = F_PX / H_M  # 50 px per m at nadir from 10 m
DETECTOR = DetectorModel.from_dict({
    "version": 4, "bin_edges_px": [1, 20, 40, 80, 2000], "p_detect": [0.1, 0.4, 0.6, 0.3],
    "p_false_alarm": [0.05, 0.1, 0.2, 0.3], "fa_rate_per_mpx": [20.0, 40.0, 80.0, 120.0],
    "input_size_px": None, "looks": {"correlation": [0.2, 0.2, 0.2, 0.2]}})
ACCURATE = PositionAccuracy(0.04, 0.08)  # an RTK-like fix


def grid(min_revisit_s=None, looks=None) -> CoverageGrid:
    dom = Domain.from_enu([[-20, -20], [20, -20], [20, 20], [-20, 20]])
    g = dom.grid_geometry(1.0)
    return CoverageGrid(g, dom.free_mask(g), CAMERA, DETECTOR, min_revisit_s=min_revisit_s,
                        looks=looks)


def tracker(**kw) -> DetectionTracker:
    return DetectionTracker(CAMERA, Geolocation(pixel_sigma_px=1.0), 1.0,
                            uid_prefix="uav1.ab12cd.", **kw)


def nadir(t_s: float):
    return fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, 0.0), np.array([0.5, 0.5, H_M]),
                            FixedMount(), t_s)


def person_at(x_m: float, y_m: float, rng=None, conf=0.8) -> Box:
    """A 20 x 40 px standing person whose feet are at ENU (x_m, y_m) under ``nadir`` (image
    x east, y south), the feet's pixel with 1 px noise when ``rng`` is given."""
    dx, dy = (0.0, 0.0) if rng is None else rng.normal(0.0, 1.0, 2)
    u = 319.5 + (x_m - 0.5) * PX_PER_M + dx
    v = 239.5 - (y_m - 0.5) * PX_PER_M + dy
    return Box("person", conf, u - 10.0, v - 40.0, 20.0, 40.0)


def fly(t: DetectionTracker, g: CoverageGrid, times, boxes_of, accuracy=ACCURATE):
    """Each frame: the grid takes it, then the tracker; the detections per frame."""
    out = []
    for k, t_s in enumerate(times):
        pose = nadir(t_s)
        g.update(pose)
        out.append(t.frame(pose, t_s, boxes_of(k), accuracy=accuracy, grid=g))
    return out


def test_two_people_1_5_m_apart_stay_two_candidates():
    rng = np.random.default_rng(3)
    t, g = tracker(), grid()
    frames = fly(t, g, [0.2 * k for k in range(20)],
                 lambda k: [person_at(0.2, 0.3, rng), person_at(1.7, 0.3, rng)])
    cands = t.candidates(g)
    assert len(cands) == 2
    assert [[d.candidate_id for d in f] for f in frames] == [[0, 1]] * 20
    np.testing.assert_allclose([c.r_enu_m[0] for c in cands], [0.2, 1.7], atol=0.05)
    # No revisit clock: every frame a look of both cells, each with a box.
    assert [(c.hits, c.looks) for c in cands] == [(20, 20), (20, 20)]
    assert [c.uid for c in cands] == ["uav1.ab12cd.0", "uav1.ab12cd.1"]


def test_two_boxes_of_one_frame_never_share_a_candidate():
    t, g = tracker(), grid()
    # 0.1 m apart, both within the gate of either candidate: one box each, every frame.
    frames = fly(t, g, [0.0, 0.2, 0.4],
                 lambda k: [person_at(0.3, 0.3), person_at(0.4, 0.3)])
    for f in frames:
        ids = [d.candidate_id for d in f]
        assert len(set(ids)) == len(ids) == 2
    assert len(t) == 2
    # One box alone joins the nearest, the other candidate misses that look.
    (d,) = fly(t, g, [0.6], lambda k: [person_at(0.41, 0.3)])[0]
    assert d.candidate_id == 1
    a, b = t.candidates(g)
    assert (a.hits, a.looks, b.hits, b.looks) == (3, 4, 4, 4)


def test_hits_never_exceed_looks_on_the_revisit_clock():
    t, g = tracker(), grid(min_revisit_s=1.0)
    for k in range(20):  # 5 fps for 4 s: looks at 0, 1, 2, 3 s
        fly(t, g, [0.2 * k], lambda _: [person_at(0.3, 0.3)])
        (c,) = t.candidates(g)
        assert c.hits <= c.looks == k // 5 + 1
    assert (c.hits, c.looks) == (4, 4) and g.n_obs[20, 20] == 4
    # A box only between looks makes the last look a hit once: 5 looks, 5 hits.
    fly(t, g, [4.0, 4.2, 4.4], lambda k: [] if k == 0 else [person_at(0.3, 0.3)])
    (c,) = t.candidates(g)
    assert (c.hits, c.looks) == (5, 5)


def test_p_person_rises_with_hits_and_falls_with_misses():
    t, g = tracker(), grid(min_revisit_s=1.0)
    seen = []
    for k in range(3):
        fly(t, g, [float(k)], lambda _: [person_at(0.3, 0.3)])
        seen.append(t.candidates(g)[0].p_person)
    missed = []
    for k in range(3, 13):
        fly(t, g, [float(k)], lambda _: [])
        missed.append(t.candidates(g)[0].p_person)
    assert seen == sorted(seen) and seen[0] < seen[-1]
    assert missed == sorted(missed, reverse=True) and missed[-1] < missed[0]
    (c,) = t.candidates(g)
    assert (c.hits, c.looks) == (3, 13)
    # By hand: the centre cell is 50 px (P_D 0.6); each miss multiplies the odds by 0.4.
    odds = [p / (1 - p) for p in missed]
    assert odds[1] / odds[0] == pytest.approx(0.4, rel=1e-5)


def test_a_candidate_born_after_looks_counts_them_as_misses():
    t, g = tracker(), grid(min_revisit_s=1.0)
    fly(t, g, [0.0, 1.0, 2.0], lambda k: [])
    fly(t, g, [3.0], lambda k: [person_at(0.3, 0.3)])
    (c,) = t.candidates(g)
    assert (c.hits, c.looks) == (1, 4)
    # Its twin seen at the first look only has the same looks: 3 misses after its hit.
    twin_t, twin_g = tracker(), grid(min_revisit_s=1.0)
    fly(twin_t, twin_g, [0.0, 1.0, 2.0, 3.0], lambda k: [person_at(0.3, 0.3)] if k == 0 else [])
    (twin,) = twin_t.candidates(twin_g)
    assert (twin.hits, twin.looks) == (1, 4)
    assert c.p_person == pytest.approx(twin.p_person, rel=1e-5)


def test_correlated_looks_lose_less_per_miss_than_independent_ones():
    ps = {}
    for rule in (LooksRule.INDEPENDENT, LooksRule.CORRELATED):
        t, g = tracker(), grid(min_revisit_s=1.0, looks=LooksConfig(rule))
        fly(t, g, [float(k) for k in range(8)],
            lambda k: [person_at(0.3, 0.3)] if k < 2 else [])
        (c,) = t.candidates(g)
        assert (c.hits, c.looks) == (2, 8)
        ps[rule] = c.p_person
    # A person missed again and again is likely hard to see: the misses say less.
    assert ps[LooksRule.CORRELATED] > ps[LooksRule.INDEPENDENT]


def key(c):
    """Every field of a candidate, its position as a list."""
    return (c.uid, c.candidate_id, c.hits, c.looks, c.p_person, c.pd, c.pfa, c.sigma_m,
            c.r_enu_m.tolist(), c.confidence, c.first_t_boot_s, c.last_t_boot_s)


def test_a_restored_tracker_continues_as_its_twin():
    rng = np.random.default_rng(5)
    boxes = [[person_at(0.3, 0.3, rng), person_at(3.0, -2.0, rng)] for _ in range(12)]
    boxes += [[person_at(0.3, 0.3, rng), person_at(-4.0, 1.0, rng)] for _ in range(12)]
    times = [0.25 * k for k in range(24)]
    a, ga = tracker(), grid(min_revisit_s=1.0, looks=LooksConfig(LooksRule.CORRELATED))
    fly(a, ga, times[:12], lambda k: boxes[k])
    doc = json.loads(json.dumps(a.to_doc()))
    b, gb = tracker(), copy.deepcopy(ga)
    b.load_doc(doc)
    assert b.next_id == a.next_id == 2
    assert [key(c) for c in b.candidates(gb)] == [key(c) for c in a.candidates(ga)]
    fly(a, ga, times[12:], lambda k: boxes[12 + k])
    fly(b, gb, times[12:], lambda k: boxes[12 + k])
    ca, cb = a.candidates(ga), b.candidates(gb)
    assert [c.uid for c in cb] == ["uav1.ab12cd.0", "uav1.ab12cd.1", "uav1.ab12cd.2"]
    assert [key(c) for c in ca] == [key(c) for c in cb]
    # A journal's entry applied over the checkpoint gives the same state.
    c = tracker()
    c.load_doc(doc)
    c.apply_candidate_docs(json.loads(json.dumps(a.candidate_docs([0, 2]))), a.next_id)
    c.apply_candidate_docs(a.candidate_docs([1]), a.next_id)
    assert c.to_doc() == a.to_doc()


def test_a_bad_state_is_refused_naming_the_field():
    t, g = tracker(), grid()
    fly(t, g, [0.0], lambda k: [person_at(0.3, 0.3)])
    doc = t.to_doc()
    bad = json.loads(json.dumps(doc))
    bad["candidates"][0]["hits"] = 5
    with pytest.raises(ValueError, match=r"candidates\[0\]\.hits 5: more than its looks 1"):
        tracker().load_doc(bad)
    bad = {**doc, "next_id": 0}
    with pytest.raises(ValueError, match="next_id 0: not above the candidate id 0"):
        tracker().load_doc(bad)
    with pytest.raises(ValueError, match="version"):
        tracker().load_doc({**doc, "version": 99})
    with pytest.raises(ValueError, match=r"candidate docs\[0\]\.sum_wr"):
        tracker().apply_candidate_docs([{**doc["candidates"][0], "sum_wr": [1.0]}], 1)


def test_the_gate_shrinks_with_the_reported_accuracy():
    def ids(accuracy):
        t, g = tracker(), grid()
        # The same person 1 m apart in two frames.
        f = fly(t, g, [0.0, 0.2], lambda k: [person_at(0.3 + k, 0.3)], accuracy=accuracy)
        return [d.candidate_id for frame in f for d in frame]
    joined = ids(None)  # the configured 1 m sigma: a gate of about 4 m
    apart = ids(ACCURATE)  # 4 cm: a gate of a few decimetres
    assert joined == [0, 0] and apart == [0, 1]
    # The gate floor: exact geolocation still joins boxes within 5 cm.
    exact = DetectionTracker(CAMERA, Geolocation(("person",), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 1.0)
    g = grid()
    f = fly(exact, g, [0.0, 0.2], lambda k: [person_at(0.3 + k * 0.9 * GATE_FLOOR_M, 0.3)])
    assert [d.candidate_id for frame in f for d in frame] == [0, 0]


def test_p_person_follows_the_prior_density():
    ps = []
    for per_m2 in (1e-6, 1e-3):
        t, g = tracker(prior_people_per_m2=per_m2), grid()
        fly(t, g, [0.0], lambda k: [person_at(0.3, 0.3)])
        ps.append(t.candidates(g)[0].p_person)
    assert 0 < ps[0] < ps[1] < 1
    assert math.isfinite(ps[0])
