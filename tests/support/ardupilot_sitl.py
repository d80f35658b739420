"""The real ArduCopter firmware for tests (../shared/ardupilot-sitl, see its README).

``ardupilot_sitl(run_dir, extra_parms)`` boots it with ``--defaults copter.parm,EXTRA...`` on a
free instance number (-I N: TCP 5760+10N is SERIAL0, 5762+10N SERIAL1, 5763+10N SERIAL2),
yields where to connect, and kills it on exit, whatever happened. Tests using it skip when the
folder is absent (``requires_ardupilot_sitl``).
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

SITL_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "ardupilot-sitl"
ARDUCOPTER = SITL_DIR / "arducopter"
COPTER_PARM = SITL_DIR / "copter.parm"
MOUNT_SERVO_PARM = SITL_DIR / "mount_servo.parm"
# The README's home: Canberra model-flying field, 584 m MSL, heading 353 deg.
HOME = "-35.363261,149.165230,584,353"

# A mission for a flight over the SITL home: the paper's 40 x 40 m square north of it, the
# servo mount's gimbal read from the autopilot (no limits here: with auto they come from the
# autopilot's MNT1_*_MIN/MAX).
FLIGHT_MISSION = {
    "vehicle_id": "ardu1",
    "origin": {"lat_deg": -35.363261, "lon_deg": 149.165230},
    # The paper's 40 x 40 m square, north of the SITL home.
    "domain": {"polygon_enu_m": [[-20, 10], [20, 10], [20, 50], [-20, 50]], "cell_size_m": 1.0},
    "camera": {"width_px": 640, "height_px": 480,
               "K": [[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]],
               "distortion_model": "plumb_bob", "distortion_coeffs": [0.0, 0.0, 0.0, 0.0, 0.0],
               "frame_rate_hz": 5},
    # No limits here: with auto they come from the autopilot's MNT1_*_MIN/MAX.
    "mount": {"type": "gimbal", "attitude_frame": "auto", "auto_fallback": "flags"},
    "detector": "illustrative",
    "thresholds": [0.5, 0.7, 0.8],
    "coverage": {"min_revisit_s": 1.0, "min_height_m": 2.0},
    "planning": {"gimbal_pitch_deg": -90},
    "link": {"attitude_hz": 25, "position_hz": 10, "gimbal_hz": 20},
}


requires_ardupilot_sitl = pytest.mark.skipif(
    not os.access(ARDUCOPTER, os.X_OK), reason=f"{ARDUCOPTER} absent (real-firmware tests)")


@dataclass(frozen=True, slots=True)
class Sitl:
    process: subprocess.Popen
    instance: int
    run_dir: Path

    def serial_url(self, serial: int) -> str:
        """pymavlink URL of SERIAL0 / 1 / 2 (TCP)."""
        return f"tcp:127.0.0.1:{self.port(serial)}"

    def port(self, serial: int) -> int:
        return 5760 + 10 * self.instance + {0: 0, 1: 2, 2: 3}[serial]

    def output(self) -> str:
        return (self.run_dir / "arducopter.out").read_text(errors="replace")


def _ports_free(instance: int) -> bool:
    for offset in (0, 2, 3):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", 5760 + 10 * instance + offset))
            except OSError:
                return False
    return True


def free_instance() -> int:
    """An -I number whose SERIAL0..2 TCP ports are free now (random, so that parallel runs
    rarely race for the same one)."""
    for _ in range(200):
        n = random.randrange(20, 256)  # the firmware takes -I modulo 256
        if _ports_free(n):
            return n
    raise RuntimeError("no free ArduPilot SITL instance number")


@contextmanager
def ardupilot_sitl(run_dir: Path, extra_parms: Sequence[Path] = (), *, speedup: float = 1.0,
                   ) -> Iterator[Sitl]:
    """Boot ArduCopter SITL in ``run_dir`` (eeprom.bin and logs/ go there); kill it on exit.
    It waits for a connection on SERIAL0 before it boots."""
    run_dir.mkdir(parents=True, exist_ok=True)
    defaults = ",".join(str(p) for p in (COPTER_PARM, *extra_parms))
    instance = free_instance()
    out = (run_dir / "arducopter.out").open("wb")
    proc = subprocess.Popen(
        [str(ARDUCOPTER), "--model", "quad", "--speedup", f"{speedup:g}", f"-I{instance}", "-w",
         "--defaults", defaults, "--home", HOME],
        cwd=run_dir, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    sitl = Sitl(proc, instance, run_dir)
    try:
        wait_listening(sitl.port(0), 20.0, proc)
        yield sitl
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        out.close()


def wait_listening(port: int, timeout_s: float, proc: subprocess.Popen | None = None) -> None:
    """Return once something accepts TCP connections on 127.0.0.1:port."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"ArduPilot SITL exited with {proc.returncode} before listening")
        if not _port_bindable(port):
            return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listening on 127.0.0.1:{port} after {timeout_s:g} s")


