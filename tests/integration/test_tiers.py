"""The test tiers of tests/conftest.py, in a pytest session of their own (pytester): every
test not marked e2e or slow is unit; one that starts a process unmarked fails saying how to
mark it, in its body or in a module-scoped fixture; marked, it runs; a stale entry of
TIER_OF_TESTS stops the collection. e2e itself: its inner tests start a process."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e

CONFTEST = Path(__file__).with_name("conftest.py").read_text()
MARKERS = """
[pytest]
addopts = --strict-markers
markers =
    unit: in memory
    e2e: processes
    slow: slow
"""
TESTS = """
import subprocess

import pytest


def test_in_memory():
    assert 1 + 1 == 2


def test_starts_a_process():
    subprocess.run(["true"], check=True)


@pytest.mark.e2e
def test_marked_starts_a_process():
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
    pytester.makepyfile(test_sample=TESTS)
    return pytester


def test_unmarked_processes_fail_saying_how_to_mark_them(session):
    r = session.runpytest("-p", "no:cacheprovider")
    r.assert_outcomes(passed=2, failed=1, errors=1)
    out = r.stdout.str()
    assert "test_sample.py::test_starts_a_process starts a process but is not marked e2e" in out
    assert "test_sample.py::test_a_fixture_starts_a_process starts a process" in out
    assert "pytestmark = pytest.mark.e2e" in out


def test_unit_is_everything_not_marked(session):
    r = session.runpytest("-p", "no:cacheprovider", "-m", "unit", "--collect-only", "-q")
    out = r.stdout.str()
    assert "test_in_memory" in out and "test_marked_starts_a_process" not in out
    session.runpytest("-m", "e2e", "-p", "no:cacheprovider").assert_outcomes(passed=1)


def test_a_stale_tier_entry_stops_the_collection(session):
    session.makeconftest(CONFTEST.replace(
        'TIER_OF_TESTS: dict[str, dict[str, str]] = {',
        'TIER_OF_TESTS: dict[str, dict[str, str]] = {"test_sample.py": {"test_gone": "e2e"},'))
    r = session.runpytest("-p", "no:cacheprovider")
    assert r.ret == pytest.ExitCode.USAGE_ERROR
    assert "test_sample.py does not have: test_gone" in r.stderr.str()
