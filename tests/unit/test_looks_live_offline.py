"""coverage.looks: correlated and viewpoint: the daemon's grid, whose P_D is derived at each
poll from the looks counted since, equals ``pdcov evaluate``'s of the same bytes, derived
once, cell for cell (one pipeline: Mission.new_grid and CoverageGrid.update)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.looks import LooksRule
from pdcov.service.settings import load_serve_config
from tests.support.link_feed import (
    FIXED,
    GROUND_M,
    LAT_DEG,
    LON_DEG,
    MISSION,
    LinkFeed,
    offline_of,
    pack,
)

DETECTOR = {"version": 4, "input_size_px": 640,
            "fa_rate_per_mpx": [0.05, 0.06, 0.08, 0.1, 0.12],
            "bin_edges_px": [4, 12, 24, 48, 96, 200],
            "p_detect": [0.1, 0.3, 0.45, 0.4, 0.2],
            "p_false_alarm": [0.02, 0.03, 0.04, 0.05, 0.06],
            "looks": {"correlation": [0.4, 0.3, 0.25, 0.3, 0.5]}}


def flying_east(seconds: float = 8.0) -> list[mavlink.MAVLink_message]:
    """A vehicle 10 m up flying east at 3 m/s across the domain, turning slowly: HEARTBEAT,
    HOME_POSITION, then ATTITUDE and GLOBAL_POSITION_INT at 20 Hz."""
    mav = mavlink.MAVLink(None)
    deg_per_m = 1.0 / 111_320.0
    out = [mav.heartbeat_encode(2, 3, 128 | 1, 4, 4),
           mav.home_position_encode(round(LAT_DEG * 1e7), round(LON_DEG * 1e7),
                                    round(GROUND_M * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)]
    for k in range(int(seconds * 20)):
        ms = 1000 + 50 * k
        east_m, north_m = 3.0 + 3.0 * k / 20, 15.0 + 2.0 * math.sin(k / 25)
        if k % 20 == 0:
            out.append(mav.heartbeat_encode(2, 3, 128 | 1, 4, 4))
        out.append(mav.attitude_encode(ms, 0.02, -0.05, 0.4 + 0.01 * k, 0, 0, 0))
        out.append(mav.global_position_int_encode(
            ms, round((LAT_DEG + north_m * deg_per_m) * 1e7),
            round((LON_DEG + east_m * deg_per_m / math.cos(math.radians(LAT_DEG))) * 1e7),
            round((GROUND_M + 10) * 1000), 10_000, 0, 0, 0, 0))
    return out


@pytest.mark.parametrize("rule", ["correlated", "viewpoint"])
def test_daemon_grid_equals_evaluate_with_looks(tmp_path: Path, rule: str) -> None:
    doc = dict(MISSION, detector=DETECTOR, mount=FIXED, coverage={"looks": rule})
    doc["service"] = {"state_dir": str(tmp_path / "state"), "record": False}
    path = tmp_path / "mission.yaml"
    path.write_text(yaml.safe_dump(doc))
    cfg = load_serve_config(path)
    assert cfg.mission.looks.rule is LooksRule(rule)
    data = [pack(m, seq=i) for i, m in enumerate(flying_east())]
    tlog = tmp_path / "hover.tlog"
    tlog.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 1000 * i) + d
                              for i, d in enumerate(data)))
    _, off = offline_of(cfg, tlog)

    feed = LinkFeed(cfg)
    for i in range(0, len(data), 7):  # polls between frames: P_D derived window by window
        feed.feed(b"".join(data[i:i + 7]), 0.5 * i)
    feed.tick(1e4)
    live = feed.live.grid
    assert live.frames == off.frames > 30
    assert (off.n_obs > 10).sum() > 100
    for key in ("log_miss_d", "log_miss_fa", "n_obs"):
        np.testing.assert_array_equal(getattr(live, key), getattr(off, key), err_msg=key)
    np.testing.assert_array_equal(live.log_miss_nodes(), off.log_miss_nodes())
