"""A domain without a free cell is refused when the mission loads."""

from __future__ import annotations

import pytest

from pdcov.config.load import mission_from_dict
from pdcov.errors import ConfigError
from tests.support.evaluate_inputs import mission_doc

SQUARE = [[0, 0], [40, 0], [40, 40], [0, 40]]


@pytest.mark.parametrize("domain", [
    {"polygon_enu_m": SQUARE, "obstacles_enu_m": [[[-1, -1], [41, -1], [41, 41], [-1, 41]]]},
    {"polygon_enu_m": [[0, 0], [40, 0], [40, 0.3], [0, 0.3]], "cell_size_m": 1.0},
    {"polygon_enu_m": [[0.1, 0.1], [0.4, 0.1], [0.4, 0.4], [0.1, 0.4]], "cell_size_m": 1.0},
], ids=["obstacle-covers-it", "sliver-narrower-than-a-cell", "smaller-than-a-cell"])
def test_domain_without_a_free_cell_is_refused_at_load(domain):
    with pytest.raises(ConfigError, match=r"m.yaml: domain: no free cell to cover"):
        mission_from_dict(mission_doc(domain=domain), source="m.yaml")
