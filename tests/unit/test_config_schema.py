"""Every key of every file pdcov reads is declared once and checked: a misspelt key in any
section or subsection is refused naming the file and the key path, with a suggestion, and
the command exits with status 2 before writing anything."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import pytest
import yaml

from pdcov.config.load import mission_from_dict
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.mount import GimbalMount
from pdcov.errors import CalibrationError, ConfigError, DetectorModelError
from pdcov.schema import Section, check_keys
from tests.support.config_docs import renamed
from tests.support.evaluate_inputs import mission_doc

# The misspellings of issue 10, each silently ignored before: (key path, misspelt, expected).
MISSPELLINGS = [
    ("domain.cell_size_m", "cell_size", "cell_size_m"),
    ("domain.obstacles_enu_m", "obstacle_enu_m", "obstacles_enu_m"),
    ("coverage.min_revisit_s", "min_revisit", "min_revisit_s"),
    ("camera.distortion_coeffs", "distortion_coefs", "distortion_coeffs"),
    ("origin.ground_alt_msl_m", "ground_alt_msl", "ground_alt_msl_m"),
    ("coverage.max_range_m", "max_range", "max_range_m"),
    ("log.max_gap_s", "max_gap", "max_gap_s"),
    ("log.frame_source", "frame_src", "frame_source"),
    ("planning.corner_cut_m", "corner_cut", "corner_cut_m"),
    ("planning.terrain_clearance_m", "terrain_clearence_m", "terrain_clearance_m"),
    ("mount.pitch_deg", "pitch", "pitch_deg"),
    ("thresholds", "treshold", "thresholds"),
]


def full_doc() -> dict:
    return mission_doc(coverage={"min_revisit_s": 1.0, "max_range_m": 50.0},
                       log={"max_gap_s": 1.0, "frame_source": "rate"},
                       planning={"corner_cut_m": 2.0, "terrain_clearance_m": 10.0})


@pytest.mark.parametrize("path, wrong, right", MISSPELLINGS,
                         ids=[f"{p.rsplit('.', 1)[0]}.{w}" for p, w, _ in MISSPELLINGS])
def test_each_misspelt_mission_key_is_refused_with_a_suggestion(path, wrong, right):
    doc = renamed(full_doc(), path, wrong, 1.0)
    section = path.rsplit(".", 1)[0] + "." if "." in path else ""
    with pytest.raises(ConfigError) as err:
        mission_from_dict(doc, source="m.yaml")
    msg = str(err.value)
    assert msg.startswith(f"m.yaml: {section}{wrong}: unknown key"), msg
    assert f"did you mean {right!r}?" in msg


def test_the_full_document_is_accepted():
    mission = mission_from_dict(full_doc(), source="m.yaml")
    assert mission.min_revisit_s == 1.0 and mission.max_range_m == 50.0


def test_gimbal_mount_and_inline_detector_keys_are_checked():
    doc = full_doc() | {"mount": {"type": "gimbal", "attitude_frame": "flags",
                                  "untrusted_policy": "use"}}
    with pytest.raises(ConfigError, match=r"m.yaml: mount.untrusted_policy: unknown key; "
                                          r"did you mean 'untrusted'\?"):
        mission_from_dict(doc, source="m.yaml")
    # A gimbal key under a fixed mount is not a fixed mount's key.
    doc = full_doc() | {"mount": {"type": "fixed", "attitude_frame": "flags"}}
    with pytest.raises(ConfigError, match="m.yaml: mount.attitude_frame: unknown key"):
        mission_from_dict(doc, source="m.yaml")
    inline = DetectorModel.illustrative().to_dict()
    inline["bin_edge_px"] = inline.pop("bin_edges_px")
    with pytest.raises(ConfigError, match=r"m.yaml: detector.bin_edge_px: unknown key; "
                                          r"did you mean 'bin_edges_px'\?"):
        mission_from_dict(full_doc() | {"detector": inline}, source="m.yaml")
    counts = {"n_true": [1], "n_detected": [1], "n_detection": [1]}
    with pytest.raises(ConfigError, match=r"detector.counts.n_detection: unknown key; "
                                          r"did you mean 'n_detections'\?"):
        mission_from_dict(full_doc() | {"detector": DetectorModel.illustrative().to_dict()
                                        | {"counts": counts}}, source="m.yaml")


def test_detector_model_file_keys_are_checked(tmp_path):
    path = tmp_path / "det.yaml"
    doc = DetectorModel.illustrative().to_dict()
    doc["iou_treshold"] = doc.pop("iou_threshold")
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(DetectorModelError, match=rf"{path}: iou_treshold: unknown key; did "
                                                 r"you mean 'iou_threshold'\?"):
        DetectorModel.from_yaml(path)
    doc = DetectorModel.illustrative().to_dict() | {"fit": {"n_image": 3}}
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(DetectorModelError, match=r"fit.n_image: unknown key; did you mean "
                                                 r"'n_images'\?"):
        DetectorModel.from_yaml(path)
    # What `pdcov detector fit` writes, and free-text notes, read back.
    doc = DetectorModel.illustrative().to_dict() | {"notes": "flight test 3"}
    path.write_text(yaml.safe_dump(doc))
    assert DetectorModel.from_yaml(path).extra["notes"] == "flight test 3"


def test_camera_info_and_inline_camera_keys_are_checked(tmp_path):
    info = {"image_width": 640, "image_height": 480, "camera_name": "cam",
            "camera_matrix": {"rows": 3, "cols": 3, "data": [480, 0, 319.5, 0, 480, 239.5,
                                                             0, 0, 1]},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0, 0, 0, 0, 0]},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
            "projection_matrix": {"rows": 3, "cols": 4,
                                  "data": [480, 0, 319.5, 0, 0, 480, 239.5, 0, 0, 0, 1, 0]}}
    path = tmp_path / "camera_info.yaml"
    path.write_text(yaml.safe_dump(info))
    assert CameraModel.from_camera_info(path).width_px == 640
    bad = copy.deepcopy(info)
    bad["distortion_coeficients"] = bad.pop("distortion_coefficients")
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(CalibrationError, match=rf"{path}: distortion_coeficients: unknown "
                                               r"key; did you mean 'distortion_coefficients'"):
        CameraModel.from_camera_info(path)
    bad = copy.deepcopy(info)
    bad["camera_matrix"]["dat"] = bad["camera_matrix"].pop("data")
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(CalibrationError, match=r"camera_matrix.dat: unknown key; did you "
                                               r"mean 'data'"):
        CameraModel.from_camera_info(path)
    with pytest.raises(CalibrationError, match=r"cam.yaml: camera.widht_px: unknown key; did "
                                               r"you mean 'width_px'"):
        CameraModel.from_config({"widht_px": 640, "height_px": 480, "K": info}, "cam.yaml")


def test_gimbal_mount_from_config_checks_its_keys():
    with pytest.raises(ConfigError, match=r"m.yaml: mount.servo_axes_order: unknown key; did "
                                          r"you mean 'servo_axis_order'"):
        GimbalMount.from_config({"type": "gimbal", "servo_axes_order": "yaw_roll_pitch"},
                                "m.yaml")


def test_reserved_daemon_sections_are_mappings_until_their_module_declares_them():
    doc = full_doc() | {"link": {"connect": "udpin:0.0.0.0:14550"}, "bus": {"anything": 1},
                        "service": {}}
    mission = mission_from_dict(doc, source="m.yaml")
    assert mission.raw["link"] == {"connect": "udpin:0.0.0.0:14550"}
    with pytest.raises(ConfigError, match="m.yaml: bus: expected a mapping"):
        mission_from_dict(full_doc() | {"bus": "zenoh"}, source="m.yaml")

    @dataclass(frozen=True)
    class LinkConfig:  # as the daemon's module would declare it
        connect: str = "udpin:0.0.0.0:14550"
        heartbeat_timeout_s: float = 3.0

    sections = {"link": Section.of_dataclass(LinkConfig)}
    assert mission_from_dict(doc, source="m.yaml", sections=sections).raw["link"]
    doc["link"] = {"conect": "udpin:0.0.0.0:14550"}
    with pytest.raises(ConfigError, match=r"m.yaml: link.conect: unknown key; did you mean "
                                          r"'connect'\?"):
        mission_from_dict(doc, source="m.yaml", sections=sections)
    with pytest.raises(ValueError, match="reserved"):
        mission_from_dict(doc, source="m.yaml", sections={"origin": Section()})


@dataclass(frozen=True)
class Inner:
    port: int = 0


@dataclass(frozen=True)
class Outer:
    inner: Inner | None = None
    name: str = ""


def test_check_keys_nested_dataclass_sections():
    schema = Section.of_dataclass(Outer)
    check_keys({"inner": {"port": 1}, "name": "x"}, schema, "f.yaml")
    with pytest.raises(ConfigError, match=r"f.yaml: inner.prot: unknown key; did you mean "
                                          r"'port'"):
        check_keys({"inner": {"prot": 1}}, schema, "f.yaml")


def test_more_thresholds_than_the_bus_carries_are_refused():
    # Every watcher refuses a status listing more than MAX_THRESHOLDS (bus/status.py):
    # such a mission would fly with a ground station that shows nothing of it.
    doc = full_doc()
    doc["thresholds"] = [round(0.1 + 0.01 * k, 2) for k in range(65)]
    with pytest.raises(ConfigError, match="65 thresholds, at most 64"):
        mission_from_dict(doc)
    doc["thresholds"] = doc["thresholds"][:64]
    assert len(mission_from_dict(doc).thresholds) == 64


def test_search_prior_people_per_km2_is_checked():
    assert mission_from_dict(full_doc()).prior_people_per_km2 == 1.0  # the default
    doc = full_doc()
    doc["search"] = {"prior_people_per_km2": 250}
    assert mission_from_dict(doc).prior_people_per_km2 == 250.0
    for bad in (0, -1.0, 2e6, "many"):
        doc["search"] = {"prior_people_per_km2": bad}
        with pytest.raises(ConfigError, match=r"m.yaml: search.prior_people_per_km2: "):
            mission_from_dict(doc, source="m.yaml")
    doc["search"] = {"prior_people_per_kmm": 1.0}
    with pytest.raises(ConfigError, match="did you mean 'prior_people_per_km2'"):
        mission_from_dict(doc, source="m.yaml")
