"""The PDO editor (/nodes/{bus}/{node}/pdos) in headless Chromium against
`candeck serve` on the demo bus: a TPDO mapping edited and applied, an
edit over 64 bits refused in the page, an edit the API refuses shown with
its message, the JMC's page, a phone-width layout and reconnecting after
the gateway restarts."""

import os
import re
import time

from conftest import SHOTS
from selenium.webdriver.common.by import By

UMC = "/api/v1/buses/demo/nodes/1"
OUTAGE_ERRORS = re.compile(
    r"WebSocket connection to 'ws://127\.0\.0\.1:\d+/api/v1/stream' failed"
    r"|/api/v1/\S* failed: net::ERR_(CONNECTION_REFUSED|CONNECTION_RESET|EMPTY_RESPONSE|CONNECTION_CLOSED)"
    r"|127\.0\.0\.1:\d+/api/v1/\S* - Failed to load resource: net::ERR_(CONNECTION_REFUSED|CONNECTION_RESET|EMPTY_RESPONSE)"
)


NOT_FOUND_YET = re.compile(rf"{UMC}(/od|/pdos)?( answered 404$| - Failed to load resource: the server responded with a status of 404)")


def open_pdos(browser, server, node=1):
    browser.driver.get(f"{server.url}/nodes/demo/{node}/pdos")
    browser.wait(lambda _: browser.js("return document.getElementById('pdo-page').dataset.loaded === 'true'"),
                 message="the PDOs were not shown")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")


def card(browser, kind, n):
    return browser.driver.find_element(By.ID, f"{kind}-{n}")


def shown_mapping(browser, kind, n):
    """The entries a card lists, as "0x6041:0"."""
    return browser.js(
        "return [...document.querySelectorAll(arguments[0])].map((li) => `${li.dataset.index}:${li.dataset.sub}`)",
        f"#{kind}-{n} .entry",
    )


def rest_mapping(pdo):
    return [f"{e['index']}:{e['sub']}" for e in pdo["mapping"]]


def device_pdo(server, kind, n, node=1):
    return next(p for p in server.get(f"/api/v1/buses/demo/nodes/{node}/pdos")[kind] if p["number"] == n)


def text(browser, selector):
    return browser.js("const el = document.querySelector(arguments[0]); return el ? el.innerText.trim() : null", selector)


def add_object(browser, kind, n, query, index, sub):
    """Types `query` into the card's search and picks index:sub."""
    search = card(browser, kind, n).find_element(By.CSS_SELECTOR, "input.search")
    search.clear()
    search.send_keys(query)
    match = browser.wait(
        lambda _: card(browser, kind, n).find_elements(
            By.CSS_SELECTOR, f'.matches button[data-index="{index}"][data-sub="{sub}"]'),
        message=f"{index}:{sub} not offered for {query!r}",
    )[0]
    match.click()


def mappable(server, kind, node=1):
    """The objects the node's dictionary lets map into a PDO of `kind`,
    with their lengths, as the page finds them."""
    widths = {"bool": 1}
    found = []
    for obj in server.get(f"/api/v1/buses/demo/nodes/{node}/od"):
        for sub in obj["subs"]:
            m = re.fullmatch(r"[iur](\d+)", sub["data_type"])
            bits = int(m.group(1)) if m else widths.get(sub["data_type"])
            if not sub["pdo_mappable"] or bits is None:
                continue
            if kind == "tpdo" and sub["access"] == "wo" or kind == "rpdo" and sub["access"] in ("ro", "const"):
                continue
            name = f"{obj['name']}/{sub['name']}" if obj["object_type"].lower() in ("array", "record") else obj["name"]
            found.append({"index": obj["index"], "sub": sub["sub"], "bits": bits, "name": name})
    return found


