"""The I/O page of a CiA 401 module (/nodes/{bus}/{node}/io) in headless
Chromium against `candeck serve`: the virtual io401 added to the demo bus,
its inputs live on the page (from its TPDOs, changing on their own), a
digital and an analogue output set there and read back."""

import time

from selenium.webdriver.common.by import By

IO = "/api/v1/buses/demo/nodes/4"


def add_io401(server):
    server.post("/api/v1/buses/demo/sim/nodes", {"product": "io401", "id": 4})
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        nodes = {n["id"]: n for n in server.get("/api/v1/buses/demo/nodes")}
        if nodes.get(4, {}).get("profile") == "cia401":
            break
        time.sleep(0.1)
    else:
        raise AssertionError("the io401 was not identified")
    server.post(f"{IO}/nmt", {"command": "start"})


def lit(browser):
    return browser.js(
        "return [...document.querySelectorAll('#digital-inputs .lamp')]"
        ".filter((l) => l.dataset.on === 'true').map((l) => l.id)")


def test_the_inputs_are_live_and_an_output_set_there_reads_back(browser, server):
    add_io401(server)
    browser.driver.get(f"{server.url}/nodes/demo/4")
    browser.wait(lambda _: browser.js("return !!document.getElementById('io-link')"), message="no I/O link")
    # Clicked in the page: the node page redraws the link as the node's
    # events come in, and an element found first may be gone when clicked.
    browser.js("document.getElementById('io-link').click()")
    browser.wait(lambda _: browser.js("return document.getElementById('io-page').dataset.loaded === 'true'"),
                 message="the I/O page did not load")
    assert browser.js("return document.querySelectorAll('#digital-inputs .lamp').length") == 16
    assert browser.js("return document.querySelectorAll('#analog-inputs .analog').length") == 4

    # Live: the running light moves on its own, the inputs come in TPDOs.
    first = lit(browser)
    assert len(first) == 1, first
    browser.wait(lambda _: lit(browser) not in ([], first), message="the inputs did not change")
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-di1').dataset.source") == "tpdo",
                 message="the inputs did not come from TPDOs")

    # A digital output set on the page, confirmed by the read-back. Found
    # and clicked in one step: the page's poll may replace the outputs
    # between a find and a click.
    browser.js("document.querySelector('#ch-do5 button.set').click()")
    browser.wait(lambda _: browser.js("const r = document.getElementById('set-result'); return r && r.dataset.channel === 'do5' && r.dataset.confirmed"),
                 message="no read-back")
    assert browser.js("return document.getElementById('set-result').dataset.confirmed") == "true"
    assert server.get(f"{IO}/od/0x6200/1")["value"] & 0x10
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-do5').dataset.on") == "true",
                 message="do5 is not shown on")

    # An analogue output: ai4 is wired to ao1 on the io401.
    # Focused first, in one step: the page's poll then leaves the outputs
    # alone (it may replace them between a find and a click otherwise).
    browser.js("document.querySelector('#ch-ao1 input').focus()")
    field = browser.driver.find_element(By.CSS_SELECTOR, "#ch-ao1 input")
    field.clear()
    field.send_keys("2000")
    browser.js("document.querySelector('#ch-ao1 button.set').click()")
    browser.wait(lambda _: browser.js("const r = document.getElementById('set-result'); return r && r.dataset.channel === 'ao1'"),
                 message="no read-back of ao1")
    assert browser.js("return document.getElementById('set-result').dataset.confirmed") == "true"
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-ai4 .value').textContent") == "2000",
                 message="ai4 does not read ao1 back")
