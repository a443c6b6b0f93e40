"""The events page in headless Chromium against `candeck serve` on the demo
bus: the audit entry of a write made from the node page, an EMCY arriving
live, the kind filter, "Load older" paging and a phone's width."""

import re

import pytest
from selenium.webdriver.common.by import By

from test_node import open_node, search, value_text, write


@pytest.fixture
def server(server):
    # The machine's change to ready is audited too: once it is in, the
    # newest audit entry is the test's own.
    server.wait_ready()
    return server


def rows(browser):
    """The table's rows, top to bottom: {kind, id, Time, Kind, Where, What, Who, Result}."""
    return browser.js(
        """return [...document.querySelectorAll('#history tbody tr[data-kind]')].map((tr) => {
             const cells = {kind: tr.dataset.kind, id: Number(tr.dataset.id)};
             for (const td of tr.querySelectorAll('td')) cells[td.dataset.label] = td.innerText.trim();
             return cells;
           });"""
    )


def open_events(browser, server, kind=None):
    browser.driver.get(server.url + "/events" + (f"?kind={kind}" if kind else ""))
    browser.wait(lambda _: rows(browser) or "No event" in browser.js("return document.querySelector('#history tbody').innerText"),
                 message="the history did not load")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")


def pick(browser, kind):
    browser.driver.find_element(By.CSS_SELECTOR, f'.kinds button[data-kind="{kind}"]').click()
    browser.wait(lambda _: all(r["kind"] == kind for r in rows(browser)) and rows(browser),
                 message=f"the {kind} filter did not apply")


def test_a_write_from_the_node_page_is_in_the_audit_log(server, browser):
    before = server.get("/api/v1/buses/demo/nodes/1/od/0x2041/1")["value"]
    open_node(browser, server)
    search(browser, "Board_voltage")
    write(browser, "0x2041:1", before - 5)
    browser.wait(lambda _: value_text(browser, "0x2041:1") == str(before - 5), message="the write did not read back")

    browser.driver.find_element(By.CSS_SELECTOR, 'nav a[href="/events"]').click()
    browser.wait(lambda _: rows(browser), message="the history did not load")
    assert browser.js("return document.querySelector('nav a[aria-current=\"page\"]').innerText") == "Events"
    pick(browser, "audit")
    entry = next(e for e in reversed(server.get("/api/v1/events?kind=audit")) if e.get("item") == "0x2041:1")
    top = rows(browser)[0]
    assert (top["kind"], top["id"]) == ("audit", entry["id"]), top
    assert top["Where"] == "demo · node 1"
    assert top["What"].startswith("write object 0x2041:1\nREST · PUT /api/v1/buses/demo/nodes/1/od/0x2041/1"), top
    assert f'{{"value":{before - 5}}}' in top["What"], top
    assert top["Who"] == f"anonymous\nrole none · {entry['peer']}", top
    assert top["Result"] == "200", top
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3}", top["Time"]), top

    # A refused write shows its status, error code and abort code.
    answer = None
    try:
        server.request("PUT", "/api/v1/buses/demo/nodes/1/od/0x1003/0", {"value": 5})
    except AssertionError as err:
        answer = str(err)
    assert answer and "0x06090030" in answer, answer
    browser.wait(lambda _: "0x1003:0" in rows(browser)[0]["What"], timeout=15,
                 message="the refused write did not appear")
    assert rows(browser)[0]["Result"] == "422 sdo_abort\nSDO abort 0x06090030", rows(browser)[0]
    server.request("PUT", "/api/v1/buses/demo/nodes/1/od/0x2041/1", {"value": before})
    browser.check()


def test_an_emcy_appears_live_and_the_filter_keeps_to_its_kind(server, browser):
    open_events(browser, server)
    browser.js("window.notReloaded = true")
    # The rows already shown stay the same elements as newer ones come in
    # (a node's link replaced between touch and release loses the tap).
    browser.js("window.kept = [...document.querySelectorAll('#history tbody tr[data-kind], #history tbody a')]")
    assert browser.js("return window.kept.length") > 0
    server.post("/api/v1/buses/demo/sim/nodes/1/faults", {"kind": "over_temperature"})
    try:
        browser.wait(lambda _: any(r["kind"] == "emcy" for r in rows(browser)), message="no EMCY appeared")
        assert browser.js("return window.kept.filter((el) => !el.isConnected).length") == 0
        emcy = [e for e in server.get("/api/v1/events?kind=emcy") if e["node"] == 1]
        shown = next(r for r in rows(browser) if r["kind"] == "emcy")
        first = next(e for e in emcy if e["id"] == shown["id"])
        assert shown["What"].startswith(f"{first['code']} {first['text']}"), shown
        # Issue 31: a history EMCY row carries the axis the UMC's EMCY names.
        where = "demo · node 1" + (f" · axis {first['axis']}" if first.get("axis") else "")
        assert shown["Where"] == where, (shown, first)
        assert browser.js("return window.notReloaded === true"), "the page was reloaded"
    finally:
        server.request("DELETE", "/api/v1/buses/demo/sim/nodes/1/faults", {"kind": "over_temperature"})

    # Newest first, every entry once.
    listed = rows(browser)
    keys = [(r["kind"], r["id"]) for r in listed]
    assert len(keys) == len(set(keys)), keys
    times = [r["Time"] for r in listed]
    assert times == sorted(times, reverse=True), times

    pick(browser, "emcy")
    assert {r["kind"] for r in rows(browser)} == {"emcy"}
    assert "?kind=emcy" in browser.driver.current_url
    pick(browser, "nmt")
    assert any(r["What"] == "appeared on the bus" for r in rows(browser)), rows(browser)
    browser.check()


def test_load_older_pages_back_through_the_history(server, browser):
    # 130 audited requests: more than a page of 100.
    for period in range(130):
        server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": 0})
    history = server.get("/api/v1/events?kind=audit&limit=1000")
    assert len(history) >= 130
    open_events(browser, server, "audit")
    assert len(rows(browser)) == 100
    # The newest entry when the page loaded: the network manager may have
    # audited one of its own since the history was read.
    latest = server.get("/api/v1/events?kind=audit&limit=1000")
    first_id = rows(browser)[0]["id"]
    assert history[-1]["id"] <= first_id <= latest[-1]["id"], (rows(browser)[0], history[-1])
    history = [e for e in latest if e["id"] <= first_id]
    button = browser.driver.find_element(By.ID, "load-older")
    assert button.is_displayed()
    button.click()
    browser.wait(lambda _: len(rows(browser)) == len(history), message=f"{len(rows(browser))} rows after load older")
    ids = [r["id"] for r in rows(browser)]
    # Newest first by the time each entry was received: an entry the network
    # manager began before a later one but finished after it has the larger id
    # and the earlier time.
    expected = sorted(history, key=lambda e: (e["time_us"], e["id"]), reverse=True)
    assert ids == [e["id"] for e in expected], ids
    assert not browser.js("return !document.getElementById('load-older').hidden"), "load older is still offered"
    browser.check()


def test_phone_width(server, browser):
    browser.phone()
    server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": 0})
    open_events(browser, server)
    layout = browser.js("return {scroll: document.documentElement.scrollWidth, width: window.innerWidth}")
    assert layout["scroll"] <= layout["width"], f"the page scrolls sideways: {layout}"
    browser.check()
