"""The web map in chromium shows the re-tasking commands to the operator's token only
(tests/unit/test_web_operator.py: the access rules themselves)."""

from __future__ import annotations

from pdcov.ground.web_auth import NO_OPERATOR
from tests.support.operator_access import BOTH, OPERATOR, VIEW, VIEW_ONLY
from tests.support.watch_fixtures import ThreadedWebMap


def test_the_page_shows_commands_to_the_operator_only(browser):
    from tests.support.chromium import wait_for

    for access in (BOTH, VIEW_ONLY):
        s = ThreadedWebMap(lambda: {"version": 7, "vehicles": [], "grid": None}, access)
        base = f"http://127.0.0.1:{s.web.port}/"
        try:
            for token, commands in ((VIEW, False), (OPERATOR, access is BOTH), (VIEW, False)):
                # Without an operator token, OPERATOR is a wrong token: the view cookie
                # of the first visit serves the page, as a viewer's.
                browser.get(f"{base}?token={token}")
                note = wait_for(lambda: browser.execute_script(
                    "const n = document.getElementById('command-note');"
                    "return n && (n.textContent || (!document.getElementById("
                    "'refly-commands').hidden && 'commands'));"), 30, "the page asked whoami")
                shown = browser.find_element("id", "refly-ask").is_displayed()
                assert shown is commands, (token, note)
                if not commands:
                    assert note.startswith("view only: "), note
                    assert (NO_OPERATOR if access is VIEW_ONLY else "view token") in note
        finally:
            s.close()