def test_a_tpdo_mapping_edited_and_applied_is_read_back(server, browser):
    before = device_pdo(server, "tpdo", 1)
    open_pdos(browser, server)
    assert shown_mapping(browser, "tpdo", 1) == rest_mapping(before)
    assert browser.js("return document.title") == "PDOs of node 1 on demo · candeck"
    assert browser.js("return document.getElementById('node-link').getAttribute('href')") == "/nodes/demo/1"
    tpdo = card(browser, "tpdo", 1)
    assert not tpdo.find_element(By.CSS_SELECTOR, ".dirty").is_displayed()

    # Add three readable objects that fit in the 64 bits, remove the last,
    # and move the second one up.
    used = sum(e["bits"] for e in before["mapping"])
    picks = []
    for obj in mappable(server, "tpdo"):
        key = f"{obj['index']}:{obj['sub']}"
        if len(picks) < 3 and key not in rest_mapping(before) and used + obj["bits"] <= 64 and obj["bits"] >= 8:
            picks.append(obj)
            used += obj["bits"]
    assert len(picks) == 3, picks
    for obj in picks:
        add_object(browser, "tpdo", 1, obj["name"], obj["index"], obj["sub"])
    keys = rest_mapping(before) + [f"{o['index']}:{o['sub']}" for o in picks]
    assert shown_mapping(browser, "tpdo", 1) == keys
    tpdo.find_elements(By.CSS_SELECTOR, ".entry button.remove")[-1].click()
    tpdo.find_elements(By.CSS_SELECTOR, ".entry button.up")[-1].click()
    expected = keys[:-3] + [keys[-2], keys[-3]]
    used -= picks[-1]["bits"]
    assert shown_mapping(browser, "tpdo", 1) == expected
    assert tpdo.find_element(By.CSS_SELECTOR, ".dirty").is_displayed(), "no unsaved marker while editing"
    bar = browser.js("return document.querySelector('#tpdo-1 .bar').getAttribute('aria-label')")
    assert bar == f"{used} of 64 bits mapped", bar

    # Apply: the button says it is busy while the procedure runs, then the
    # card shows what the device reports.
    browser.js(
        """
        window.seen = [];
        const card = document.getElementById('tpdo-1');
        const button = card.querySelector('button.apply');
        const result = card.querySelector('.pdo-result');
        new MutationObserver(() => window.seen.push({busy: button.getAttribute('aria-busy'),
          disabled: button.disabled, label: button.textContent, state: result.dataset.state}))
          .observe(card, {subtree: true, childList: true, attributes: true, characterData: true});
        """
    )
    tpdo.find_element(By.CSS_SELECTOR, "button.apply").click()
    browser.wait(lambda _: browser.js("return document.querySelector('#tpdo-1 .pdo-result').dataset.state") in ("done", "failed"),
                 message="applying gave no result")
    assert browser.js("return document.querySelector('#tpdo-1 .pdo-result').dataset.state") == "done", \
        text(browser, "#tpdo-1 .pdo-error")
    seen = browser.js("return window.seen")
    assert any(s["busy"] == "true" and s["disabled"] and s["label"] == "Applying…" and s["state"] == "busy" for s in seen), seen
    assert re.match(r"Applied at \d\d:\d\d:\d\d: shown as the device reports it now\.$", text(browser, "#tpdo-1 .pdo-result"))

    after = device_pdo(server, "tpdo", 1)
    assert rest_mapping(after) == expected, after
    assert shown_mapping(browser, "tpdo", 1) == expected
    assert not tpdo.find_element(By.CSS_SELECTOR, ".dirty").is_displayed(), "still marked unsaved after applying"
    names = browser.js("return [...document.querySelectorAll('#tpdo-1 .bar .block:not(.free) .block-name')].map((b) => b.textContent)")
    assert names == [e["name"] or f"{e['index']}:{e['sub']}" for e in after["mapping"]], names
    browser.check()


