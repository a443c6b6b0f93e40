"""The node page in headless Chromium against `candeck serve` on the demo
bus: the UMC's identity and links, an object read and written from the
dictionary browser (checked over REST), SDO aborts and refused values in
words, NMT and store/restore, the DCF backup and restore, an unknown node,
a phone's width and the page's weight."""

import os
import re
import tempfile
import time

from selenium.webdriver.common.by import By

NODE = "/api/v1/buses/demo/nodes/1"


def fact(browser, key):
    return browser.js(
        "const el = document.querySelector(`#identity dd[data-fact=\"${arguments[0]}\"]`);"
        "return el ? el.innerText.trim() : null;",
        key,
    )


def open_node(browser, server, node=1):
    browser.driver.get(f"{server.url}/nodes/demo/{node}")
    browser.wait(lambda _: fact(browser, "nmt") not in (None, "", "…"), message="the identity did not show")
    browser.wait(
        lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
        message="the stream did not connect",
    )
    browser.wait(lambda _: browser.js("return document.querySelectorAll('.od-object').length") > 0,
                 message="the dictionary did not load")


def search(browser, text):
    """Types into the dictionary's search box and waits for the answer."""
    box = browser.driver.find_element(By.ID, "od-search")
    box.clear()
    box.send_keys(text)
    browser.wait(lambda _: f"matching “{text}”" in browser.js("return document.getElementById('od-count').innerText"),
                 message=f"the search for {text} gave no answer")


def row(browser, key):
    return browser.driver.find_element(By.CSS_SELECTOR, f'tr[data-key="{key}"]')


def value_text(browser, key):
    return browser.js(
        "const o = document.querySelector(`tr[data-key=\"${arguments[0]}\"] output.value`);"
        "return o ? o.textContent : null;",
        key,
    )


def cell_text(browser, key):
    return browser.js(
        "return document.querySelector(`tr[data-key=\"${arguments[0]}\"] .od-value`).innerText;", key
    )


def write(browser, key, value):
    r = row(browser, key)
    field = r.find_element(By.CSS_SELECTOR, ".od-write input")
    field.clear()
    field.send_keys(str(value))
    r.find_element(By.CSS_SELECTOR, "button.write").click()


def expected_only(browser, pattern):
    """Takes what the browser logged out of its log and checks that it is
    exactly the expected refusal (a 4xx counts as a failed request)."""
    found = browser.drain()
    assert found, "the expected refused request was not logged"
    unexpected = [p for p in found if not re.search(pattern, p)]
    assert not unexpected, unexpected


def test_the_umc_shows_its_identity_and_links(server, browser):
    open_node(browser, server)
    detail = server.get(NODE)
    ident = detail["identity"]
    assert fact(browser, "name") == detail["name"]
    assert fact(browser, "vendor") == f"0x{ident['vendor_id']:08X}"
    assert fact(browser, "product") == f"0x{ident['product_code']:08X}"
    assert fact(browser, "revision") == f"0x{ident['revision']:08X}"
    assert fact(browser, "serial") == f"0x{ident['serial']:08X}"
    assert fact(browser, "device-type").startswith(f"0x{detail['device_type']:08X} (profile 402")
    assert fact(browser, "profile") == "umc"
    assert fact(browser, "eds") == detail["eds"]
    assert fact(browser, "nmt") == detail["nmt"].replace("_", "-")
    assert fact(browser, "online") == "online"
    assert re.fullmatch(r"just now|\d+ s ago", fact(browser, "last-seen"))
    assert browser.js("return document.getElementById('node-title').innerText") == detail["name"]
    links = browser.js("return [...document.querySelectorAll('#node-links a')].map(a => [a.innerText, a.getAttribute('href')])")
    assert links == [
        ["Drive axis 1", "/nodes/demo/1/axes/1"],
        ["Drive axis 2", "/nodes/demo/1/axes/2"],
        ["PDOs", "/nodes/demo/1/pdos"],
    ], links
    # The node is read again at each of its events; its links stay the same
    # elements (one replaced between touch and release loses the tap).
    browser.js("window.keptLinks = [...document.querySelectorAll('#node-links a')]")
    server.post(f"{NODE}/nmt", {"command": "pre_operational"})
    browser.wait(lambda _: fact(browser, "nmt") == "pre-operational", message="node 1 did not show pre-operational")
    server.post(f"{NODE}/nmt", {"command": "start"})
    browser.wait(lambda _: fact(browser, "nmt") == "operational", message="node 1 did not show operational")
    assert browser.js("return window.keptLinks.every((a) => a.isConnected)")
    # The dictionary grouped by area, the UMC's axes recognised.
    areas = browser.js("return [...document.querySelectorAll('.od-area')].map(s => s.dataset.area)")
    assert areas == [
        "Communication", "Manufacturer · board", "Manufacturer · axis 1", "Manufacturer · axis 2",
        "Device profile · axis 1", "Device profile · axis 2",
    ], areas
    assert browser.js("return document.querySelector('.od-area[data-area=\"Manufacturer · axis 2\"] .od-object').dataset.index") == "0x4200"

    # The LED controller links its LED page and no drive.
    open_node(browser, server, 3)
    links = browser.js("return [...document.querySelectorAll('#node-links a')].map(a => a.getAttribute('href'))")
    assert links == ["/nodes/demo/3/leds", "/nodes/demo/3/pdos"], links
    browser.check()


