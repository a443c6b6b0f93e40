"""Node-IDs from the dashboard: an unconfigured device (LSS) found by the
overview's scan and given a node ID, and a UIO1LED's node ID changed from
its node page (0x2040, save, reset), against `candeck serve` with the demo
devices and one unconfigured UIO1LED on bus `demo` (issue 17)."""

import os

import pytest
from selenium.webdriver.common.by import By

from conftest import Server, free_port

DEVICES = "umc1bds32@1,jmc@2,uio1led@3,uio1led@lss,io401@5"


@pytest.fixture
def server():
    s = Server(free_port(), args=["--bus", f"demo=virtual:{DEVICES}"])
    s.start()
    yield s
    s.stop()
    os.unlink(s.log_file.name)


def result(browser, el):
    return browser.js(f"const r = document.getElementById('{el}'); return [r.dataset.state, r.innerText]")


def change_node_id(browser, new_id):
    """Changes the open node page's node ID to `new_id` (its card, the
    confirmation) and waits until the page says the device booted up."""
    browser.driver.find_element(By.ID, "node-id-new").send_keys(str(new_id))
    browser.driver.find_element(By.ID, "node-id-change").click()
    browser.wait(lambda _: browser.js("return document.getElementById('confirm').open"), message="no confirmation asked")
    browser.driver.find_element(By.ID, "confirm-ok").click()
    browser.wait(lambda _: result(browser, "node-id-result")[0] in ("done", "failed"), timeout=20,
                 message=f"change: {result(browser, 'node-id-result')}")
    state, text = result(browser, "node-id-result")
    assert state == "done" and f"booted up as node {new_id}" in text, text


def test_an_unconfigured_device_is_scanned_and_given_a_node_id(server, browser):
    browser.driver.get(server.url)
    browser.wait(lambda _: browser.js("return document.querySelector('#lss-bus option')?.value") == "demo",
                 message="the LSS panel has no bus")
    browser.driver.find_element(By.ID, "lss-scan").click()
    browser.wait(lambda _: result(browser, "lss-result")[0] == "done", message=f"scan: {result(browser, 'lss-result')}")
    rows = browser.driver.find_elements(By.CSS_SELECTOR, "#lss-found tbody tr[data-serial]")
    assert [r.get_attribute("data-serial") for r in rows] == ["257"]
    assert "0x00004101" in rows[0].text
    rows[0].find_element(By.CSS_SELECTOR, "input").send_keys("10")
    rows[0].find_element(By.CSS_SELECTOR, "button.lss-assign").click()
    browser.wait(lambda _: result(browser, "lss-result")[0] in ("done", "failed")
                 and "booted up" in result(browser, "lss-result")[1] or result(browser, "lss-result")[0] == "failed",
                 timeout=20, message=f"assign: {result(browser, 'lss-result')}")
    state, text = result(browser, "lss-result")
    assert state == "done" and "booted up as node 10" in text, text
    assert 10 in [n["id"] for n in server.get("/api/v1/buses/demo/nodes")]
    # It shows in the node list by itself (the stream's boot-up).
    browser.wait(lambda _: browser.js("return !!document.querySelector('#nodes tr[data-node=\"10\"]')"),
                 message="node 10 is not in the node list")
    browser.check()


def test_a_uniswarm_node_changes_its_node_id_from_its_page(server, browser):
    browser.driver.get(f"{server.url}/nodes/demo/3")
    browser.wait(lambda _: browser.js("return !document.getElementById('node-id-panel').hidden"),
                 message="no node-ID panel on the UIO1LED's page")
    change_node_id(browser, 9)
    assert server.get("/api/v1/buses/demo/nodes/9/od/0x2040/1")["value"] == 9
    # Issue 31 point 6: the old ID's page no longer says "operational /
    # online" (what it last read); it says where the device went.
    def fact(key):
        return browser.js(f"return document.querySelector('#identity dd[data-fact=\"{key}\"]').innerText")
    browser.wait(lambda _: fact("online") == "gone", message=f"the old page still says {fact('online')}")
    assert fact("nmt") == "moved to node ID 9", fact("nmt")
    message = browser.js("const m = document.getElementById('page-message'); return [m.hidden, m.innerText, "
                         "m.querySelector('a')?.getAttribute('href')]")
    assert message[0] is False and "Node 3 moved to node ID 9" in message[1], message
    assert message[2] == "/nodes/demo/9", message
    # The JMC's page says where its node ID comes from (its switches: no
    # object, no LSS) and offers no change.
    browser.driver.get(f"{server.url}/nodes/demo/2")
    browser.wait(lambda _: browser.js("return !document.getElementById('node-id-panel').hidden"),
                 message="the JMC's page has no node-ID panel")
    assert browser.js("return document.getElementById('node-id-form').hidden")
    how = browser.js("return document.getElementById('node-id-how').innerText")
    assert "S1" in how and "S3" in how and "no LSS" in how, how
    browser.check()


def test_a_configured_node_without_0x2040_is_readdressed_by_lss_from_its_page(server, browser):
    # Issue 31 point 6: LSS in the dashboard covered unconfigured devices
    # only, and the CiA 401 I/O module's page had no node-ID card.
    browser.driver.get(f"{server.url}/nodes/demo/5")
    browser.wait(lambda _: browser.js("return document.getElementById('node-id-panel').dataset.way") == "lss",
                 message="no LSS node-ID panel on the I/O module's page")
    assert not browser.js("return document.getElementById('node-id-form').hidden")
    change_node_id(browser, 12)
    ids = [n["id"] for n in server.get("/api/v1/buses/demo/nodes")]
    assert 12 in ids and 5 not in ids, ids
    assert browser.js("return document.getElementById('node-id-new-page').getAttribute('href')") == "/nodes/demo/12"
    browser.check()