def test_more_than_64_bits_is_refused_in_the_page_without_a_request(server, browser):
    open_pdos(browser, server)
    before = device_pdo(server, "tpdo", 2)
    used = sum(e["bits"] for e in before["mapping"])
    wide = [o for o in mappable(server, "tpdo") if o["bits"] == 32]
    added = 0
    for obj in wide:
        if used > 64:
            break
        add_object(browser, "tpdo", 2, obj["name"], obj["index"], obj["sub"])
        used += obj["bits"]
        added += 1
    assert used > 64, "not enough 32-bit objects to go over 64 bits"
    error = text(browser, "#tpdo-2 .pdo-error")
    assert error == f"The mapping is {used} bits: a PDO carries at most 64. Remove {used - 64} bits.", error
    assert browser.js("return document.querySelector('#tpdo-2 .bar').classList.contains('over')")
    assert text(browser, "#tpdo-2 .bar-scale span:last-child") == f"{used} of 64 bits"

    card(browser, "tpdo", 2).find_element(By.CSS_SELECTOR, "button.apply").click()
    assert text(browser, "#tpdo-2 .pdo-result") == "Not sent: correct what is shown above first."
    os.makedirs(SHOTS, exist_ok=True)
    browser.js("document.getElementById('tpdo-2').scrollIntoView()")
    browser.driver.save_screenshot(os.path.join(SHOTS, "pdos-over-64-bits.png"))
    time.sleep(0.3)  # time for a request, had one been made
    sent = browser.js(
        "return performance.getEntriesByType('resource').map((r) => r.name).filter((n) => n.includes('/pdos/'))"
    )
    assert sent == [], sent
    assert device_pdo(server, "tpdo", 2)["mapping"] == before["mapping"]

    # Drag and drop: the last entry dropped on the first goes first (the
    # events a mouse drag fires, dispatched as Chromium would).
    order = shown_mapping(browser, "tpdo", 2)
    browser.js(
        """
        const rows = document.querySelectorAll('#tpdo-2 .entry');
        const from = rows[rows.length - 1], to = rows[0];
        const dataTransfer = new DataTransfer();
        const fire = (el, type) => el.dispatchEvent(new DragEvent(type, {bubbles: true, cancelable: true, dataTransfer}));
        fire(from, 'dragstart'); fire(to, 'dragover'); fire(to, 'drop'); fire(from, 'dragend');
        """
    )
    assert shown_mapping(browser, "tpdo", 2) == [order[-1]] + order[:-1]

    # Revert: back to the device's mapping, no longer marked unsaved.
    card(browser, "tpdo", 2).find_element(By.CSS_SELECTOR, "button.revert").click()
    assert shown_mapping(browser, "tpdo", 2) == rest_mapping(before)
    assert not card(browser, "tpdo", 2).find_element(By.CSS_SELECTOR, ".dirty").is_displayed()
    assert not card(browser, "tpdo", 2).find_element(By.CSS_SELECTOR, ".pdo-error").is_displayed()
    browser.check()


def test_an_edit_the_api_refuses_shows_its_message(server, browser):
    open_pdos(browser, server)
    browser.check()
    before = device_pdo(server, "tpdo", 1)
    cob = card(browser, "tpdo", 1).find_element(By.CSS_SELECTOR, "input[name=cob_id]")
    cob.clear()
    cob.send_keys("0x701")  # node 1's heartbeat: CiA 301 reserves it
    card(browser, "tpdo", 1).find_element(By.CSS_SELECTOR, "button.apply").click()
    browser.wait(lambda _: browser.js("return document.querySelector('#tpdo-1 .pdo-result').dataset.state") == "failed",
                 message="the refusal was not shown")
    # What the API says to the same request, in the page's words.
    body = {"cob_id": 0x701, "enabled": before["enabled"],
            "mapping": [{"index": e["index"], "sub": e["sub"], "bits": e["bits"]} for e in before["mapping"]]}
    try:
        server.request("PUT", f"{UMC}/pdos/tpdo/1", body)
        raise AssertionError("the API took COB-ID 0x701")
    except AssertionError as err:
        answer = str(err)
    assert ": 400 " in answer, answer
    message = re.search(r'"message":"([^"]+)"', answer).group(1)
    assert "0x701" in message, message
    error = text(browser, "#tpdo-1 .pdo-error")
    assert error == f"Refused: {message} (invalid_mapping)", error
    assert re.match(r"Not applied \(\d\d:\d\d:\d\d\)\.$", text(browser, "#tpdo-1 .pdo-result"))
    assert card(browser, "tpdo", 1).find_element(By.CSS_SELECTOR, ".dirty").is_displayed()
    assert device_pdo(server, "tpdo", 1)["cob_id"] == before["cob_id"]

    # The refused request is the one failure the browser logged.
    logged = browser.drain()
    put = re.escape(f"{server.url}{UMC}/pdos/tpdo/1")
    expected = [re.compile(rf"request: {put} answered 400$"),
                re.compile(rf"console: {put} - Failed to load resource: the server responded with a status of 400")]
    assert len(logged) == len(expected) and all(any(p.match(line) for line in logged) for p in expected), logged
    browser.check()