def test_an_object_is_read_and_written_from_the_dictionary(server, browser):
    key = "0x2041:1"  # Board_voltage_config/Undervoltage, u16, in 0.01 V
    before = server.get(f"{NODE}/od/0x2041/1")["value"]
    new = before - 37
    open_node(browser, server)
    search(browser, "Board_voltage")
    # A narrow search opens what it found.
    row(browser, key).find_element(By.CSS_SELECTOR, "button.read").click()
    browser.wait(lambda _: value_text(browser, key) == str(before), message=f"the read showed {cell_text(browser, key)!r}")
    assert f"raw {before & 0xFF:02x}{before >> 8:02x}" in cell_text(browser, key)
    attrs = browser.js(
        "const i = document.querySelector(`tr[data-key=\"0x2041:1\"] .od-write input`); return [i.type, i.min, i.max, i.value]"
    )
    assert attrs == ["number", "0", "65535", str(before)], attrs

    # Records what the value cell shows while the write runs.
    browser.js(
        """window.seen = [];
        const tr = document.querySelector('tr[data-key="0x2041:1"]');
        new MutationObserver(() => window.seen.push({cell: tr.querySelector('.od-value').innerText,
          button: tr.querySelector('button.write').textContent, disabled: tr.querySelector('button.write').disabled}))
          .observe(tr, {subtree: true, childList: true, characterData: true, attributes: true});"""
    )
    write(browser, key, new)
    browser.wait(lambda _: "Written" in cell_text(browser, key), message=f"no write result: {cell_text(browser, key)!r}")
    seen = browser.js("return window.seen")
    assert any(s["button"] == "Writing…" and s["disabled"] for s in seen), seen
    assert value_text(browser, key) == str(new)
    assert server.get(f"{NODE}/od/0x2041/1")["value"] == new

    # The hex toggle shows integers in hex, of their width.
    browser.driver.find_element(By.ID, "od-hex").click()
    assert value_text(browser, key) == f"0x{new:04X}"
    browser.driver.find_element(By.ID, "od-hex").click()

    # "Read this object" reads every sub in one batch.
    obj = browser.driver.find_element(By.CSS_SELECTOR, '.od-object[data-index="0x2041"]')
    obj.find_element(By.CSS_SELECTOR, "button.read-all").click()
    browser.wait(lambda _: re.match(r"Read (\d+) of \1 ", obj.find_element(By.CSS_SELECTOR, ".od-status").text),
                 message="the object was not read")
    over = server.get(f"{NODE}/od/0x2041/2")["value"]
    assert value_text(browser, "0x2041:2") == str(over)
    assert value_text(browser, key) == str(new)
    server.request("PUT", f"{NODE}/od/0x2041/1", {"value": before})
    browser.check()


def test_refusals_are_shown_in_words(server, browser):
    open_node(browser, server)
    # 0x1003 sub 0 takes only 0 (CiA 301): the device aborts.
    search(browser, "0x1003")
    write(browser, "0x1003:0", 5)
    browser.wait(lambda _: "Write failed" in cell_text(browser, "0x1003:0"), message="no abort shown")
    text = cell_text(browser, "0x1003:0")
    assert "The device refused: 0x06090030 Invalid value for parameter (download only)" in text, text
    expected_only(browser, r"/api/v1/buses/demo/nodes/1/od/0x1003/0\b.*422|status of 422")

    # A value outside the type: refused by the gateway before the bus.
    search(browser, "Producer_heartbeat")
    write(browser, "0x1017:0", 70000)
    browser.wait(lambda _: "Write failed" in cell_text(browser, "0x1017:0"), message="no refusal shown")
    text = cell_text(browser, "0x1017:0")
    assert "70000 is outside the range of UNSIGNED16 (0 to 65535) (value_out_of_range)" in text, text
    expected_only(browser, r"/api/v1/buses/demo/nodes/1/od/0x1017/0\b.*400|status of 400")
    assert server.get(f"{NODE}/od/0x1017/0")["value"] != 70000
    browser.check()


