"""The ATAK data package (report/atak_package.py), as a TAK client reads it: the manifest
(xml.etree) lists every other entry and nothing else, the KMZ is the run's, and each pin's
CoT event carries what a TAK client requires, checked by hand (pytak 7.6 builds CoT but
parses none: its only reader decodes takproto's protobuf) against the attributes pytak's
own events carry, its position detections.geojson's to 7 decimals."""

from __future__ import annotations

import json
import sys
import uuid
import xml.etree.ElementTree as ET
import zipfile
from datetime import datetime, timedelta

import pytest
from pytak.functions import gen_cot_xml

from pdcov.report.atak_package import (
    KMZ_ENTRY,
    MANIFEST_ENTRY,
    MARKER_STALE_S,
    PACKAGE_NAME,
    package_uid,
)
from pdcov.report.exports import VehicleDetections, write_exports
from tests.support.exports_fixtures import coverage, detections_doc

TITLE = "pdcov watch: alpha, bravo"


def export(out, title: str = TITLE):
    out.mkdir(exist_ok=True)
    return write_exports(out, coverage(), [VehicleDetections.from_doc(detections_doc(v))
                                           for v in ("alpha", "bravo")], title=title)


def manifest_of(path) -> tuple[ET.Element, dict[str, bytes]]:
    with zipfile.ZipFile(path) as z:
        entries = {n: z.read(n) for n in z.namelist()}
    return ET.fromstring(entries.pop(MANIFEST_ENTRY)), entries


def parameters(element: ET.Element) -> dict[str, str]:
    return {p.get("name"): p.get("value") for p in element.findall("Parameter")}


def when(text: str) -> datetime:
    assert text.endswith("Z")  # UTC
    return datetime.fromisoformat(text)


def test_the_manifest_lists_every_entry_and_the_kmz_is_the_runs(tmp_path):
    assert PACKAGE_NAME in export(tmp_path).files
    root, entries = manifest_of(tmp_path / PACKAGE_NAME)
    assert root.tag == "MissionPackageManifest" and root.get("version") == "2"
    config = parameters(root.find("Configuration"))
    assert config["name"] == TITLE
    assert config["uid"] == str(uuid.UUID(config["uid"]))
    contents = root.findall("Contents/Content")
    assert {c.get("zipEntry") for c in contents} == set(entries)  # each way
    assert len(contents) == len(entries) and all(c.get("ignore") == "false" for c in contents)
    assert entries[KMZ_ENTRY] == (tmp_path / "pdcov.kmz").read_bytes()
    uids = {"alpha.3fa2c1.3", "alpha.3fa2c1.4", "bravo.3fa2c1.3", "bravo.3fa2c1.4"}
    assert set(entries) - {KMZ_ENTRY} == {f"{u}/{u}.cot" for u in uids}
    for c in contents:
        if c.get("zipEntry") != KMZ_ENTRY:
            event = ET.fromstring(entries[c.get("zipEntry")])
            assert parameters(c) == {"uid": event.get("uid")}


def test_a_re_export_keeps_the_package_uid_another_run_has_its_own(tmp_path):
    def uid_in(out) -> str:
        return parameters(manifest_of(out / PACKAGE_NAME)[0].find("Configuration"))["uid"]

    export(tmp_path / "a")
    first = uid_in(tmp_path / "a")
    export(tmp_path / "a")
    export(tmp_path / "b")
    export(tmp_path / "c", title="pdcov watch: alpha")
    assert uid_in(tmp_path / "a") == first == package_uid(TITLE, tmp_path / "a")
    assert len({first, uid_in(tmp_path / "b"), uid_in(tmp_path / "c")}) == 3


def test_each_marker_is_a_complete_cot_event_where_detections_geojson_puts_it(tmp_path):
    export(tmp_path)
    _, entries = manifest_of(tmp_path / PACKAGE_NAME)
    features = json.loads((tmp_path / "detections.geojson").read_text())["features"]
    where = {f["properties"]["uid"]: f["geometry"]["coordinates"] for f in features
             if f["properties"]["kind"] == "candidate"}
    reference = gen_cot_xml(lat=46.5, lon=7.25, uid="ref")  # what pytak's events carry
    markers = {n: b for n, b in entries.items() if n != KMZ_ENTRY}
    assert len(markers) == len(where) == 4
    for name, data in markers.items():
        assert data.startswith(b"<?xml version='1.0' encoding='UTF-8'")
        event = ET.fromstring(data)
        assert event.tag == "event" and event.get("version") == "2.0"
        assert set(reference.attrib) <= set(event.attrib)
        assert name == f"{event.get('uid')}/{event.get('uid')}.cot"
        assert event.get("type") == "a-u-G" and event.get("how") == "m-f"
        t, start, stale = (when(event.get(k)) for k in ("time", "start", "stale"))
        assert t == start and stale - start == timedelta(seconds=MARKER_STALE_S)
        point = event.find("point")
        assert set(reference.find("point").attrib) <= set(point.attrib)
        lat, lon, hae, ce, le = (float(point.get(k)) for k in ("lat", "lon", "hae", "ce", "le"))
        assert [lon, lat] == where[event.get("uid")]  # both to 7 decimals
        assert point.get("lat") == f"{lat:.7f}" and point.get("lon") == f"{lon:.7f}"
        assert hae == le == 9999999.0 and 0 < ce < 9999999.0
        detail = event.find("detail")
        assert detail.find("archive") is not None  # kept across the client's restarts
        assert "MGRS" in detail.findtext("remarks")
        assert detail.find("contact").get("callsign").endswith(event.get("uid"))


def test_without_mgrs_the_package_is_named_not_written(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mgrs", None)
    result = export(tmp_path)
    assert PACKAGE_NAME not in result.files and not (tmp_path / PACKAGE_NAME).exists()
    assert ("pdcov_atak.zip (its markers' remarks): MGRS and UTM references need mgrs: "
            "pip install 'pdcov[gis]'") in result.not_written


@pytest.mark.parametrize("docs", [[], [{"vehicle": "alpha"}]])
def test_without_pins_the_package_holds_the_kmz(tmp_path, monkeypatch, docs):
    monkeypatch.setitem(sys.modules, "mgrs", None)  # no marker: no reference needed
    write_exports(tmp_path, coverage(), [VehicleDetections.from_doc(d) for d in docs],
                  title="nothing found")
    root, entries = manifest_of(tmp_path / PACKAGE_NAME)
    assert list(entries) == [KMZ_ENTRY]
    assert [c.get("zipEntry") for c in root.findall("Contents/Content")] == [KMZ_ENTRY]
