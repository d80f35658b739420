"""Test tiers (CONTRIBUTING.md "Tests"). A test is ``e2e`` when it starts a process, opens
a Zenoh session or router, runs the JSBSim simulator or the simulator's link, drives a
browser or talks to real firmware; ``slow`` when it needs none of these but takes more than
a few seconds; ``unit`` otherwise (given here): ``python -m pytest -m unit`` is the fast
tier.

A module of such tests says so at its top (``pytestmark = pytest.mark.e2e``); the few
end-to-end or slow tests of otherwise in-memory modules are listed in TIER_OF_TESTS; a test
using one of E2E_FIXTURES (a router, daemons, a browser) is e2e without saying so. The
rule is held at run time: a test not marked ``e2e`` that starts a process, opens a Zenoh
session or builds a JSBSim model, in its fixtures or its body, fails saying to mark it, so a
new end-to-end test cannot slip into the fast tier unnoticed."""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from pdcov import cli

# watch_fixtures: router, processes, daemons (real Zenoh on loopback); chromium: browser;
# pytester: for tests/test_tiers.py, which runs pytest sessions of its own
pytest_plugins = ["watch_fixtures", "chromium", "pytester"]

TIERS = ("e2e", "slow")
E2E_FIXTURES = frozenset({"router", "processes", "daemons", "browser"})
"""A test that uses one of these fixtures is e2e, wherever it is."""
TIER_OF_TESTS: dict[str, dict[str, str]] = {
    # module -> {test function (all its parameters): tier}
    "test_benchmarks_smoke.py": {"test_smoke_run_completes": "e2e"},
    "test_cameras.py": dict.fromkeys((
        "test_the_daemon_follows_both_cameras_as_evaluate_does",
        "test_a_two_camera_checkpoint_resumes_every_camera"), "slow"),
    "test_cli_inputs.py": {"test_full_disk_and_read_only_are_one_line_errors": "e2e"},
    "test_config_schema.py": {
        "test_cli_refuses_a_misspelt_key_with_exit_2_and_writes_nothing": "e2e"},
    "test_detector_cli.py": {"test_fit_validate_plot": "e2e",
                             "test_plot_without_validation_and_a_bad_report": "e2e"},
    "test_estimator_status.py": {"test_px4_glitch_over_udp_live_equals_offline": "e2e"},
    "test_evaluate.py": dict.fromkeys((
        "test_bad_inputs_fail_clearly", "test_compare_and_footprint",
        "test_config_errors_name_file_and_key", "test_outputs_are_readable_and_follow_the_input",
        "test_pose_csv_gives_the_core_grid",
        "test_prior_gives_probability_of_success_and_posterior",
        "test_prior_segments_with_holes_multipolygons_and_parts_outside_the_grid",
        "test_tlog_evaluates_to_the_pose_csv_grid"), "e2e"),
    "test_firmware_params.py": {"test_47_file_is_accepted_by_the_real_firmware": "e2e"},
    "test_grid.py": {"test_window_does_not_grow_with_the_domain": "slow"},
    "test_link_params.py": {"test_no_autopilot_exits_2_with_one_clear_line": "e2e"},
    "test_output_folders.py": {"test_a_real_kill_9_mid_run_is_recovered_by_the_next_run": "e2e",
                               "test_evaluate_without_prior_drops_posterior_and_says_so": "e2e"},
    "test_recorded_frames.py": dict.fromkeys((
        "test_capture_frames_duplicated_or_late_evaluate_to_the_live_grid",
        "test_evaluate_of_the_recording_is_the_live_grid",
        "test_evaluate_uses_the_recorded_frames_unless_rate_is_chosen"), "e2e"),
    "test_terrain_reference.py": dict.fromkeys((
        "test_flat_pdcov_misjudges_the_valley", "test_pdcov_with_the_dem_agrees_with_r3"),
        "slow"),
    "test_revisit_clock.py": {"test_row_order_and_time_origin_do_not_change_the_grid": "e2e"},
    "test_serve_e2e.py": {"test_real_flight_replay_equals_offline": "e2e"},
    "test_sitl_replay.py": dict.fromkeys((
        "test_a_log_with_console_junk_replays_its_mavlink_part",
        "test_replay_as_a_tcp_server_waits_for_its_client",
        "test_replay_keeps_the_pace_at_speed_n",
        "test_replay_of_a_real_ardupilot_log_arrives_complete_and_in_order"), "e2e"),
    "test_security_daemon.py": {
        "test_status_and_tiles_carry_the_daemon_session_as_source": "e2e"},
    "test_systemd_unit.py": dict.fromkeys((
        "test_systemd_analyze_security_exposure_at_most_2",
        "test_systemd_analyze_verify_is_clean", "test_sysusers_creates_pdcov_in_dialout"), "e2e"),
    "test_telemetry_logs.py": {"test_mavlink2_kept_in_a_fresh_process": "e2e"},
    "test_unseen_domain.py": dict.fromkeys((
        "test_empty_domain_refused_by_evaluate_and_plan",
        "test_flight_over_the_domain_has_no_warning",
        "test_flight_that_never_sees_the_domain_warns_with_its_distance",
        "test_no_frame_to_evaluate_says_why_and_keeps_the_summary"), "e2e"),
    "test_web_auth.py": dict.fromkeys((
        "test_watch_prints_the_tokened_url_once",
        "test_watch_refuses_a_bad_token_or_options_without_web",
        "test_watch_refuses_an_open_token_file"), "e2e"),
}
HOW_TO_MARK = ("mark it e2e: `pytestmark = pytest.mark.e2e` at the top of its module, or "
               "its name in tests/conftest.py TIER_OF_TESTS (CONTRIBUTING.md \"Tests\")")
REFUSED = (  # (module, attribute, what a test does when it calls it)
    ("subprocess", "Popen", "starts a process"),
    ("zenoh", "open", "opens a Zenoh session"),
    ("jsbsim", "FGFDMExec", "builds a JSBSim model"),
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        listed = TIER_OF_TESTS.get(item.path.name, {})
        name = getattr(item, "originalname", item.name)
        if name in listed:
            item.add_marker(listed[name])
        if E2E_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.e2e)
        if not any(item.get_closest_marker(tier) for tier in TIERS):
            item.add_marker(pytest.mark.unit)
    for module in {item.module for item in items if isinstance(item, pytest.Function)}:
        stale = [n for n in TIER_OF_TESTS.get(module.__name__ + ".py", {})
                 if not hasattr(module, n)]
        if stale:
            raise pytest.UsageError(f"tests/conftest.py TIER_OF_TESTS names tests that "
                                    f"{module.__name__}.py does not have: {', '.join(stale)}")


@contextmanager
def _refused(item: pytest.Item) -> Iterator[None]:
    """No child process, Zenoh session or JSBSim model for a test not marked ``e2e``."""
    if item.get_closest_marker("e2e") is not None:
        yield
        return
    with pytest.MonkeyPatch.context() as mp:
        for module_name, attribute, what in REFUSED:
            try:
                module = importlib.import_module(module_name)
            except ImportError:
                continue  # not installed: nothing to refuse
            mp.setattr(module, attribute, _refuse(item.nodeid, what))
        yield


def _refuse(nodeid: str, what: str):
    def refused(*args, **kwargs):
        raise RuntimeError(f"{nodeid} {what} but is not marked e2e: {HOW_TO_MARK}")
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