def confirm(browser, ok=True):
    browser.wait(lambda _: browser.js("return document.getElementById('confirm').open"), message="no confirmation asked")
    browser.driver.find_element(By.ID, "confirm-ok" if ok else "confirm-cancel").click()


def nmt_button(browser, command):
    return browser.driver.find_element(By.CSS_SELECTOR, f'#nmt-buttons button[data-command="{command}"]')


def result(browser, el):
    return browser.js(f"const r = document.getElementById('{el}'); return [r.dataset.state, r.innerText]")


def test_nmt_shows_the_state_read_back_and_store_the_device_refusal(server, browser):
    # The JMC sends a heartbeat: the state shown is the one it reports.
    open_node(browser, server, 2)
    nmt_button(browser, "start").click()
    browser.wait(lambda _: fact(browser, "nmt") == "operational", message="node 2 did not show operational")
    browser.wait(lambda _: "NMT state the gateway knows: operational" in result(browser, "nmt-result")[1],
                 message=f"NMT result: {result(browser, 'nmt-result')}")
    assert server.get("/api/v1/buses/demo/nodes/2")["nmt"] == "operational"
    # A destructive command asks first; cancelled, nothing is sent.
    nmt_button(browser, "stop").click()
    confirm(browser, ok=False)
    assert not browser.js("return document.getElementById('confirm').open")
    time.sleep(1.5)  # more than a heartbeat of the JMC
    assert server.get("/api/v1/buses/demo/nodes/2")["nmt"] == "operational"
    nmt_button(browser, "stop").click()
    confirm(browser)
    browser.wait(lambda _: fact(browser, "nmt") == "stopped", message="node 2 did not show stopped")
    nmt_button(browser, "pre_operational").click()
    browser.wait(lambda _: fact(browser, "nmt") == "pre-operational", message="node 2 did not show pre-operational")

    # The UMC sends a heartbeat too since the network manager sets one (it
    # had none before): the page shows the state read back. In operational
    # it refuses to store (UniSwarm: pre-operational only): an abort, in
    # words.
    open_node(browser, server, 1)
    nmt_button(browser, "start").click()
    browser.wait(lambda _: "Start sent" in result(browser, "nmt-result")[1] and result(browser, "nmt-result")[0] == "done",
                 message=f"NMT result: {result(browser, 'nmt-result')}")
    browser.wait(lambda _: "NMT state the gateway knows: operational" in result(browser, "nmt-result")[1],
                 message=f"NMT result: {result(browser, 'nmt-result')}")
    browser.driver.find_element(By.ID, "store").click()
    confirm(browser)
    browser.wait(lambda _: result(browser, "config-result")[0] == "failed", message="the store did not fail")
    state, text = result(browser, "config-result")
    assert re.search(r"Store failed \(\d\d:\d\d:\d\d\): The device refused: 0x08000021 \S", text), text
    expected_only(browser, r"/api/v1/buses/demo/nodes/1/store\b.*422|status of 422")

    nmt_button(browser, "pre_operational").click()
    browser.wait(lambda _: "Pre-operational sent" in result(browser, "nmt-result")[1], message="pre-operational not sent")
    browser.driver.find_element(By.ID, "store").click()
    confirm(browser)
    browser.wait(lambda _: result(browser, "config-result")[0] == "done", message="the store did not succeed")
    assert 'accepted "save" in 0x1010:1 (Save_all_parameters)' in result(browser, "config-result")[1]
    browser.check()


