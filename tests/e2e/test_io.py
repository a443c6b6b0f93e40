"""The I/O page of a CiA 401 module (/nodes/{bus}/{node}/io) in headless
Chromium against `candeck serve`: the virtual io401 added to the demo bus,
its inputs live on the page (from its TPDOs, changing on their own), a
digital and an analogue output set there and read back."""

from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys

IO = "/api/v1/buses/demo/nodes/4"


def add_io401(server):
    server.post("/api/v1/buses/demo/sim/nodes", {"product": "io401", "id": 4})
    server.wait_for("/api/v1/buses/demo/nodes",
                    lambda nodes: any(n["id"] == 4 and n["profile"] == "cia401" for n in nodes),
                    "the io401 was not identified", timeout=15)
    server.post(f"{IO}/nmt", {"command": "start"})


def loaded(browser):
    browser.wait(lambda _: browser.js("return document.getElementById('io-page').dataset.loaded === 'true'"),
                 message="the I/O page did not load")


def lit(browser):
    return browser.js(
        "return [...document.querySelectorAll('#digital-inputs .lamp')]"
        ".filter((l) => l.dataset.on === 'true').map((l) => l.id)")


def test_the_inputs_are_live_and_an_output_set_there_reads_back(browser, server):
    add_io401(server)
    browser.driver.get(f"{server.url}/nodes/demo/4")
    browser.wait(lambda _: browser.js("return !!document.getElementById('io-link')"), message="no I/O link")
    browser.driver.find_element(By.ID, "io-link").click()
    loaded(browser)
    assert browser.js("return document.querySelectorAll('#digital-inputs .lamp').length") == 16
    assert browser.js("return document.querySelectorAll('#analog-inputs .analog').length") == 4

    # Live: the running light moves on its own, the inputs come in TPDOs.
    first = lit(browser)
    assert len(first) == 1, first
    browser.wait(lambda _: lit(browser) not in ([], first), message="the inputs did not change")
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-di1').dataset.source") == "tpdo",
                 message="the inputs did not come from TPDOs")

    # A digital output set on the page, confirmed by the read-back.
    browser.driver.find_element(By.CSS_SELECTOR, "#ch-do5 button.set").click()
    browser.wait(lambda _: browser.js("const r = document.getElementById('set-result'); return r && r.dataset.channel === 'do5' && r.dataset.confirmed"),
                 message="no read-back")
    assert browser.js("return document.getElementById('set-result').dataset.confirmed") == "true"
    assert server.get(f"{IO}/od/0x6200/1")["value"] & 0x10
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-do5').dataset.on") == "true",
                 message="do5 is not shown on")
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-do5 button.set').textContent") == "Switch off",
                 message="do5's switch does not offer to switch it off")

    # An analogue output: ai4 is wired to ao1 on the io401.
    field = browser.driver.find_element(By.CSS_SELECTOR, "#ch-ao1 input")
    field.clear()
    field.send_keys("2000")
    browser.driver.find_element(By.CSS_SELECTOR, "#ch-ao1 button.set").click()
    browser.wait(lambda _: browser.js("const r = document.getElementById('set-result'); return r && r.dataset.channel === 'ao1'"),
                 message="no read-back of ao1")
    assert browser.js("return document.getElementById('set-result').dataset.confirmed") == "true"
    browser.wait(lambda _: browser.js("return document.querySelector('#ch-ai4 .value').textContent") == "2000",
                 message="ai4 does not read ao1 back")


