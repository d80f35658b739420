"""Flight logs -> one ``FlightLog`` of time-sorted telemetry arrays in the autopilot clock.

Formats: MAVLink telemetry logs (.tlog: ``telemetry.tlog``), ArduPilot DataFlash (.bin:
pymavlink DFReader) and PX4 ULog (.ulg: pyulog, the optional ``ulog`` extra), told apart by
their first bytes. Times are the autopilot's boot clock (time_boot_ms, TimeUS, ULog
timestamps), made monotonic across restarts by ``clocks.BootClock``; a tlog's wall-clock
stamps are never used (a log may have been recorded faster than real time). Every failure to
read becomes a ``TelemetryError`` that names the file; a damaged log is read up to and past
its damage, which ``FlightLog.damage`` describes.
"""

from pdcov.telemetry.logs.choose import for_gimbal
from pdcov.telemetry.logs.flight_log import FlightLog
from pdcov.telemetry.logs.reader import read_flight_log

__all__ = ["FlightLog", "for_gimbal", "read_flight_log"]
