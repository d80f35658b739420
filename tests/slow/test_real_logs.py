"""Real autopilot logs (../shared/real-logs, see its README): skipped where absent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.errors import PdcovError, TelemetryError
from pdcov.flight.frame_decision import Framing
from pdcov.flight.ground_altitude import DEFAULT_HOME_WAIT_S, GroundAltitude
from pdcov.flight.log_frames import ground_alt_of_log, poses_from_log
from pdcov.telemetry.gimbal import resolve_interpretation
from pdcov.telemetry.logs import read_flight_log
from pdcov.telemetry.pose_tracker import PoseTracker

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real-logs"
pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} not present")

TLOG = REAL / "ardupilot_sitl_servo_gimbal.tlog"
BIN = REAL / "ardupilot_sitl_servo_gimbal.BIN"
HOME = dict(origin_lat_deg=-35.363261, origin_lon_deg=149.165230, ground_alt_msl_m=None)
# The tlog holds no MNT1_* parameters: give the servo limits the .BIN records.
SERVO = dict(roll_limits_deg=(-30, 30), pitch_limits_deg=(-90, 20), yaw_limits_deg=(-180, 180))


@pytest.mark.parametrize("name", sorted(p.name for p in REAL.glob("*")
                                        if p.suffix != ".md") if REAL.is_dir() else [])
def test_every_log_evaluates_or_fails_clearly(name: str) -> None:
    path = REAL / name
    try:
        lp = poses_from_log(path, Framing(FixedMount(), 5.0), **HOME)
    except PdcovError as exc:
        assert name.endswith(".log") and "text DataFlash" in str(exc) and name in str(exc)
        return
    assert len(lp.poses) > 100 and len(lp.summary_lines) > 3


def test_text_dataflash_log_is_refused() -> None:
    with pytest.raises(TelemetryError, match="text DataFlash"):
        read_flight_log(REAL / "ap_loganalyzer_robert_lefebvre_octo_PM.log")


def test_fast_recorded_log_uses_autopilot_time() -> None:
    # Every frame, also those on the ground before the EKF fused GPS (skipped by default).
    lp = poses_from_log(REAL / "uavlogviewer_flight_logs.tlog",
                        Framing(FixedMount(), 2.0, estimator_status=False), **HOME)
    t = np.array([p.t_s for p in lp.poses])
    assert t[-1] - t[0] > 290.0  # 301.7 s of time_boot_ms, not the 12.3 s of wall clock
    assert t[-1] == pytest.approx(304.18, abs=0.5)
    assert any("restarted" in line for line in lp.summary_lines)
    assert any("following system 1" in line for line in lp.summary_lines)


@pytest.fixture(scope="module")
def servo_flight() -> dict:
    """The servo-gimbal flight's frames at 5 Hz, read both ways, with the .BIN's MNT
    target at each frame."""
    out = {}
    for name, path, mount in [
            ("body", TLOG, GimbalMount(attitude_frame="body", untrusted="use", **SERVO)),
            ("flags", TLOG, GimbalMount(attitude_frame="flags", untrusted="use")),
            ("bin", BIN, GimbalMount(attitude_frame="auto", untrusted="use"))]:
        out[name] = poses_from_log(path, Framing(mount, 5.0), **HOME)
    targets = read_flight_log(BIN).mount_targets
    t = np.array([p.t_s for p in out["body"].poses])
    i = np.clip(np.searchsorted(targets.t_s, t), 1, len(targets.t_s) - 1)
    out["target_pitch_deg"] = np.degrees(targets.pitch_rad[i - 1])
    out["t_s"] = t
    return out


def off_nadir_deg(lp) -> np.ndarray:
    down = np.array([p.optical_axis_enu[2] for p in lp.poses])
    return np.degrees(np.arccos(np.clip(-down, -1, 1)))


def test_auto_picks_body_from_dataflash_params(servo_flight: dict) -> None:
    assert any("'body': auto: MNT1_TYPE=1" in x for x in servo_flight["bin"].summary_lines)
    flags = poses_from_log(TLOG, Framing(GimbalMount(), 1.0), **HOME)
    assert any("no MNT1_TYPE" in x for x in flags.summary_lines)  # tlog: config decides


def test_body_vs_flags_on_nose_down_legs(servo_flight: dict) -> None:
    body, flags = servo_flight["body"], servo_flight["flags"]
    rpy = body.vehicle_rpy_deg
    z = np.array([p.r_cam_enu[2] for p in body.poses])
    # With yaw lock and the vehicle turned south the servo demand passes its pitch stop
    # (at_limit): the camera is where the body reading says, but not at nadir. Those are
    # not the frames "commanded to nadir and there".
    legs = ((servo_flight["target_pitch_deg"] < -89.9) & (rpy[:, 1] < -15)
            & (np.abs(rpy[:, 0]) < 5) & (z > 9) & ~body.at_limit)
    assert legs.sum() >= 20
    body_err, flags_err = off_nadir_deg(body)[legs], off_nadir_deg(flags)[legs]
    assert body_err.max() < 2.0
    # Read at its flags' word the camera is off nadir by about the vehicle pitch.
    np.testing.assert_allclose(flags_err, -rpy[legs, 1], atol=2.0)
    assert flags_err.min() > 13.0


def test_level_hover_footprint_centre_under_vehicle(servo_flight: dict) -> None:
    body = servo_flight["body"]
    rpy = body.vehicle_rpy_deg
    z = np.array([p.r_cam_enu[2] for p in body.poses])
    hover = ((servo_flight["target_pitch_deg"] < -89.9) & (np.abs(rpy[:, 0]) < 1)
             & (np.abs(rpy[:, 1]) < 1) & (z > 9))
    assert hover.sum() >= 10
    for p in np.array(body.poses, dtype=object)[hover]:
        a = p.optical_axis_enu
        ground = p.r_cam_enu - a * (p.r_cam_enu[2] / a[2])
        assert np.linalg.norm(ground[:2] - p.r_cam_enu[:2]) < 1.0


def test_bin_and_tlog_give_the_same_poses() -> None:
    """Same flight, two logs: poses at the same instants agree."""
    trackers = []
    for path in (TLOG, BIN):
        log = read_flight_log(path)
        origin = Origin(HOME["origin_lat_deg"], HOME["origin_lon_deg"], 584.08)
        mount = GimbalMount(attitude_frame="body", **SERVO)
        trackers.append(PoseTracker.from_flight_log(
            log, origin, mount, resolve_interpretation(mount, log.params), max_gap_s=1.0,
            use_estimator=False))  # the poses on the ground too
    t0 = max(tr.coverage_s()[0] for tr in trackers)
    t1 = min(tr.coverage_s()[1] for tr in trackers)
    t = np.arange(t0, t1, 0.2)
    a, b = (tr.frames_at(t) for tr in trackers)
    ok = a.valid & b.valid
    # At a reported pitch of exactly -90 deg the servo's roll and yaw are inseparable, and
    # the .BIN's MNT angles lose them (docs/autopilots.md): compare rotations elsewhere.
    clear = ok & ~a.at_limit & ~b.at_limit
    assert ok.sum() > 600 and clear.sum() > 400
    rel = np.einsum("nji,njk->nik", a.R_enu_cam[clear], b.R_enu_cam[clear])
    rot_deg = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    axis_deg = np.degrees(np.arccos(np.clip(
        np.einsum("ni,ni->n", a.R_enu_cam[ok][:, :, 2], b.R_enu_cam[ok][:, :, 2]), -1, 1)))
    pos_m = np.linalg.norm(a.r_cam_enu[ok] - b.r_cam_enu[ok], axis=1)
    # Interpolation tolerance: ATT/MNT at 10 Hz in the .BIN against 20-25 Hz in the tlog;
    # the gimbal steps when a new target is commanded.
    assert np.percentile(rot_deg, 95) < 0.5
    assert np.percentile(axis_deg, 95) < 0.5
    assert pos_m.max() < 0.3


# --- real logs damaged at test time: junk before, after, inside; cut short ------------------

def _junk(n: int, seed: int) -> bytes:
    return bytes(np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8))


@pytest.fixture(scope="module")
def whole() -> dict:
    return {p: read_flight_log(p) for p in (TLOG, BIN)}


@pytest.mark.parametrize("source, damage", [
    (TLOG, "prepend"), (TLOG, "append"), (TLOG, "insert"), (TLOG, "truncate"),
    (BIN, "append"), (BIN, "insert"), (BIN, "truncate")])  # a .BIN is told by its first bytes
def test_damaged_real_log_reads_up_to_the_damage(tmp_path: Path, whole: dict, source: Path,
                                                 damage: str, capfd) -> None:
    data = source.read_bytes()
    middle = len(data) // 2 + 13
    hostile = {"prepend": _junk(37, 1) + data, "append": data + _junk(4096, 2),
               "insert": data[:middle] + _junk(20000, 3) + data[middle:],
               "truncate": data[:middle]}[damage]
    path = tmp_path / f"hostile{source.suffix}"
    path.write_bytes(hostile)
    capfd.readouterr()
    log, ref = read_flight_log(path), whole[source]
    out = capfd.readouterr()
    assert "bad header" not in out.err + out.out and len(out.err) < 200  # no flood of lines
    n_ref, n = len(ref.attitude.t_s), len(log.attitude.t_s)
    if damage == "truncate":
        assert 0.4 * n_ref < n < 0.6 * n_ref
        assert any("cut short" in line for line in log.damage)
    else:
        assert n_ref - 2 <= n <= n_ref  # at most the damaged record is lost
        assert len(log.gimbal.t_s) >= len(ref.gimbal.t_s) - 2
        assert any("not MAVLink" in line or "not DataFlash" in line for line in log.damage)
    if damage == "append":
        assert any("reading stopped at byte" in line for line in log.damage)
    # Every message read is one of the original's: none is made up from the junk.
    assert np.isin(np.round(log.attitude.t_s, 4), np.round(ref.attitude.t_s, 4)).all()


def test_the_tlog_and_its_dataflash_arm_together_and_give_the_home_at_arming() -> None:
    """The same flight's HEARTBEATs (1 Hz) and DataFlash ARM records arm within a second,
    and both logs give the home ArduPilot set at arming (the DataFlash's ORGN home, not the
    EKF origin logged at the same instant)."""
    tlog, dataflash = read_flight_log(TLOG), read_flight_log(BIN)
    assert tlog.armed_states is not None and dataflash.armed_states is not None
    armed = [[t for t, a in log.armed_states if a] for log in (tlog, dataflash)]
    assert len(armed[0]) == len(armed[1]) == 1
    assert abs(armed[0][0] - armed[1][0]) < 1.0
    assert dataflash.armed_states[0] == (-np.inf, False)
    for log, source in ((tlog, "HOME_POSITION"), (dataflash, "ORGN home")):
        assert ground_alt_of_log(log, GroundAltitude(None, DEFAULT_HOME_WAIT_S)) == (
            584.08, f"the autopilot's home at arming ({source})")
    # A real flight from before ARM records (ArduCopter 3.4): its EV ARMED / DISARMED.
    old = read_flight_log(REAL / "beast_log_0036_mechanical_failure.bin")
    assert old.armed_states is not None
    assert [a for _t, a in old.armed_states] == [False, True, False]
