"""Issue 21 point 6, bus tools in headless Chromium: the bus's SYNC
started, its period set and stopped from the trace and PDO pages, a raw
frame and an RPDO (by its mapping, typed fields) sent from the trace page
and audited, and the PDO editor saying why a TPDO value has not come yet
(node not operational, then no SYNC running) until SYNC brings one."""

from selenium.webdriver.common.by import By

from test_trace import open_trace, rows


def text(browser, selector):
    return browser.js("const e = document.querySelector(arguments[0]); return e ? e.textContent : null", selector)


def dataset(browser, selector, key):
    return browser.js("const e = document.querySelector(arguments[0]); return e ? e.dataset[arguments[1]] ?? null : null",
                      selector, key)


def fill(browser, element_id, value):
    field = browser.driver.find_element(By.ID, element_id)
    field.clear()
    field.send_keys(value)


def sync_period(server):
    return server.get("/api/v1/buses/demo/sync")["period_ms"]


def start_node(server, node):
    server.post(f"/api/v1/buses/demo/nodes/{node}/nmt", {"command": "start"})
    server.wait_for(f"/api/v1/buses/demo/nodes/{node}", lambda n: n["nmt"] == "operational",
                    f"node {node} did not become operational", timeout=10)


def audited(server, path):
    return [e for e in server.get("/api/v1/events?kind=audit&limit=200") if e.get("path") == path]


def test_sync_raw_frame_and_rpdo_from_the_trace_page(server, browser):
    open_trace(browser, server)
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "off", message="the SYNC state was not read")
    assert browser.js("return document.getElementById('sync-stop').disabled"), "Stop SYNC enabled with SYNC off"

    # SYNC at 100 ms from the page: the gateway sends it, the trace shows it.
    fill(browser, "sync-period", "100")
    browser.driver.find_element(By.ID, "sync-start").click()
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "on", message="SYNC did not start")
    assert sync_period(server) == 100
    assert text(browser, "#sync-state") == "running, every 100 ms"
    browser.wait(lambda _: len(rows(browser, {"service": "sync", "dir": "tx"})) >= 2, message="no SYNC in the trace")
    assert audited(server, "/api/v1/buses/demo/sync"), "SYNC from the page not audited"

    # A raw frame: hex id and bytes with spaces; the trace shows it sent.
    fill(browser, "raw-id", "123")
    fill(browser, "raw-data", "de ad be ef")
    browser.driver.find_element(By.ID, "raw-send").click()
    browser.wait(lambda _: dataset(browser, "#raw-result", "state") == "done", message=text(browser, "#raw-result"))
    browser.wait(lambda _: rows(browser, {"id": 0x123, "dir": "tx"}), message="the raw frame is not in the trace")
    assert rows(browser, {"id": 0x123, "dir": "tx"})[0]["data"].lower() == "de ad be ef"
    assert audited(server, "/api/v1/buses/demo/frames"), "the raw frame not audited"

    # A bad id is said at its field, nothing is sent.
    fill(browser, "raw-id", "xyz")
    browser.driver.find_element(By.ID, "raw-send").click()
    assert browser.js("return document.getElementById('raw-id').getAttribute('aria-invalid')") == "true"
    assert browser.js("return document.getElementById('raw-data').getAttribute('aria-invalid')") is None
    assert "no hex CAN identifier" in text(browser, "#raw-result")

    # An RPDO by its mapping: RPDO 1 of the UMC maps the controlword (u16).
    start_node(server, 1)
    fill(browser, "rpdo-node", "1")
    fill(browser, "rpdo-number", "1")
    browser.driver.find_element(By.ID, "rpdo-load").click()
    browser.wait(lambda _: browser.js("return !!document.getElementById('rpdo-field-0')"), message=text(browser, "#rpdo-result"))
    assert browser.js("return document.getElementById('rpdo-field-0').dataset.key") == "a1_Controlword"
    # Typed: out of the u16 range is refused at its field.
    fill(browser, "rpdo-field-0", "70000")
    browser.driver.find_element(By.ID, "rpdo-send").click()
    assert "outside 0 to 65535" in text(browser, "#rpdo-result")
    assert browser.js("return document.getElementById('rpdo-field-0').getAttribute('aria-invalid')") == "true"
    fill(browser, "rpdo-field-0", "6")
    browser.driver.find_element(By.ID, "rpdo-send").click()
    browser.wait(lambda _: dataset(browser, "#rpdo-result", "state") == "done", message=text(browser, "#rpdo-result"))
    assert text(browser, "#rpdo-result") == "Sent on 201: 0600"
    browser.wait(lambda _: rows(browser, {"id": 0x201, "dir": "tx"}), message="the RPDO is not in the trace")
    assert audited(server, "/api/v1/buses/demo/nodes/1/pdos/rpdo/1/send"), "the RPDO not audited"

    browser.driver.find_element(By.ID, "sync-stop").click()
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "off", message="SYNC did not stop")
    assert sync_period(server) == 0


def test_the_pdo_page_says_why_no_value_and_has_sync_at_hand(server, browser):
    browser.driver.get(server.url + "/nodes/demo/1/pdos")
    browser.wait(lambda _: browser.js("return !!document.querySelector('#tpdo-1 output.live')"), message="no TPDO values")
    # Pre-operational, the UMC sends no TPDO.
    server.post("/api/v1/buses/demo/nodes/1/nmt", {"command": "pre_operational"})
    browser.wait(lambda _: "node not operational" in text(browser, "#tpdo-1 output.live"),
                 message=text(browser, "#tpdo-1 output.live"))
    start_node(server, 1)
    # Operational, but its TPDOs are synchronous and nobody sends SYNC.
    browser.wait(lambda _: "no SYNC running" in text(browser, "#tpdo-1 output.live"),
                 message=text(browser, "#tpdo-1 output.live"))
    # The SYNC control is on the page: started, the values come.
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "off", message="the SYNC state was not read")
    browser.driver.find_element(By.ID, "sync-start").click()
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "on", message="SYNC did not start")
    assert sync_period(server) == 10
    browser.wait(lambda _: browser.js("return !document.querySelector('#tpdo-1 output.live').classList.contains('none')"),
                 message="no TPDO value with SYNC running")
    assert text(browser, "#tpdo-1 output.live").isdigit()
    browser.driver.find_element(By.ID, "sync-stop").click()
    browser.wait(lambda _: dataset(browser, "#sync-state", "state") == "off", message="SYNC did not stop")
    assert sync_period(server) == 0
