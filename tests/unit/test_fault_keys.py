"""The status's fault keys are declared once (``pdcov.bus.faults``): docs/protocol.md "fault
keys" lists exactly them, every count in the service goes through them (no key spelled as a
string), and a daemon fed faults in memory reports them under those names."""

from __future__ import annotations

import ast
import math
import re
from pathlib import Path

import pdcov
from pdcov.bus.errors import Refusal
from pdcov.bus.faults import Fault, FaultFamily
from pdcov.bus.frames import encode_frames_v2
from pdcov.core.detections import Box, FrameBoxes
from pdcov.detection.candidates import Skip
from pdcov.service.frame_admission import FrameRefusal
from pdcov.service.retask_auth import RetaskRefusal
from pdcov.telemetry.tlog import mavlink
from tests.support.link_feed import Hover, LinkFeed, pack, serve_config

ROOT = Path(__file__).resolve().parents[2]
SOURCE = Path(pdcov.__file__).parent
FAMILY_REASONS = {FaultFamily.FRAMES_REFUSED: Refusal, FaultFamily.RETASK_REFUSED: RetaskRefusal}


def documented_keys() -> list[str]:
    """The keys of docs/protocol.md's "fault keys" table, in its order."""
    text = (ROOT / "docs" / "protocol.md").read_text()
    section = text.split("### fault keys", 1)[1].split("\n#", 1)[0]
    return re.findall(r"^\| `([a-z_<>]+)` \|", section, flags=re.M)


def test_the_documented_keys_are_the_enums() -> None:
    keys = documented_keys()
    assert len(keys) == len(set(keys)), keys
    assert {k for k in keys if "<" not in k} == {f.value for f in Fault}
    assert {k for k in keys if "<" in k} == {f"{fam.value}<reason>" for fam in FaultFamily}


def test_a_family_key_is_the_prefix_and_the_reasons_name() -> None:
    assert FaultFamily.FRAMES_REFUSED.key(Refusal.OUTSIDE_PICTURE) == \
        "frames_refused_outside_picture"
    assert FaultFamily.RETASK_REFUSED.key(RetaskRefusal.WILDCARD) == "retask_refused_wildcard"
    for family, reasons in FAMILY_REASONS.items():  # no reason's key is a Fault's
        assert not {family.key(r) for r in reasons} & {f.value for f in Fault}


def _faults_subscripts(tree: ast.AST) -> list[ast.expr]:
    """The keys of every ``...faults[key]`` in a module."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            target = node.value
            name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
            if name == "faults":
                out.append(node.slice)
    return out


def test_every_count_goes_through_the_enum() -> None:
    """No fault key is spelled as a string where a fault is counted; every Fault and every
    FaultFamily is counted somewhere; the other enums that name faults hold Faults."""
    used: set[str] = set()
    spelled = []
    for path in sorted(SOURCE.rglob("*.py")):
        if path.name == "faults.py" and path.parent.name == "bus":
            continue
        tree = ast.parse(path.read_text(), str(path))
        for key in _faults_subscripts(tree):
            if isinstance(key, (ast.Constant, ast.JoinedStr, ast.BinOp)):
                spelled.append(f"{path.relative_to(SOURCE)}:{key.lineno}")
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in ("Fault", "FaultFamily")):
                used.add(f"{node.value.id}.{node.attr}")
    assert not spelled, f"fault keys spelled as strings (use pdcov.bus.faults): {spelled}"
    assert used == ({f"Fault.{f.name}" for f in Fault}
                    | {f"FaultFamily.{f.name}" for f in FaultFamily})
    assert all(isinstance(r.value, Fault) for r in FrameRefusal)
    assert all(isinstance(getattr(Skip, n), Fault) for n in vars(Skip) if n.isupper())


def test_a_daemon_reports_its_faults_under_the_documented_keys(tmp_path: Path) -> None:
    """Faults fed in memory (a gimbal failure, a refused frames message, a NaN attitude):
    each counted under its documented key, and no key the docs do not list."""
    feed = LinkFeed(serve_config(tmp_path))
    mav = mavlink.MAVLink(None)
    c = math.sqrt(0.5)
    msgs = [*Hover(seconds=2.0).messages(),
            mav.gimbal_device_attitude_status_encode(0, 0, 2500, 4 | 8 | 16, [c, 0.0, -c, 0.0],
                                                     0, 0, 0, 1),
            mav.attitude_encode(2600, math.nan, 0.0, 0.0, 0, 0, 0)]
    feed.feed(b"".join(pack(m, seq=i % 256) for i, m in enumerate(msgs)), 3.0)
    outside = FrameBoxes(2.0, (Box("person", 0.9, 630.0, 0.0, 20.0, 20.0),))
    feed.core.receive_frames(encode_frames_v2([outside]))
    faults = feed.status()["faults"]
    assert all(type(k) is str for k in faults), faults
    assert faults[Fault.GIMBAL_FAILURES.value] == 1, faults
    assert faults[Fault.BAD_FRAMES_MESSAGES.value] == 1, faults
    assert faults["frames_refused_outside_picture"] == 1, faults
    documented = set(documented_keys())
    families = {k[:-len("<reason>")] for k in documented if k.endswith("<reason>")}
    undocumented = [k for k in faults if k not in documented
                    and not any(k.startswith(f) for f in families)]
    assert not undocumented, undocumented
