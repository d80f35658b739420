"""The detector's frames payload (both versions) and the detections payload: round trips and
every refusal, each with its reason (docs/protocol.md "frames", "detections")."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from pdcov.bus.detections import (
    MAX_CANDIDATES,
    decode_detections,
    detections_document,
    encode_detections,
)
from pdcov.bus.errors import BusPayloadError, Refusal
from pdcov.bus.frames import (
    MAX_BOXES_PER_FRAME,
    MAX_FRAMES,
    decode_frames,
    encode_frames,
    encode_frames_v2,
)
from pdcov.core.detections import Box, Candidate, Detection, FrameBoxes
from pdcov.core.geodesy import Origin

PERSON = Box("person", 0.87, 100.0, 50.0, 20.0, 40.0)
FRAMES = (FrameBoxes(1.5, (PERSON, Box("fire hydrant", 0.5, -0.5, -0.5, 640.0, 480.0))),
          FrameBoxes(1.7))


def v2(frames: list[dict]) -> bytes:
    return json.dumps({"schema": "pdcov.frames", "version": 2, "frames": frames}).encode()


def refusal(payload: bytes, **kw) -> BusPayloadError:
    with pytest.raises(BusPayloadError) as err:
        decode_frames(payload, "pdcov/uav1/frames", **kw)
    assert str(err.value).startswith("pdcov/uav1/frames: not a usable frames message: ")
    return err.value


def test_frames_both_versions_round_trip():
    assert decode_frames(encode_frames_v2(FRAMES)) == FRAMES
    assert decode_frames(encode_frames_v2(FRAMES), picture_px=(640, 480)) == FRAMES
    assert decode_frames(encode_frames([2.0, 1.0])) == (FrameBoxes(2.0), FrameBoxes(1.0))
    doc = json.loads(encode_frames_v2(FRAMES[:1]))
    assert doc["frames"][0]["boxes"][0] == {"class": "person", "confidence": 0.87,
                                            "box_px": [100.0, 50.0, 20.0, 40.0]}


BOX = {"class": "person", "confidence": 0.9, "box_px": [1, 2, 3, 4]}


@pytest.mark.parametrize(("change", "reason", "why"), [
    ({"box_px": [1, 2, -3, 4]}, Refusal.BAD_FIELD, "frames[0].boxes[0].box_px [1, 2, -3, 4]: "
                                                  "width and height must be > 0"),
    ({"box_px": [1, 2, 0, 4]}, Refusal.BAD_FIELD, "width and height must be > 0"),
    ({"box_px": [1, 2, 3]}, Refusal.BAD_FIELD, "box_px: expected [left, top, width, height]"),
    ({"box_px": [1, 2, 3, True]}, Refusal.BAD_FIELD, "box_px: expected"),
    ({"confidence": 1.5}, Refusal.BAD_FIELD, "frames[0].boxes[0].confidence: expected a "
                                            "number in [0, 1]"),
    ({"class": ""}, Refusal.BAD_FIELD, "class '': expected 1 to 64 printable"),
    ({"class": "a\nb"}, Refusal.BAD_FIELD, "class"),
    ({"class": " person"}, Refusal.BAD_FIELD, "class"),
    ({"class": 7}, Refusal.BAD_FIELD, "class 7"),
])
def test_bad_boxes_are_refused_naming_the_field(change, reason, why):
    err = refusal(v2([{"t_boot_s": 1.0, "boxes": [{**BOX, **change}]}]))
    assert err.reason is reason and why in str(err), str(err)


def test_nan_and_floods_are_refused():
    nan = v2([{"t_boot_s": 1.0, "boxes": [BOX]}]).replace(b"[1, 2, 3, 4]", b"[NaN, 2, 3, 4]")
    err = refusal(nan)
    assert err.reason is Refusal.NON_FINITE and "frames[0].boxes[0].box_px[0]" in str(err)
    err = refusal(v2([{"t_boot_s": 1.0, "boxes": [BOX] * (MAX_BOXES_PER_FRAME + 1)}]))
    assert err.reason is Refusal.OVER_BOUND and "boxes: 257 items, more than 256" in str(err)
    decode_frames(v2([{"t_boot_s": 1.0, "boxes": [BOX] * MAX_BOXES_PER_FRAME}]))
    err = refusal(v2([{"t_boot_s": 1.0, "boxes": []}] * (MAX_FRAMES + 1)))
    assert err.reason is Refusal.OVER_BOUND and "frames: 1001 items" in str(err)
    err = refusal(encode_frames([1.0] * (MAX_FRAMES + 1)))
    assert err.reason is Refusal.OVER_BOUND
    for frames, why in (([], "frames: expected 1..1000 frames, got none"),
                        ([{"t_boot_s": -1.0, "boxes": []}], "frames[0].t_boot_s"),
                        ([{"t_boot_s": 1.0}], "frames[0].boxes: expected a list"),
                        ([7], "frames[0]: expected an object")):
        err = refusal(v2(frames))
        assert err.reason is Refusal.BAD_FIELD and why in str(err), str(err)


def test_boxes_outside_the_picture_are_refused_when_its_size_is_known():
    inside = [-0.5, -0.5, 640, 480]  # the whole picture: [-0.5, 639.5] x [-0.5, 479.5]
    decode_frames(v2([{"t_boot_s": 1.0, "boxes": [{**BOX, "box_px": inside}]}]),
                  picture_px=(640, 480))
    for px in ([-0.6, 0, 10, 10], [0, -0.6, 10, 10], [630, 0, 10, 10], [0, 470, 10, 10]):
        payload = v2([{"t_boot_s": 1.0, "boxes": [{**BOX, "box_px": px}]}])
        decode_frames(payload)  # no picture size: no geometry check
        err = refusal(payload, picture_px=(640, 480))
        assert err.reason is Refusal.OUTSIDE_PICTURE and "outside the 640x480 px" in str(err)


ORIGIN = Origin(-35.3, 149.1, 580.0)


def document() -> dict:
    d = Detection(1.5, PERSON, np.array([3.0, 4.0, 0.0]), 0.5, candidate_id=0)
    c = Candidate(0, "person", np.array([3.0, 4.0, 0.0]), 0.4, hits=2, looks=5, pd=0.7,
                  pfa=0.01, confidence=0.87, first_t_boot_s=1.5, last_t_boot_s=2.5,
                  uid="uav1.a1b2c3.0", p_person=0.9)
    return detections_document([d], [c], ORIGIN, "uav1")


def test_detections_round_trip():
    doc = document()
    assert decode_detections(encode_detections(doc), vehicle_id="uav1") == doc
    det, cand = doc["detections"][0], doc["candidates"][0]
    assert det["x_m"] == 3.0 and det["y_m"] == 4.0 and det["alt_msl_m"] == pytest.approx(580)
    assert det["lat_deg"] == pytest.approx(-35.3 + 4.0 / 111_000, abs=1e-6)
    assert det["candidate"] == 0 and det["box_px"] == [100.0, 50.0, 20.0, 40.0]
    assert (cand["hits"], cand["looks"], cand["pd"]) == (2, 5, 0.7)
    assert cand["uid"] == det["uid"] == "uav1.a1b2c3.0"
    assert cand["p_person"] == 0.9


def test_p_person_is_rounded_and_a_candidate_without_hits_is_carried():
    c = Candidate(4, "person", np.array([0.0, 0.0, 0.0]), 0.4, hits=0, looks=3, pd=0.5,
                  pfa=0.01, confidence=0.5, first_t_boot_s=1.0, last_t_boot_s=1.0,
                  uid="uav1.a1b2c3.4", p_person=0.123456)
    doc = detections_document([], [c], ORIGIN, "uav1")
    assert doc["version"] == 2 and doc["candidates"][0]["p_person"] == 0.1235
    assert decode_detections(encode_detections(doc))["candidates"][0]["hits"] == 0


def test_a_detection_of_a_candidate_evicted_since_gets_the_uid_the_caller_gives():
    d = Detection(1.5, PERSON, np.array([3.0, 4.0, 0.0]), 0.5, candidate_id=7)
    with pytest.raises(ValueError, match=r"candidates \[7\] without those candidates"):
        detections_document([d], [], ORIGIN, "uav1")
    doc = detections_document([d], [], ORIGIN, "uav1", lambda cid: f"uav1.a1b2c3.{cid}")
    assert decode_detections(encode_detections(doc))["detections"][0]["uid"] == "uav1.a1b2c3.7"


def test_version_1_is_refused_saying_to_update_together():
    doc = document()
    doc["version"] = 1
    with pytest.raises(BusPayloadError) as err:
        decode_detections(encode_detections(doc), "pdcov/uav1/detections")
    assert "version 1 (a daemon from before candidate uids), expected 2: update the " \
           "daemon and pdcov watch together" in str(err.value)
    assert err.value.reason is Refusal.MALFORMED


@pytest.mark.parametrize(("path", "value", "why"), [
    (("vehicle",), "uav2", "vehicle 'uav2', but the key is vehicle 'uav1'"),
    (("vehicle",), "a/b", "vehicle: 'a/b', expected"),
    (("detections", 0, "box_px"), [1, 2, 0, 4], "detections[0].box_px"),
    (("detections", 0, "lat_deg"), 91.0, "detections[0].lat_deg"),
    (("detections", 0, "candidate"), -1, "detections[0].candidate"),
    (("candidates", 0, "hits"), -1, "candidates[0].hits"),
    (("candidates", 0, "hits"), 6, "candidates[0].hits 6 > looks 5: at most one hit per "
                                   "look"),
    (("candidates", 0, "p_person"), 1.01, "candidates[0].p_person"),
    (("candidates", 0, "p_person"), None, "candidates[0].p_person"),
    (("candidates", 0, "uid"), "uav1/0", "candidates[0].uid 'uav1/0': expected 1 to 100"),
    (("candidates", 0, "uid"), "x" * 101, "candidates[0].uid"),
    (("detections", 0, "uid"), None, "detections[0].uid None"),
    (("detections", 0, "uid"), "uav1.a1b2c3.9", "detections[0].uid 'uav1.a1b2c3.9': its "
                                                "candidate 0 is 'uav1.a1b2c3.0'"),
    (("candidates", 0, "pd"), 1.5, "candidates[0].pd"),
    (("candidates", 0, "last_t_boot_s"), 1.0, "candidates[0].last_t_boot_s"),
    (("candidates", 0, "class"), "", "candidates[0].class"),
])
def test_bad_detections_are_refused(path, value, why):
    doc = copy.deepcopy(document())
    holder = doc
    for k in path[:-1]:
        holder = holder[k]
    holder[path[-1]] = value
    with pytest.raises(BusPayloadError, match="pdcov/uav1/detections: not a usable") as err:
        decode_detections(encode_detections(doc), "pdcov/uav1/detections", "uav1")
    assert why in str(err.value), str(err.value)


def test_one_candidate_id_with_two_uids_is_refused():
    doc = document()
    doc["candidates"].append({**doc["candidates"][0], "uid": "uav1.a1b2c3.x"})
    with pytest.raises(BusPayloadError, match=r"candidates\[1\].uid 'uav1.a1b2c3.x': "
                                              r"candidate 0 is also 'uav1.a1b2c3.0'"):
        decode_detections(encode_detections(doc))


def test_too_many_candidates_are_refused():
    doc = document()
    doc["candidates"] = doc["candidates"] * (MAX_CANDIDATES + 1)
    with pytest.raises(BusPayloadError) as err:
        decode_detections(encode_detections(doc))
    assert err.value.reason is Refusal.OVER_BOUND


def test_values_refuse_what_cannot_be_right():
    for args in (("person", float("nan"), 0, 0, 1, 1), ("person", 0.5, 0, 0, -1, 1),
                 ("", 0.5, 0, 0, 1, 1), ("person", 0.5, float("inf"), 0, 1, 1)):
        with pytest.raises(ValueError):
            Box(*args)
    with pytest.raises(ValueError, match="r_enu_m"):
        Detection(1.0, PERSON, np.array([0.0, np.nan, 0.0]), 1.0, 0)
    d = Detection(1.0, PERSON, np.array([1.0, 2.0, 0.0]), 1.0, 0)
    assert not d.r_enu_m.flags.writeable
    assert PERSON.bottom_centre_px == (110.0, 90.0) and PERSON.centre_px == (110.0, 70.0)


def test_frames_naming_another_vehicle_are_refused():
    doc = {"schema": "pdcov.frames", "version": 2, "vehicle": "uav2",
           "frames": [{"t_boot_s": 1.0, "boxes": []}]}
    decode_frames(json.dumps(doc).encode(), vehicle_id="uav2")
    err = refusal(json.dumps(doc).encode(), vehicle_id="uav1")
    assert "vehicle 'uav2', but the key is vehicle 'uav1'" in str(err)


def test_recorded_boxes_read_back_bit_identical():
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from pdcov.telemetry.recorded_frames import BOX, FrameEncoder, box_of, recorded_mark

    enc = FrameEncoder()
    enc.encode(1, 1500)
    worst = Box("x" * 30 + " " + "y" * 33, 0.1 + 0.2, -0.1 / 3, 1e-7 / 3, 2 / 3, 1e5 / 7)
    for box in (PERSON, worst):
        msg = mavlink.MAVLink(None).parse_char(enc.box(1, 1500, box))
        assert recorded_mark(msg) == BOX and box_of(msg) == box
        assert (msg.time_boot_ms, msg.image_index) == (1500, 0)
