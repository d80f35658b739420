"""The ATAK data package, ``pdcov_atak.zip`` (docs/outputs.md "Exports"): one file that
ATAK, WinTAK and iTAK import whole (Import Manager, or sent to a contact or a TAK server),
written beside ``pdcov.kmz`` by ``write_exports``. It holds:

* ``MANIFEST/manifest.xml``: a ``MissionPackageManifest`` version 2 whose Configuration
  gives the package's ``uid`` and ``name`` and whose Contents list every other entry by
  its ``zipEntry`` (a CoT entry with its event's ``uid``, as TAK clients write them);
* ``pdcov.kmz``, the same bytes as the run's: the P_D overlay, outlines, gaps, re-fly
  areas and pins;
* ``<uid>/<uid>.cot`` per candidate: its pin's CoT event (report/cot_events.py, the
  live feed's), archived and stale a year on (MARKER_STALE_S), so that it stays a marker
  on the map; the detections are in the KMZ.

The package's uid is a UUID derived from the title and the folder written to
(``package_uid``): a re-export of the same run replaces the package on the device, another
run's is a package of its own. The pins' uids are durable, so their markers are replaced
either way.
"""

from __future__ import annotations

import io
import time
import uuid
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Sequence
from pathlib import Path

from pdcov.atomic import atomic_write
from pdcov.report.cot_events import candidate_event
from pdcov.report.exports import Pin

__all__ = ["KMZ_ENTRY", "MANIFEST_ENTRY", "PACKAGE_NAME", "atak_package", "package_uid",
           "write_atak_package"]

PACKAGE_NAME = "pdcov_atak.zip"
MANIFEST_ENTRY = "MANIFEST/manifest.xml"
KMZ_ENTRY = "pdcov.kmz"
MARKER_STALE_S = 365 * 86400.0
"""A marker's stale time after the export: a year, as ATAK stamps the markers it exports
itself (a TAK client drops a marker gone stale)."""
UID_NAMESPACE = uuid.uuid5(uuid.NAMESPACE_URL, "https://pdcov/atak-package")
XML_DECLARATION = b"<?xml version='1.0' encoding='UTF-8' standalone='yes'?>\n"


def package_uid(title: str, out_dir: Path) -> str:
    """The package's uid: a UUID (version 5) of ``title`` and the absolute ``out_dir``."""
    return str(uuid.uuid5(UID_NAMESPACE, f"{title}\n{out_dir.resolve()}"))


def cot_entry(pin_uid: str) -> str:
    """A marker's zip entry, in a folder of its own as TAK clients write them."""
    return f"{pin_uid}/{pin_uid}.cot"


def atak_package(kmz: bytes, pins: Sequence[Pin], *, uid: str, name: str,
                 now_unix_s: float) -> bytes:
    """The package's bytes: the manifest, ``kmz`` and a CoT event per candidate pin, made
    at ``now_unix_s`` (needs mgrs when there is a candidate: the remarks' references)."""
    markers: dict[str, bytes] = {}
    for p in pins:
        if p.kind == "candidate" and p.properties["uid"] not in markers:
            c = {**p.properties, "lat_deg": p.lat_deg, "lon_deg": p.lon_deg}
            markers[c["uid"]] = XML_DECLARATION + candidate_event(
                c["vehicle"], c, now_unix_s, MARKER_STALE_S, archive=True)
    manifest = ET.Element("MissionPackageManifest", version="2")
    config = ET.SubElement(manifest, "Configuration")
    ET.SubElement(config, "Parameter", name="uid", value=uid)
    ET.SubElement(config, "Parameter", name="name", value=name)
    contents = ET.SubElement(manifest, "Contents")
    ET.SubElement(contents, "Content", ignore="false", zipEntry=KMZ_ENTRY)
    for pin_uid in markers:
        content = ET.SubElement(contents, "Content", ignore="false",
                                zipEntry=cot_entry(pin_uid))
        ET.SubElement(content, "Parameter", name="uid", value=pin_uid)
    ET.indent(manifest)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(MANIFEST_ENTRY, ET.tostring(manifest, encoding="UTF-8",
                                               xml_declaration=True))
        z.writestr(KMZ_ENTRY, kmz)
        for pin_uid, event in markers.items():
            z.writestr(cot_entry(pin_uid), event)
    return buf.getvalue()


def write_atak_package(out_dir: Path, kmz: bytes, pins: Sequence[Pin], title: str) -> str:
    """Write PACKAGE_NAME into ``out_dir`` atomically, its markers made now; its name."""
    data = atak_package(kmz, pins, uid=package_uid(title, out_dir), name=title,
                        now_unix_s=time.time())
    with atomic_write(out_dir / PACKAGE_NAME, "wb") as f:
        f.write(data)
    return PACKAGE_NAME
