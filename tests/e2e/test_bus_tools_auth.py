"""Issue 21 point 6 with tokens: the bus tools send on the bus, which the
gateway allows an admin only; a page signed in as an operator shows
them disabled with the reason, an admin's page has them enabled."""

import os

import pytest

from conftest import free_port
from test_signin import ADMIN, OPERATOR, TokenServer, sign_in, signin_visible, take_whoami_401

CONTROLS = ["sync-start", "sync-stop", "sync-period", "raw-id", "raw-data", "raw-send", "rpdo-node", "rpdo-load"]


@pytest.fixture
def server():
    # Overrides the conftest's: the browser fixture gets this one.
    s = TokenServer(free_port())
    s.start()
    yield s
    s.stop()
    os.unlink(s.log_file.name)
    os.unlink(s.config.name)


def open_signed_in(browser, server, token):
    browser.driver.get(server.url + "/buses/demo/trace")
    browser.wait(lambda _: signin_visible(browser), message="no sign-in form")
    take_whoami_401(browser)
    sign_in(browser, token)
    browser.wait(lambda _: not signin_visible(browser), message="the sign-in did not close")


def disabled(browser):
    return browser.js("return arguments[0].map((id) => document.getElementById(id).disabled)", CONTROLS)


def test_an_operator_sees_the_bus_tools_disabled_with_the_reason(server, browser):
    open_signed_in(browser, server, OPERATOR)
    browser.wait(lambda _: all(disabled(browser)), message=f"enabled for an operator: {disabled(browser)}")
    refusal = browser.js("return document.getElementById('send-refusal').textContent")
    assert refusal == "Sending on the bus needs an admin token; this page is signed in as operator."
    assert browser.js("return document.getElementById('send-refusal').hidden") is False
    assert browser.js("return document.getElementById('raw-send').title") == refusal


def test_an_admin_has_the_bus_tools(server, browser):
    open_signed_in(browser, server, ADMIN)
    browser.wait(lambda _: browser.js("return document.getElementById('sync-state')?.dataset.state") == "off",
                 message="the SYNC state was not read")
    states = dict(zip(CONTROLS, disabled(browser)))
    # Stop SYNC waits for a SYNC to stop; the rest are there to use.
    assert states.pop("sync-stop") is True
    assert not any(states.values()), states
    assert browser.js("return document.getElementById('send-refusal').hidden") is True
