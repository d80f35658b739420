"""Fuzzing the file readers (issue 15, bad input): mission YAML, camera_info, detector YAML,
pose CSV, .plan / WPL. Every bad input gets a PdcovError (a clear message, exit 2 at the
CLI), never another exception. The checkpoints and the Zenoh payloads: test_fuzz_state.py."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from pdcov.config.load import load_mission, mission_from_dict
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.geodesy import Origin
from pdcov.errors import PdcovError
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_files import read_mission, write_plan
from pdcov.telemetry.pose_csv import read_pose_csv
from tests.support.fuzz_inputs import SETTINGS, mutated_bytes, mutated_doc, only_pdcov_errors
from tests.support.link_feed import MISSION

CAMERA_INFO = {"image_width": 640, "image_height": 480,
               "camera_matrix": {"rows": 3, "cols": 3,
                                 "data": [480.0, 0, 319.5, 0, 480.0, 239.5, 0, 0, 1]},
               "distortion_model": "plumb_bob",
               "distortion_coefficients": {"rows": 1, "cols": 5,
                                           "data": [-0.05, 0.01, 0, 0, 0]}}
DETECTOR = yaml.safe_load(DetectorModel.illustrative().to_yaml())


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, bytes]:
    """The valid files every mutation starts from."""
    d = tmp_path_factory.mktemp("valid")
    plan = Plan((Waypoint(0.0, 0.0, 10.0, 5.0), Waypoint(0.0, 20.0, 10.0, 5.0, 3.0),
                 Waypoint(10.0, 20.0, 12.0, 3.5)))
    origin = Origin(47.39, 8.54, 488.0)
    write_plan(d / "p.plan", plan, origin)
    write_plan(d / "p.waypoints", plan, origin)
    poses = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n" + "".join(
        f"{t},{t},2.0,10.0,0.0,1.0,0.0,0.0\n" for t in range(5))
    return {"plan": (d / "p.plan").read_bytes(), "wpl": (d / "p.waypoints").read_bytes(),
            "poses": poses.encode(), "mission": yaml.safe_dump(MISSION).encode(),
            "camera_info": yaml.safe_dump(CAMERA_INFO).encode(),
            "detector": yaml.safe_dump(DETECTOR).encode()}


READERS = {"mission": load_mission, "camera_info": CameraModel.from_camera_info,
           "detector": DetectorModel.from_yaml, "poses": read_pose_csv, "plan": read_mission,
           "wpl": read_mission}
SUFFIX = {"plan": ".plan", "wpl": ".waypoints", "poses": ".csv"}


def read_file(tmp_path: Path, kind: str, data: bytes):
    path = tmp_path / f"input{SUFFIX.get(kind, '.yaml')}"
    path.write_bytes(data)
    return only_pdcov_errors(READERS[kind], path)


@pytest.mark.parametrize("kind", sorted(READERS))
def test_the_valid_files_read(tmp_path, files, kind):
    assert read_file(tmp_path, kind, files[kind]) is not None


@pytest.mark.parametrize("kind", sorted(READERS))
@SETTINGS
@given(data=st.data())
def test_damaged_files_give_a_pdcov_error(tmp_path, files, kind, data):
    read_file(tmp_path, kind, data.draw(mutated_bytes(files[kind])))


@pytest.mark.parametrize("kind", sorted(READERS))
@SETTINGS
@given(blob=st.binary(max_size=2000))
def test_random_bytes_give_a_pdcov_error(tmp_path, kind, blob):
    read_file(tmp_path, kind, blob)


@pytest.mark.parametrize("kind", ["mission", "camera_info", "detector", "plan"])
@SETTINGS
@given(data=st.data())
def test_hostile_values_give_a_pdcov_error(tmp_path, files, kind, data):
    doc = json.loads(files[kind]) if kind == "plan" else yaml.safe_load(files[kind])
    bad = data.draw(mutated_doc(doc))
    text = json.dumps(bad) if kind == "plan" else yaml.safe_dump(bad)
    read_file(tmp_path, kind, text.encode())


@SETTINGS
@given(data=st.data())
def test_hostile_mission_documents_in_memory(tmp_path, data):
    """mission_from_dict directly (the daemon's and every command's config path)."""
    only_pdcov_errors(mission_from_dict, data.draw(mutated_doc(MISSION)), "m.yaml", tmp_path)


def test_a_bad_file_is_exit_2_without_a_traceback(tmp_path, files, capsys):
    from pdcov.cli import main
    (tmp_path / "m.yaml").write_bytes(files["mission"][:-40] + b"\x00\xff: [")
    (tmp_path / "p.csv").write_bytes(b"t_s,x_m\n1,2\n")
    assert main(["evaluate", "--config", str(tmp_path / "m.yaml"), "--poses",
                 str(tmp_path / "p.csv"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "m.yaml" in err


# --- inputs the 500-example run found (docs: PDCOV_FUZZ_EXAMPLES=500), kept as plain cases ----

@pytest.mark.parametrize(("section", "key", "value", "message"), [
    ("camera", "K", [[], [0, 480, 239.5], [0, 0, 1]],
     "camera.K: expected 3 rows of 3 numbers, row 1 has 0"),  # numpy ValueError before
    ("camera", "K", [[480, 0, 319.5], [0, 480, 239.5, 7], [0, 0, 1]],
     "camera.K: expected 3 rows of 3 numbers, row 2 has 4"),
    ("camera", "distortion_model", [], "distortion_model: expected one of"),  # TypeError
    ("camera", "distortion_model", {"a": 1}, "distortion_model: expected one of"),
    # Integers no float holds (YAML reads them exactly): OverflowError in math.isfinite.
    ("camera", "K", [[10**400, 0, 319.5], [0, 480, 239.5], [0, 0, 1]], "camera.K: a number"),
    ("origin", "lat_deg", 10**400, "origin.lat_deg: expected a finite number"),
    ("mount", "lever_arm_frd_m", [0, 0, -10**400], "mount.lever_arm_frd_m: expected"),
    # Cells so small that the cell count has no float quotient (OverflowError before), or
    # that the domain's width in cells is infinite.
    ("domain", "cell_size_m", 1.8e-274, "= 10^550 cells; at most 4,294,967,296 cells"),
    ("domain", "cell_size_m", 5e-324, "too small for a 30 x 30 m domain"),
], ids=["K-empty-row", "K-long-row", "model-list", "model-mapping", "K-huge-int",
        "lat-huge-int", "lever-arm-huge-int", "cell-1e-274", "cell-denormal"])
def test_found_mission_values_give_a_pdcov_error(tmp_path, section, key, value, message):
    doc = copy.deepcopy(MISSION)
    if section == "mount":
        doc["mount"] = {"type": "fixed"}
    doc[section][key] = value
    for read in (lambda: mission_from_dict(doc, "m.yaml", tmp_path),
                 lambda: load_mission(_written(tmp_path / "m.yaml", yaml.safe_dump(doc)))):
        with pytest.raises(PdcovError, match=re.escape(message)):
            read()


def _written(path: Path, text: str) -> Path:
    path.write_text(text)
    return path



@pytest.mark.parametrize("text", ["origin: {lat_deg: " + "1" * 5000 + "}\n",  # ValueError
                                  "camera: " + "[" * 5000 + "]" * 5000 + "\n"])
def test_yaml_that_python_cannot_build_gives_a_pdcov_error(tmp_path, text):
    with pytest.raises(PdcovError, match="m.yaml: not valid YAML"):
        load_mission(_written(tmp_path / "m.yaml", text))
