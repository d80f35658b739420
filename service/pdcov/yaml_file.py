"""Reading YAML files with errors that name the file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from pdcov.errors import ConfigError


def load_yaml(path: str | Path, what: str, error: type[ConfigError] = ConfigError) -> Any:
    """The parsed document of a YAML file; ``error`` names the file and what it should be."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({exc})") from None
