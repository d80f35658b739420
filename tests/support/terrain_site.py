"""A terrain scenario's files (issue 21) and R3, the per-pixel DEM ray caster, over them,
shared by the tests and the benchmarks.

``TerrainSite.prepare`` writes the scenario's valley DEM (GeoTIFF, UTM 32 N) and its mission
config (``terrain: {dem: valley.tif}``) into a folder; pdcov takes its terrain from the loaded
mission (``mission.terrain``), R3 reads the same file on its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from pdcov.config.load import load_mission
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from tests.support.references import pixel_rays
from tests.support.scenarios import Scenario
from tests.support.terrain_reference import Heightfield, TerrainReferenceGrid, r3_update

DEM_FILE = "valley.tif"
# R3 on S5 casts every pixel's ray (1920 x 1080: 2 M rays per frame). Over the whole valley
# flight, to keep it to minutes, it casts through the centre of every 2 x 2 block (518 400
# rays): flown over level ground that still puts 99.7 % of cells within 0.05 of flat pdcov.
VALLEY_STEP_PX = 2


@dataclass(frozen=True)
class TerrainSite:
    """A terrain scenario's files in ``folder`` and R3's heightfield over its DEM."""

    scenario: Scenario
    mission_path: Path
    heightfield: Heightfield

    @classmethod
    def prepare(cls, folder: Path, sc: Scenario) -> TerrainSite:
        """Write the DEM and the mission config into ``folder``; sample R3's heightfield
        over the domain and the DEM's margin."""
        relief = sc.relief
        if relief is None:
            raise ValueError(f"{sc.name} has no relief")
        dem = relief.write_geotiff(folder / DEM_FILE)
        mission_path = folder / "mission.yaml"
        mission_path.write_text(yaml.safe_dump(sc.mission_doc(DEM_FILE), sort_keys=False))
        m = relief.margin_m - relief.spacing_m  # the lattice stays inside the raster
        hf = Heightfield.from_dem(dem, relief.origin_lat_deg, relief.origin_lon_deg,
                                  relief.floor_alt_msl_m,
                                  (-m, -m, sc.side_m + m, sc.side_m + m), relief.spacing_m)
        return cls(sc, mission_path, hf)

    def terrain_grid(self) -> CoverageGrid:
        """pdcov's grid over the terrain of the mission config (its DEM)."""
        return load_mission(self.mission_path).new_mission_grid()

    def reference(self, grid: CoverageGrid, step_px: int = 1) -> TerrainReferenceGrid:
        """An empty R3 grid like ``grid`` (cells, camera, detector, range)."""
        return TerrainReferenceGrid(grid.geometry, grid.mask, grid.camera, grid.detector,
                                    grid.max_range_m, self.heightfield, step_px)

    def run_reference(self, grid: CoverageGrid, poses: list[CameraPose],
                      step_px: int = 1) -> TerrainReferenceGrid:
        """R3 over ``poses`` in a fresh grid like ``grid``, through every ``step_px``-th
        pixel."""
        ref = self.reference(grid, step_px)
        rays = pixel_rays(grid.camera, step_px)
        for pose in poses:
            r3_update(ref, rays, pose)
        return ref