def test_dcf_backup_and_restore(server, browser):
    open_node(browser, server)
    browser.driver.find_element(By.ID, "dcf-download").click()
    browser.wait(lambda _: result(browser, "config-result")[0] == "done", timeout=30, message="no backup")
    text = result(browser, "config-result")[1]
    assert re.search(r"Backup read \(\d\d:\d\d:\d\d\): \d+ parameter values, [\d,]+ bytes, downloaded as node1\.dcf", text), text

    # The backup of a changed device written back: the value comes back.
    import urllib.request
    with urllib.request.urlopen(server.url + f"{NODE}/config.dcf", timeout=30) as resp:
        dcf = resp.read()
    before = server.get(f"{NODE}/od/0x2041/1")["value"]
    server.request("PUT", f"{NODE}/od/0x2041/1", {"value": before - 11})
    with tempfile.NamedTemporaryFile(suffix=".dcf", delete=False) as f:
        f.write(dcf)
    try:
        browser.driver.find_element(By.ID, "dcf-file").send_keys(f.name)
        browser.driver.find_element(By.ID, "dcf-restore").click()
        confirm(browser)
        browser.wait(lambda _: result(browser, "config-result")[0] in ("done", "failed") and "DCF restore" in result(browser, "config-result")[1],
                     timeout=30, message=f"no restore report: {result(browser, 'config-result')}")
    finally:
        os.unlink(f.name)
    state, text = result(browser, "config-result")
    assert state == "done", text
    m = re.search(r"DCF restore \(\d\d:\d\d:\d\d\): (\d+) written, 0 failed\.", text)
    assert m and int(m.group(1)) > 100, text
    assert browser.js("return document.querySelectorAll('.dcf-report tr[data-index=\"0x2041\"][data-sub=\"1\"]').length") == 1
    assert server.get(f"{NODE}/od/0x2041/1")["value"] == before
    browser.check()


def test_an_unknown_node_says_so(server, browser):
    browser.driver.get(f"{server.url}/nodes/demo/99")
    browser.wait(lambda _: browser.js("return !document.getElementById('page-message').hidden"), message="no message")
    message = browser.js("return document.getElementById('page-message').innerText")
    assert message == "node 99 is not known on bus demo (try POST /api/v1/buses/demo/scan) (unknown_node)", message
    assert browser.js("return getComputedStyle(document.getElementById('node-body')).display") == "none"
    assert browser.js("return document.getElementById('node-title').innerText") == "Unknown node"
    expected_only(browser, r"/api/v1/buses/demo/nodes/99\b.*404|status of 404")

    browser.driver.get(f"{server.url}/nodes/nowhere/1")
    browser.wait(lambda _: "no bus is named 'nowhere'" in browser.js("return document.getElementById('page-message').innerText"),
                 message="no message for an unknown bus")
    assert browser.js("return document.getElementById('node-title').innerText") == "Unknown bus"
    expected_only(browser, r"/api/v1/buses/nowhere/nodes/1\b.*404|status of 404")
    browser.check()


def test_phone_width_and_weight(server, browser):
    browser.phone()
    open_node(browser, server)
    search(browser, "0x2041")
    layout = browser.js(
        """return {scroll: document.documentElement.scrollWidth, width: window.innerWidth,
                   thead: getComputedStyle(document.querySelector('.od-subs thead')).display};"""
    )
    assert layout["width"] == 390, layout
    assert layout["scroll"] <= layout["width"], f"the page scrolls sideways: {layout}"
    assert layout["thead"] == "none", "the sub-objects are not cards"
    loaded = [f for f in browser.loaded_files() if not f["url"].endswith(".svg")]
    names = [f["url"].rsplit("/", 1)[-1] for f in loaded]
    for wanted in ["node.css", "node.js", "app.css", "api.js"]:
        assert wanted in names, names
    total = sum(f["bytes"] for f in loaded)
    assert total < 300 * 1024, f"the node page weighs {total} bytes: {loaded}"
    print(f"node page: {total} bytes of HTML, CSS and JS")
    browser.check()


def test_program_download_with_a_progress_bar(server, browser):
    import zlib

    open_node(browser, server)
    image = b"CDKI\x031.9" + bytes((i * 7 + 1) & 0xFF for i in range(40000))
    with tempfile.NamedTemporaryFile(suffix=".bin", delete=False) as f:
        f.write(image)
    try:
        browser.driver.find_element(By.ID, "program-file").send_keys(f.name)
        # Every value the stream gives the bar, in order.
        browser.js("""
            window.programStream = [];
            new MutationObserver(() => {
              const bar = document.getElementById('program-progress');
              if (bar.dataset.stream) window.programStream.push(Number(bar.dataset.stream));
            }).observe(document.getElementById('program-progress'),
                       {attributes: true, attributeFilter: ['data-stream']});""")
        browser.driver.find_element(By.ID, "program-download").click()
        confirm(browser)
        browser.wait(lambda _: result(browser, "program-result")[0] in ("done", "failed"),
                     timeout=60, message=f"no program report: {result(browser, 'program-result')}")
    finally:
        os.unlink(f.name)
    state, text = result(browser, "program-result")
    assert state == "done", text
    crc = f"0x{zlib.crc32(image):08X}"
    assert f"0x1F56 = {crc} verified" in text and "the program was started" in text, text
    assert browser.js("return document.getElementById('program-progress').value") == 100
    # The bar moved from the stream's `.../program` topic through the
    # device's download, up to 100 %.
    browser.wait(lambda _: browser.js("return window.programStream.at(-1)") == 100,
                 timeout=10, message="the stream's progress did not reach 100 %")
    steps = browser.js("return window.programStream")
    assert any(0 < p < 100 for p in steps), steps
    assert steps == sorted(steps), steps
    assert server.get(f"{NODE}/od/0x1F56/1")["value"] == zlib.crc32(image)
    assert server.get(f"{NODE}/od/0x100A/0")["value"] == "1.9"
    # Issue 31 point 6: the new software version is shown after the download.
    browser.wait(lambda _: browser.js("const v = document.getElementById('program-version'); return v && v.innerText")
                 == "Software version (0x100A): 1.9.", message="the new software version is not shown")
    browser.check()


