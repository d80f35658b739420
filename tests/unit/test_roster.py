"""The fleet roster (ground/roster.py, fleet.vehicles): a vehicle not on it is unknown,
listed with why, and changes no figure; without a roster everything is merged as before
and the views say there is none."""

from __future__ import annotations

import pytest

from pdcov.errors import ConfigError
from pdcov.ground.roster import NO_ROSTER, Roster, roster_of
from pdcov.ground.terminal import plain_lines
from pdcov.ground.watcher import Watcher
from tests.support.watch_fixtures import Link, TinyPublisher


def fly_with_rogue(watcher: Watcher) -> None:
    """uav1 flies 20 frames; an invented uav9 flies a whole other lane, status and tiles."""
    real, rogue = Link(TinyPublisher("uav1"), watcher), Link(TinyPublisher("uav9", y_m=-20.0),
                                                             watcher)
    for _ in range(20):
        real.fly(1)
        rogue.fly(1)
    rogue.pub.step(30)
    rogue.fly(1)
    rogue.status()


def test_a_vehicle_not_on_the_roster_changes_no_figure_and_is_listed_as_unknown():
    alone = Watcher(roster=Roster(frozenset({"uav1", "uav2"})))
    Link(TinyPublisher("uav1"), alone).fly(20)
    with_rogue = Watcher(roster=Roster(frozenset({"uav1", "uav2"})))
    fly_with_rogue(with_rogue)
    before, after = alone.report(5.0), with_rogue.report(5.0)
    assert after.merged == ("uav1",) and list(with_rogue.feeds) == ["uav1"]
    assert after.proportion_at_or_above == before.proportion_at_or_above
    assert after.mean_pd == before.mean_pd and after.cells_free == before.cells_free
    assert [v.vehicle_id for v in after.vehicles] == ["uav1"]
    assert with_rogue.taken_from("uav9", "snapshot") == ()
    assert list(after.unknown) == ["uav9"] and "not on fleet.vehicles" in after.unknown["uav9"]
    assert any(w.startswith("unknown vehicle uav9: not on fleet.vehicles")
               for w in after.warnings)
    assert after.notes == ()
    assert any("unknown vehicle uav9" in line for line in plain_lines(after))


def test_without_a_roster_every_vehicle_is_merged_and_the_views_say_so():
    w = Watcher()
    fly_with_rogue(w)
    report = w.report(5.0)
    assert report.merged == ("uav1", "uav9") and report.unknown == {}
    assert report.notes == (NO_ROSTER,) and NO_ROSTER not in report.warnings
    assert NO_ROSTER in plain_lines(report)


def test_roster_of_the_mission_config():
    assert roster_of({}) == Roster() and roster_of({"fleet": {}}) == Roster()
    assert roster_of({"fleet": {"vehicles": ["uav1", "uav2"]}}).vehicles == {"uav1", "uav2"}
    for bad, match in (({"fleet": {"vehicles": []}}, "non-empty list"),
                       ({"fleet": {"vehicles": "uav1"}}, "non-empty list"),
                       ({"fleet": {"vehicles": ["uav 1"]}}, "fleet.vehicles: 'uav 1'"),
                       ({"fleet": {"vehicles": [3]}}, "fleet.vehicles"),
                       ({"fleet": {"vehicle": ["uav1"]}}, "unknown key"),
                       ({"fleet": ["uav1"]}, "expected a mapping")):
        with pytest.raises(ConfigError, match=match):
            roster_of(bad, "m.yaml")


def test_unknown_vehicles_are_listed_up_to_the_vehicle_limit_then_counted():
    w = Watcher(roster=Roster(frozenset({"uav1"})), max_vehicles=3)
    for k in range(10):
        w.on_alive(f"rogue{k}", True, 1.0)
    w.on_alive("rogue0", True, 2.0)
    report = w.report(2.0)
    assert list(report.unknown) == ["rogue0", "rogue1", "rogue2"] and w.feeds == {}
    assert "2 samples refused" in report.unknown["rogue0"]
    assert report.refused == {"not on fleet.vehicles, beyond 3 ids": 7}
