"""Test tiers (CONTRIBUTING.md "Tests"): a test's tier is the folder it lives in under tests/,
and it is marked with that folder's name (``pytest -m unit`` is ``pytest tests/unit``):

* unit: in memory and quick, the fast tier;
* slow: in memory, but seconds per test (real logs, whole flights, fits, fuzz properties);
* integration: starts processes (pdcov commands, the simulator's link, GDAL, systemd);
* system: Zenoh routers and sessions, several daemons;
* simulators: JSBSim flights, the real ArduCopter SITL, MAVSDK;
* browsers: chromium.

A test goes in the folder of the heaviest thing it (or a fixture it uses) starts, in that
order. The in-memory tiers are held at run time: a test in unit/ or slow/ that starts a
process, opens a Zenoh session or builds a JSBSim model, in its fixtures or its body, fails
saying to move it, so an end-to-end test cannot slip into the fast tier unnoticed. A test
module outside the tier folders stops the collection. Shared helpers live in tests/support
(``from tests.support.X import ...``)."""

from __future__ import annotations

import importlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from pdcov import cli

# One BLAS thread per process. The suite runs a pytest-xdist worker per core (.ci/run), and
# many tests start processes of their own; an OpenBLAS pool of a thread per core in each of
# them oversubscribes the cores (its threads spin while they wait): R3's 518,400 ray
# rotations per frame took 4 times as long. Set before numpy's first import (the plugins
# below import it; nothing above does), so this process, the xdist workers and every
# process a test starts inherit it.
for _blas_threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas_threads, "1")

# matplotlib builds its font cache at its first import on a machine, running fontconfig's
# fc-list when installed (Debian's chromium brings it): built here, once per process, before
# any test, so that a figure drawn by an in-memory test does not start that process.
try:
    import matplotlib.font_manager  # noqa: F401
except ImportError:  # without the plots extra: no figure is drawn
    pass

# The support modules that hold fixtures of more than one tier: watch_fixtures: router,
# processes, daemons (real Zenoh on loopback); chromium: browser; cli_inputs: poses;
# link_params_autopilot: autopilot (a parameter server); output_runs: umask; pytester: for
# tests/integration/test_tiers.py, which runs pytest sessions of its own
pytest_plugins = ["tests.support.watch_fixtures", "tests.support.chromium",
                  "tests.support.cli_inputs", "tests.support.link_params_autopilot",
                  "tests.support.output_runs", "pytester"]

TESTS = Path(__file__).resolve().parent
TIERS = ("unit", "slow", "integration", "system", "simulators", "browsers")
"""The tier folders under tests/, lightest first (pyproject.toml declares their markers)."""
IN_MEMORY = frozenset({"unit", "slow"})
"""The tiers whose tests may not start a process, a Zenoh session or a JSBSim model."""
REFUSED = (  # (module, attribute, what a test does when it calls it)
    ("subprocess", "Popen", "starts a process"),
    ("zenoh", "open", "opens a Zenoh session"),
    ("jsbsim", "FGFDMExec", "builds a JSBSim model"),
)


def tier_of(path: Path) -> str | None:
    """The tier of the test module at ``path``: its first folder under tests/, if a tier."""
    try:
        parts = path.resolve().relative_to(TESTS).parts
    except ValueError:  # not under tests/
        return None
    return parts[0] if len(parts) > 1 and parts[0] in TIERS else None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    outside = sorted({str(item.path) for item in items if tier_of(item.path) is None})
    if outside:
        raise pytest.UsageError(f"test modules outside the tier folders "
                                f"({', '.join(TIERS)}): {', '.join(outside)}")
    for item in items:
        item.add_marker(tier_of(item.path))


@contextmanager
def _refused(item: pytest.Item) -> Iterator[None]:
    """No child process, Zenoh session or JSBSim model for a test of an in-memory tier."""
    tier = tier_of(item.path)
    if tier not in IN_MEMORY:
        yield
        return
    with pytest.MonkeyPatch.context() as mp:
        for module_name, attribute, what in REFUSED:
            try:
                module = importlib.import_module(module_name)
            except ImportError:
                continue  # not installed: nothing to refuse
            mp.setattr(module, attribute, _refuse(item.nodeid, what, tier))
        yield


def _refuse(nodeid: str, what: str, tier: str | None):
    def refused(*args, **kwargs):
        raise RuntimeError(f"{nodeid} {what} but lives in tests/{tier}/, an in-memory tier: "
                           f"move it to the folder of what it starts (tests/conftest.py, "
                           f"CONTRIBUTING.md \"Tests\")")
    return refused


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    with _refused(item):  # module- and session-scoped fixtures start here too
        return (yield)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    with _refused(item):
        return (yield)


@pytest.fixture
def pdcov(capsys):
    """Run the real console entry point in this process: (status, stdout, stderr)."""

    def run(*argv: str | Path) -> tuple[int, str, str]:
        status = cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return status, out, err

    return run
