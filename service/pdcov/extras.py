"""The optional parts of pdcov: each extra of pyproject.toml that pdcov imports from, and
the one message that says which to install when a part is missing.

A base install (``pip install pdcov``) runs the onboard daemon and ``pdcov evaluate``'s
numbers (metrics.json, grid.npz); figures, GeoTIFF / GeoJSON files, the GPX export and the
pins' grid references, the ground station and the simulator each need their extra."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

from pdcov.errors import PdcovError


@dataclass(frozen=True, slots=True)
class Extra:
    """``pip install 'pdcov[name]'``: the modules pdcov imports from it and what needs
    them, as the start of a sentence ("figures need")."""

    name: str
    modules: tuple[str, ...]
    needed_by: str

    def missing(self) -> tuple[str, ...]:
        """The modules of this extra that are not installed (found, not imported)."""
        return tuple(m for m in self.modules if not _installed(m))

    def message(self, needed_by: str | None = None) -> str | None:
        """One line naming what is missing and the command that installs it; None when
        nothing is missing."""
        missing = self.missing()
        if not missing:
            return None
        names = ", ".join(missing[:-1]) + " and " * (len(missing) > 1) + missing[-1]
        return f"{needed_by or self.needed_by} {names}: pip install 'pdcov[{self.name}]'"

    def require(self, needed_by: str | None = None) -> None:
        """Raise PdcovError (one line, exit 2 from the CLI) when a module is missing."""
        message = self.message(needed_by)
        if message is not None:
            raise PdcovError(message)


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ValueError:  # in sys.modules as None: refused, as not installed
        return False


PLOTS = Extra("plots", ("matplotlib",), "figures need")
GIS = Extra("gis", ("rasterio",), "GeoTIFF and GeoJSON outputs need")
GPX = Extra("gis", ("gpxpy",), "the GPX export needs")
GRID_REFERENCES = Extra("gis", ("mgrs",), "MGRS and UTM references need")
GROUND = Extra("ground", ("rich", "aiohttp"), "pdcov watch needs")
COT = Extra("ground", ("pytak", "mgrs"), "pdcov watch --cot needs")
ROUTING = Extra("routing", ("ortools",), "pdcov plan --pattern vantage needs")
CLUSTER = Extra("cluster", ("distributed",), "pdcov evaluate --dask needs")
SITL = Extra("sitl", ("jsbsim",), "the simulator needs")
DEMO = Extra("demo", ("jsbsim", "rich", "aiohttp", "matplotlib", "rasterio"),
             "pdcov demo needs")
