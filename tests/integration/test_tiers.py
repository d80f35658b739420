"""The test tiers of tests/conftest.py, in a pytest session of their own (pytester): a test
is marked with its folder's tier; one in unit/ (or slow/) that starts a process fails saying
to move it, in its body or in a module-scoped fixture; in integration/ the same test runs;
a test module outside the tier folders stops the collection. Integration itself: its inner
tests start a process."""

from __future__ import annotations

from pathlib import Path

import pytest

CONFTEST = Path(__file__).resolve().parents[1].joinpath("conftest.py").read_text()
MARKERS = """
[pytest]
addopts = --strict-markers
markers =
    unit: in memory
    slow: in memory, long
    integration: processes
    system: routers
    simulators: simulators
    browsers: chromium
"""
IN_MEMORY = """
def test_in_memory():
    assert 1 + 1 == 2
"""
PROCESSES = """
import subprocess

import pytest


def test_starts_a_process():
    subprocess.run(["true"], check=True)


@pytest.fixture(scope="module")
def child():
    with subprocess.Popen(["true"]) as p:
        yield p


def test_a_fixture_starts_a_process(child):
    assert child.wait() == 0
"""


@pytest.fixture
def session(pytester: pytest.Pytester) -> pytest.Pytester:
    pytester.makeini(MARKERS)
    pytester.makeconftest(CONFTEST)
    for tier in ("unit", "integration"):
        pytester.mkpydir(tier)
    pytester.path.joinpath("unit", "test_memory.py").write_text(IN_MEMORY)
    pytester.path.joinpath("unit", "test_processes_in_unit.py").write_text(PROCESSES)
    pytester.path.joinpath("integration", "test_processes.py").write_text(PROCESSES)
    return pytester


def test_a_process_in_unit_fails_saying_to_move_it(session):
    r = session.runpytest("-p", "no:cacheprovider")
    r.assert_outcomes(passed=3, failed=1, errors=1)
    out = r.stdout.str()
    assert ("unit/test_processes_in_unit.py::test_starts_a_process starts a process but lives "
            "in tests/unit/, an in-memory tier: move it") in out
    assert "unit/test_processes_in_unit.py::test_a_fixture_starts_a_process starts a process" \
        in out


def test_each_test_is_marked_with_its_folder(session):
    r = session.runpytest("-p", "no:cacheprovider", "-m", "unit", "--collect-only", "-q")
    out = r.stdout.str()
    assert "unit/test_memory.py::test_in_memory" in out
    assert "integration/" not in out
    session.runpytest("-m", "integration", "-p", "no:cacheprovider").assert_outcomes(passed=2)


def test_a_module_outside_the_tier_folders_stops_the_collection(session):
    session.makepyfile(test_stray=IN_MEMORY)
    r = session.runpytest("-p", "no:cacheprovider")
    assert r.ret == pytest.ExitCode.USAGE_ERROR
    assert "test modules outside the tier folders" in r.stderr.str()
    assert "test_stray.py" in r.stderr.str()