def test_last_seen_is_not_marked_stale_while_the_gateway_hears_the_node(browser, server):
    """Issue 31 point 6: "Last seen" was marked stale at 1-2 s while the
    API said 6-86 ms: the page added the time since its own read (every
    2 s) to the gateway's age, and a 500 ms heartbeat is stale after 750 ms."""
    open_node(browser, server)
    heartbeat = server.get("/api/v1/buses/demo/nodes/1")["heartbeat_ms"]
    assert heartbeat and heartbeat < 1000, heartbeat
    marks = []
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        marks.append(browser.js("const el = document.getElementById('last-seen');"
                                "return [el.classList.contains('stale'), Number(el.dataset.ageMs || 0)]"))
        time.sleep(0.25)
    stale = [age for is_stale, age in marks if is_stale]
    assert not stale, f"marked stale at {stale} ms with a {heartbeat} ms heartbeat"


def test_assigning_an_eds_of_another_product_warns_and_asks(browser, server):
    """Issue 31 point 6: assigning an EDS whose identity is not the
    device's (a product 0xA16 file on a 0x401 device) said nothing."""
    node = server.get("/api/v1/buses/demo/nodes/2")
    files = server.get("/api/v1/eds")["files"]
    other = next(f for f in files if f["usable"] and f["product_code"] not in (None, node["identity"]["product_code"]))
    open_node(browser, server, node=2)
    browser.wait(lambda _: browser.js(f"return [...document.querySelectorAll('#eds-file option')].some((o) => o.value === '{other['name']}')"),
                 message="the EDS files did not load")
    browser.js("const s = document.getElementById('eds-file'); s.value = arguments[0];"
               "s.dispatchEvent(new Event('change'))", other["name"])
    warning = browser.wait(lambda _: browser.js(
        "const w = document.getElementById('eds-warning'); return !w.hidden && w.innerText"),
        message="no warning for an EDS of another product")
    assert "another device" in warning and f"{other['product_code']:08X}" in warning, warning
    browser.driver.find_element(By.ID, "eds-assign").click()
    browser.wait(lambda _: browser.js("return document.getElementById('confirm').open"), message="no question asked")
    assert "Assign it to node 2 anyway" in browser.js("return document.getElementById('confirm-text').innerText")
    browser.driver.find_element(By.ID, "confirm-cancel").click()
    assert server.get("/api/v1/buses/demo/nodes/2")["eds"] == node["eds"]


def test_program_download_is_not_offered_to_a_node_without_0x1f50(browser, server):
    """Issue 31 point 6: the download was offered to a node without the
    program download object and failed only after the confirmation."""
    without = [n["id"] for n in server.get("/api/v1/buses/demo/nodes")
               if not any(o["index"].upper() == "0X1F50" for o in server.get(f"/api/v1/buses/demo/nodes/{n['id']}/od?q=0x1F50"))]
    assert without, "every demo node has 0x1F50"
    open_node(browser, server, node=without[0])
    browser.wait(lambda _: browser.js("return document.getElementById('program-panel').dataset.supported") == "false",
                 message="the page did not find that the node takes no program")
    assert browser.js("return document.getElementById('program-file').disabled")
    assert browser.js("return document.getElementById('program-download').disabled")
    assert "0x1F50" in browser.js("return document.getElementById('program-result').innerText")
    open_node(browser, server, node=1)
    browser.wait(lambda _: browser.js("return document.getElementById('program-panel').dataset.supported") == "true",
                 message="the UMC's program download is not offered")
    assert not browser.js("return document.getElementById('program-file').disabled")
