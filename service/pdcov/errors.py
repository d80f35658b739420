"""Error hierarchy: every message names what was wrong, where, and what was expected."""

from __future__ import annotations


class PdcovError(Exception):
    """Base of all errors pdcov raises on purpose; the CLI turns them into exit status 2."""


class ConfigError(PdcovError):
    """A configuration file or section is invalid (names the file, key and expectation)."""


class CalibrationError(ConfigError):
    """A camera calibration is invalid (names the field and the valid range)."""


class DetectorModelError(ConfigError):
    """A detector model file is invalid."""


class DomainError(ConfigError):
    """A search domain (polygon, obstacles, GeoJSON) is invalid."""


class TelemetryError(PdcovError):
    """A log or telemetry stream cannot be read or lacks what is needed."""


class InputFileError(PdcovError):
    """An input data file (CSV, grid, prior) is missing or malformed."""


class OutputError(PdcovError):
    """An output file or folder cannot be written there (names the path and why)."""


def where(source: str | None, key: str) -> str:
    """Format a location such as ``mission.yaml: camera.K`` for error messages."""
    return f"{source}: {key}" if source else key