def _port_bindable(port: int) -> bool:
    # Probing by bind, not connect: a connect to SERIAL0 would be taken as the ground station.
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


# ---- ground-station actions for tests that fly (the daemon never sends these) ----------------

COPTER_MODES = {"AUTO": 3, "GUIDED": 4}


def command(conn, target: tuple[int, int], cmd: int, *params: float,
            timeout_s: float = 5.0) -> int | None:
    """COMMAND_LONG ``cmd`` with up to 7 params; the COMMAND_ACK result (None: no answer)."""
    p = [*params, *[0.0] * (7 - len(params))]
    conn.mav.command_long_send(*target, cmd, 0, *p)
    t_end = time.monotonic() + timeout_s
    while (left := t_end - time.monotonic()) > 0:
        ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=left)
        if ack is not None and ack.command == cmd:
            return ack.result
    return None


def fly_mission(conn, target: tuple[int, int], last_seq: int, *, altitude_m: float,
                timeout_s: float) -> None:
    """Point the mount at nadir, arm in GUIDED (retried until the pre-arm checks pass: GPS
    lock and EKF origin take 30-45 s of autopilot time), take off to ``altitude_m``, switch to
    AUTO and return once mission item ``last_seq`` is reached. README facts: arming in AUTO
    was refused, GUIDED + NAV_TAKEOFF + AUTO flies the mission."""
    from pymavlink.dialects.v20 import common as mav

    t_end = time.monotonic() + timeout_s

    def left() -> float:
        if (s := t_end - time.monotonic()) <= 0:
            raise TimeoutError(f"mission not flown within {timeout_s:g} s")
        return s

    for msg_id, hz in ((mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 5),
                       (mav.MAVLINK_MSG_ID_MISSION_ITEM_REACHED, 0)):
        if hz:
            command(conn, target, mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)
    # DO_MOUNT_CONTROL: pitch, roll, yaw (deg), ..., mode (param7).
    command(conn, target, mav.MAV_CMD_DO_MOUNT_CONTROL, -90, 0, 0, 0, 0, 0,
            mav.MAV_MOUNT_MODE_MAVLINK_TARGETING)
    command(conn, target, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
            COPTER_MODES["GUIDED"])
    while command(conn, target, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1,
                  timeout_s=min(2.0, left())) != mav.MAV_RESULT_ACCEPTED:
        time.sleep(min(1.0, left()))
    if command(conn, target, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0,
               altitude_m) != mav.MAV_RESULT_ACCEPTED:
        raise RuntimeError("take-off refused")
    while True:
        pos = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=left())
        if pos is not None and pos.relative_alt >= 0.9 * altitude_m * 1000:
            break
    if command(conn, target, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
               COPTER_MODES["AUTO"]) != mav.MAV_RESULT_ACCEPTED:
        raise RuntimeError("AUTO refused")
    while True:
        reached = conn.recv_match(type="MISSION_ITEM_REACHED", blocking=True, timeout=left())
        if reached is not None and reached.seq >= last_seq:
            return
