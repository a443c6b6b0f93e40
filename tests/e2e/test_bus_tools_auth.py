"""Issue 21 point 6 with tokens: the bus tools send on the bus, which the
gateway allows an operator and an admin ("operator only, audited"); a
page signed in as a viewer shows them disabled with the reason, an
operator's and an admin's have them enabled, and what an operator sends
is audited with its name."""

import os

import pytest
from selenium.webdriver.common.by import By

from conftest import free_port
from test_signin import ADMIN, CONFIG, OPERATOR, TokenServer, sign_in, signin_visible, take_whoami_401

VIEWER = "hmi-viewer-2f6a0c9e7b13d485"

CONTROLS = ["sync-start", "sync-stop", "sync-period", "raw-id", "raw-data", "raw-send", "rpdo-node", "rpdo-load"]


@pytest.fixture
def server():
    # Overrides the conftest's: the browser fixture gets this one.
    s = TokenServer(free_port())
    with open(s.config.name, "w", encoding="utf-8") as f:
        f.write(CONFIG + f'\n[[tokens]]\nname = "hmi"\nrole = "viewer"\ntoken = "{VIEWER}"\n')
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


def test_a_viewer_sees_the_bus_tools_disabled_with_the_reason(server, browser):
    open_signed_in(browser, server, VIEWER)
    browser.wait(lambda _: all(disabled(browser)), message=f"enabled for a viewer: {disabled(browser)}")
    refusal = browser.js("return document.getElementById('send-refusal').textContent")
    assert refusal == "Sending on the bus needs an operator or admin token; this page is signed in as viewer."
    assert browser.js("return document.getElementById('send-refusal').hidden") is False
    assert browser.js("return document.getElementById('raw-send').title") == refusal


def assert_bus_tools_offered(server, browser, token):
    """Signed in with `token`: every bus tool enabled but Stop SYNC (it
    waits for a SYNC to stop), and no refusal shown."""
    open_signed_in(browser, server, token)
    browser.wait(lambda _: browser.js("return document.getElementById('sync-state')?.dataset.state") == "off",
                 message="the SYNC state was not read")
    states = dict(zip(CONTROLS, disabled(browser)))
    assert states.pop("sync-stop") is True
    assert not any(states.values()), states
    assert browser.js("return document.getElementById('send-refusal').hidden") is True


def test_an_operator_has_the_bus_tools_and_is_audited(server, browser):
    assert_bus_tools_offered(server, browser, OPERATOR)
    # SYNC from the operator's page: sent, and audited with its name.
    browser.driver.find_element(By.ID, "sync-start").click()
    browser.wait(lambda _: browser.js("return document.getElementById('sync-state').dataset.state") == "on",
                 message="SYNC did not start for the operator")
    browser.driver.find_element(By.ID, "sync-stop").click()
    browser.wait(lambda _: browser.js("return document.getElementById('sync-state').dataset.state") == "off",
                 message="SYNC did not stop")
    audit = [e for e in server.get("/api/v1/events?kind=audit&limit=200") if e.get("path") == "/api/v1/buses/demo/sync"]
    assert len(audit) >= 2 and all(e["who"] == "line-plc" and e["role"] == "operator" for e in audit), audit


def test_an_admin_has_the_bus_tools(server, browser):
    assert_bus_tools_offered(server, browser, ADMIN)
