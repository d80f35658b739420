"""The demo mission's search flight: its people, and a plan over its domain, for the tests
of the search loop and of the pins across restarts."""

from __future__ import annotations

from pathlib import Path

PEOPLE = 200


DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"


def demo_plan(folder: Path) -> Path:
    """The live demo's plan: a spiral over the scene at 10 m, 5 m/s (commands/demo.py)."""
    from pdcov.commands.plan import scenario_of
    from pdcov.config.load import load_mission
    from pdcov.planning.optimise import PlanParams, build_plan
    from pdcov.planning.plan_files import write_plan

    mission = load_mission(DEMO)
    plan, _ = build_plan(scenario_of(mission), PlanParams("spiral", 10.0, 5.0))
    path = folder / "demo.plan"
    write_plan(path, plan, mission.origin())
    return path