def test_the_page_reads_leave_the_elements_under_a_finger_in_place(browser, server):
    """The page reads every channel twice a second. A button replaced by a
    read between touch and release loses the tap, and a field replaced
    while typed into loses the digits: each read updates the channels in
    place."""
    add_io401(server)
    browser.driver.get(f"{server.url}/nodes/demo/4/io")
    loaded(browser)
    switch = browser.driver.find_element(By.CSS_SELECTOR, "#ch-do2 button.set")
    browser.js("window.kept = [...document.querySelectorAll('#io-page .lamp, #io-page .analog, #io-page button, #io-page input')]")
    # Typed but not set, then left: the digits stay through the reads.
    field = browser.driver.find_element(By.CSS_SELECTOR, "#ch-ao2 input")
    # Focused first, as a finger does: WebDriver's clear() alone leaves the
    # field unfocused, and a read between it and the typing fills it again.
    field.click()
    field.send_keys(Keys.CONTROL, "a")
    field.send_keys("1234")
    browser.js("document.activeElement.blur()")
    # The running light moves only on reads of the page: two moves, two reads at least.
    for _ in range(2):
        before = lit(browser)
        browser.wait(lambda _: lit(browser) not in ([], before), message="the inputs did not change")
    assert browser.js("return window.kept.filter((el) => !el.isConnected).length") == 0
    assert field.get_attribute("value") == "1234"

    switch.click()
    browser.wait(lambda _: browser.js("const r = document.getElementById('set-result'); return r && r.dataset.channel === 'do2' && r.dataset.confirmed"),
                 message="no read-back of do2")
    assert server.get(f"{IO}/od/0x6200/1")["value"] & 0x02
    browser.wait(lambda _: switch.text == "Switch off", message="do2's switch does not offer to switch it off")
    browser.check()


def test_a_stopped_nodes_inputs_are_greyed_out_with_its_nmt_state(browser, server):
    """Issue 31 point 6: the inputs kept "TPDO, 224 ms ago" for 15 s after
    the node was NMT-stopped (and the page asked a stopped node for its
    channels, which answers 409). Now the node's state shows, and each
    channel is greyed out with when it was last read."""
    add_io401(server)
    browser.driver.get(f"{server.url}/nodes/demo/4/io")
    loaded(browser)
    browser.wait(lambda _: browser.js("return document.getElementById('io-node-state').dataset.nmt") == "operational",
                 message="the page does not show the node's NMT state")
    assert browser.js("return [...document.querySelectorAll('#digital-inputs .lamp')].every((l) => l.dataset.stale === 'no')")
    # The page polls: a read of the channels in flight when the stop arrives
    # is not answered by the stopped node (504 after the SDO time-out) or,
    # sent just after, is refused (409 wrong_nmt_state). Either is the
    # gateway telling the truth; any other problem still fails the test.
    browser.tolerate(r"/api/v1/buses/demo/nodes/4/io (- Failed to load resource: the server responded with a status of|answered) (409|504)")
    server.post(f"{IO}/nmt", {"command": "stop"})
    browser.wait(lambda _: browser.js(
        "return [...document.querySelectorAll('#digital-inputs .lamp, #analog-inputs .analog')]"
        ".every((l) => l.dataset.stale === 'yes' && /stopped: last read/.test(l.innerText))"),
        timeout=3, message="the stopped node's inputs were not greyed out: "
        + str(browser.js("return document.getElementById('digital-inputs').innerText")))
    said = browser.js("return document.getElementById('io-node-state').innerText")
    assert "stopped" in said and "online" in said, said
    assert browser.js("return [...document.querySelectorAll('#digital-outputs button')].every((b) => b.disabled)")
    server.post(f"{IO}/nmt", {"command": "start"})
    browser.wait(lambda _: browser.js(
        "return [...document.querySelectorAll('#digital-inputs .lamp')].every((l) => l.dataset.stale === 'no')"),
        message="the inputs stayed grey after the node started again")


def test_the_age_text_stays_inside_its_card_at_1280_px(browser, server):
    """Issue 31 point 6: "TPDO, 224 ms ago" overflowed its lamp at 1280 px."""
    add_io401(server)
    browser.driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                                   {"width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": False})
    browser.driver.get(f"{server.url}/nodes/demo/4/io")
    loaded(browser)
    browser.wait(lambda _: browser.js("return /TPDO/.test(document.getElementById('digital-inputs').innerText)"),
                 message="no TPDO age shown")
    over = browser.js(
        "return [...document.querySelectorAll('.lamp, .analog')].filter((c) => {"
        "  const box = c.getBoundingClientRect();"
        "  return [...c.querySelectorAll('*')].some((e) => e.getBoundingClientRect().right > box.right + 0.5);"
        "}).map((c) => c.id)")
    assert over == [], over
