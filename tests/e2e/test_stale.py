"""Issue 21 point 5, stale values marked: a TPDO value on the PDO page is
fresh while SYNC runs and, once SYNC stops, greyed with its age growing;
the drive page's readouts and statusword carry their age and turn stale
while the node is stopped (the gateway no longer reads it), fresh again
once it is started. Every wait is for a state, with a generous timeout."""

import re

from selenium.webdriver.common.by import By

from test_bus_tools import dataset, start_node
from test_drive import open_drive

AGE = re.compile(r"\d+(\.\d)? s ago")
VALUE = "#tpdo-1 output.live[data-key=\"a1_Statusword\"]"


def age_of(browser, selector):
    return browser.js(
        "const e = document.querySelector(arguments[0]); return e && e.dataset.ageMs !== undefined ? Number(e.dataset.ageMs) : null",
        selector)


def age_text(browser, selector):
    return browser.js("return document.querySelector(arguments[0]).parentElement.querySelector('.age').textContent", selector)


def test_a_tpdo_value_turns_stale_with_its_age_when_sync_stops(server, browser):
    start_node(server, 1)
    browser.driver.get(server.url + "/nodes/demo/1/pdos")
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "off", message="the SYNC state was not read")
    browser.driver.find_element(By.ID, "sync-start").click()
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "on", message="SYNC did not start")
    try:
        browser.wait(lambda _: dataset(browser, VALUE, "stale") == "no", timeout=20,
                     message="the TPDO value never showed fresh with SYNC running")
        assert AGE.fullmatch(age_text(browser, VALUE)), age_text(browser, VALUE)
        assert not browser.js("return document.querySelector(arguments[0]).classList.contains('stale')", VALUE)
    finally:
        browser.driver.find_element(By.ID, "sync-stop").click()
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "off", message="SYNC did not stop")
    # No SYNC, no synchronous TPDO: the value keeps what it was, greyed,
    # with an age that grows.
    browser.wait(lambda _: dataset(browser, VALUE, "stale") == "yes", timeout=20,
                 message=f"the value stayed fresh after SYNC stopped: {age_text(browser, VALUE)}")
    assert browser.js("return document.querySelector(arguments[0]).classList.contains('stale')", VALUE)
    first = age_of(browser, VALUE)
    assert first >= 2000, first
    browser.wait(lambda _: age_of(browser, VALUE) >= first + 1000, timeout=20, message="the age did not grow")
    assert AGE.fullmatch(age_text(browser, VALUE)), age_text(browser, VALUE)
    # The value is still the last one the node sent, not blanked.
    assert browser.js("return document.querySelector(arguments[0]).textContent", VALUE).isdigit()
    browser.check()


def readout_stale(browser, name):
    return browser.js("return document.querySelector(`#live-panel .readout[data-live='${arguments[0]}']`).dataset.stale ?? null", name)


def readout_age(browser, name):
    return browser.js("return document.querySelector(`#live-panel .readout[data-live='${arguments[0]}'] .age`).textContent", name)


def test_the_drive_page_readouts_carry_their_age_and_turn_stale(server, browser):
    open_drive(browser, server)
    browser.wait(lambda _: readout_stale(browser, "position") == "no", message="the position never showed fresh")
    assert AGE.fullmatch(readout_age(browser, "position")), readout_age(browser, "position")
    assert browser.js("return document.getElementById('status-panel').dataset.stale") == "no"
    # A stopped node is not read: the values shown are the last ones, and
    # the page says how old they are.
    server.post("/api/v1/buses/demo/nodes/1/nmt", {"command": "stop"})
    try:
        for name in ["position", "velocity", "torque", "mode"]:
            browser.wait(lambda _, n=name: readout_stale(browser, n) == "yes", timeout=20,
                         message=f"{name} stayed fresh with the node stopped")
        assert browser.js("return document.getElementById('status-panel').dataset.stale") == "yes"
        first = int(browser.js("return document.querySelector('#live-panel .readout[data-live=position]').dataset.ageMs"))
        browser.wait(lambda _: int(browser.js(
            "return document.querySelector('#live-panel .readout[data-live=position]').dataset.ageMs")) >= first + 1000,
            timeout=20, message="the age did not grow")
        assert AGE.fullmatch(readout_age(browser, "position")), readout_age(browser, "position")
    finally:
        server.post("/api/v1/buses/demo/nodes/1/nmt", {"command": "start"})
    browser.wait(lambda _: readout_stale(browser, "position") == "no", timeout=20,
                 message="the position did not turn fresh once the node was started")
    browser.check()
