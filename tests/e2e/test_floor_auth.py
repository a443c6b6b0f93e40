"""Issue 21 with tokens configured: every request the dashboard makes
carries the page's token, the node page's DCF backup (text, not JSON,
so not through the api() helper) included."""

import os

import pytest

from conftest import free_port
from test_node import result
from test_signin import ADMIN, TokenServer, sign_in, signin_visible, take_whoami_401


@pytest.fixture
def server():
    # Overrides the conftest's: the browser fixture gets this one.
    s = TokenServer(free_port())
    s.start()
    yield s
    s.stop()
    os.unlink(s.log_file.name)
    os.unlink(s.config.name)


def test_dcf_backup_carries_the_token(server, browser):
    browser.driver.get(server.url + "/nodes/demo/1")
    browser.wait(lambda _: signin_visible(browser), message="no sign-in form")
    take_whoami_401(browser)
    sign_in(browser, ADMIN)
    browser.wait(lambda _: not signin_visible(browser), message="the sign-in did not close")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")
    browser.driver.find_element("id", "dcf-download").click()
    browser.wait(lambda _: result(browser, "config-result")[0] in ("done", "failed"), timeout=30, message="no backup")
    state, text = result(browser, "config-result")
    assert state == "done" and "Backup read" in text, text
    assert not signin_visible(browser), "the backup's request was refused: the sign-in came back"