def test_the_jmc_page_loads(server, browser):
    pdos = server.get("/api/v1/buses/demo/nodes/2/pdos")
    open_pdos(browser, server, node=2)
    for kind in ("tpdo", "rpdo"):
        shown = browser.js("return [...document.querySelectorAll(arguments[0])].map((c) => Number(c.dataset.number))",
                           f"#{kind}s article.pdo")
        assert shown == [p["number"] for p in pdos[kind]], (kind, shown)
        for pdo in pdos[kind]:
            assert shown_mapping(browser, kind, pdo["number"]) == rest_mapping(pdo)
            state = text(browser, f"#{kind}-{pdo['number']} .pdo-state")
            assert state == f"{'enabled' if pdo['enabled'] else 'disabled'} · COB-ID 0x{pdo['cob_id']:03X}", state
    name = server.get("/api/v1/buses/demo/nodes/2")["name"]
    assert text(browser, "#node-name") == f"{name} · node 2 on demo"
    browser.check()


def test_phone_width(server, browser):
    browser.phone()
    open_pdos(browser, server)
    layout = browser.js(
        """
        const b = document.querySelector('#tpdo-1 button.apply').getBoundingClientRect();
        const up = document.querySelector('#tpdo-1 .entry button.up').getBoundingClientRect();
        return {scroll: document.documentElement.scrollWidth, width: window.innerWidth,
                right: b.right, target: Math.min(up.width, up.height)};
        """
    )
    assert layout["width"] == 390, layout
    assert layout["scroll"] <= layout["width"], f"the page scrolls sideways: {layout}"
    assert layout["right"] <= layout["width"], layout
    assert layout["target"] >= 36, f"the reorder buttons are too small to touch: {layout}"
    browser.check()


def test_the_page_reads_the_pdos_again_after_the_gateway_restarts(server, browser):
    open_pdos(browser, server)
    browser.check()
    loads = int(browser.js("return document.getElementById('pdo-page').dataset.loads"))
    server.kill()
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "disconnected",
                 message="the page did not show the outage")
    time.sleep(1.0)
    server.start()
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 timeout=20, message="the page did not reconnect")
    browser.wait(lambda _: int(browser.js("return document.getElementById('pdo-page').dataset.loads")) > loads,
                 timeout=20, message="the page did not read the PDOs again")
    assert shown_mapping(browser, "tpdo", 1) == rest_mapping(device_pdo(server, "tpdo", 1))
    outage = browser.drain()
    # Until the new gateway has found node 1 again, it does not know it.
    unexpected = [p for p in outage if not OUTAGE_ERRORS.search(p) and not NOT_FOUND_YET.search(p)]
    assert not unexpected, unexpected
    assert not browser.js("return document.getElementById('page-message').hidden === false"
                          " && document.getElementById('page-message').innerText"), "a problem is still shown"
    browser.check()


def test_live_tpdo_values_show_next_to_their_objects(server, browser):
    open_pdos(browser, server)
    assert browser.js("return document.querySelector('#tpdo-1 output.live').textContent").startswith("no value yet")
    # An operational node sends its synchronous TPDOs at each SYNC.
    server.post(f"{UMC}/nmt", {"command": "start"})
    server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": 20})

    def shown(_):
        values = {v["name"]: v["value"] for v in server.get(f"{UMC}/values")["values"]}
        page = browser.js("return document.querySelector('#tpdo-1 output.live[data-key=\"a1_Statusword\"]').textContent")
        return page if "a1_Statusword" in values and page == str(values["a1_Statusword"]) else None

    browser.wait(shown, message="the statusword the node sends did not show next to TPDO 1's entry")

    # TPDO 3's frame may come in a later message of the values topic than
    # TPDO 1's (the suite's load splits them): wait for it too.
    def position(_):
        text = browser.js("return document.querySelector('#tpdo-3 output.live[data-key=\"a1_pc_Position_actual_value\"]').textContent")
        return text if re.fullmatch(r"-?\d+", text) else None

    browser.wait(position, message="the position the node sends did not show next to TPDO 3's entry")
    server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": 0})
    browser.check()


def test_page_weight(server, browser):
    open_pdos(browser, server)
    files = browser.loaded_files()
    names = [f["url"].rsplit("/", 1)[-1] for f in files]
    for wanted in ["app.css", "pdos.css", "pdos.js", "layout.js", "stream.js", "api.js", "dom.js"]:
        assert wanted in names, f"{wanted} not among what the page loaded: {names}"
    assert all(f["bytes"] > 0 for f in files), files
    total = sum(f["bytes"] for f in files if not f["url"].endswith(".svg"))
    assert total < 300 * 1024, f"the PDO editor weighs {total} bytes: {files}"
    print(f"PDO editor: {total} bytes of HTML, CSS and JS before API data")
    browser.check()
