"""Issue 21 point 7, the trace at bus rate in headless Chromium: PDO frames
decoded by the node's current mapping (names and values, read again when
the node is remapped), delta times in the list, the per-COB-ID view (count,
rate, last data, delta time) under the filters, and a bad COB-ID filter
marking only its own field."""

import struct

from selenium.webdriver.common.by import By

from test_trace import open_trace, server  # noqa: F401 (the quiet demo's server fixture)

UMC = "/api/v1/buses/demo/nodes/1"


def entries(browser, where=None):
    """Every frame row the trace holds: {id, dir, service, node, label, detail, data, us, delta}."""
    found = browser.js(
        """return window.candeckTrace.rows().filter((e) => !e.gap).map((e) => ({
             id: e.id, dir: e.dir, service: e.service, node: e.node, label: e.label, detail: e.detail,
             data: e.data, us: e.us, delta: e.deltaUs}));"""
    )
    return [r for r in found if all(r[k] == v for k, v in (where or {}).items())]


def data_bytes(row):
    return bytes.fromhex(row["data"].replace(" ", ""))


def run_umc(server, sync_ms):
    server.post(f"{UMC}/nmt", {"command": "start"})
    server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": sync_ms})


def test_pdo_frames_are_decoded_by_the_nodes_current_mapping(server, browser):
    open_trace(browser, server)
    run_umc(server, 100)
    # TPDO 3 of the UMC: statusword (u16) and position actual value (i32).
    browser.wait(lambda _: any(r["detail"].startswith("a1_Statusword=") for r in entries(browser, {"id": 0x381})),
                 message=f"TPDO 3 not decoded: {entries(browser, {'id': 0x381})[-1:]}")
    for row in [r for r in entries(browser, {"id": 0x381}) if r["detail"].startswith("a1_")]:
        status, position = struct.unpack("<Hi", data_bytes(row))
        assert row["label"] == "TPDO3"
        assert row["detail"] == f"a1_Statusword={status}, a1_pc_Position_actual_value={position}", row
    row = entries(browser, {"id": 0x181})[-1]
    assert row["detail"] == f"a1_Statusword={struct.unpack('<H', data_bytes(row))[0]}", row

    # Remapped: TPDO 1 now carries the position alone; the trace follows.
    server.request("PUT", f"{UMC}/pdos/tpdo/1", {"transmission_type": 1, "mapping": [{"index": "0x6064"}]})
    browser.wait(lambda _: any(r["detail"].startswith("a1_pc_Position_actual_value=") for r in entries(browser, {"id": 0x181})),
                 message=f"TPDO 1 not decoded by its new mapping: {entries(browser, {'id': 0x181})[-1:]}")
    row = [r for r in entries(browser, {"id": 0x181}) if r["detail"].startswith("a1_pc")][-1]
    assert row["detail"] == f"a1_pc_Position_actual_value={struct.unpack('<i', data_bytes(row))[0]}", row
    server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": 0})


def test_delta_times_the_per_cob_id_view_and_its_filters(server, browser):
    open_trace(browser, server)
    run_umc(server, 100)
    browser.wait(lambda _: len(entries(browser, {"id": 0x080})) >= 5 and entries(browser, {"id": 0x181}),
                 message="no SYNC and TPDOs")
    browser.driver.find_element(By.ID, "pause").click()
    server.request("PUT", "/api/v1/buses/demo/sync", {"period_ms": 0})
    held = entries(browser)

    # Delta times: each frame's time since the previous one of its COB-ID.
    by_id = {}
    for row in held:
        by_id.setdefault(row["id"], []).append(row)
    for rows in by_id.values():
        for before, after in zip(rows, rows[1:]):
            assert after["delta"] == after["us"] - before["us"], (before, after)
    drawn = browser.js("""return [...document.querySelectorAll('#trace tbody tr[data-service]')]
                          .map((tr) => [Number(tr.dataset.id), tr.cells[8].textContent]);""")
    assert any(cell.endswith(" ms") for _, cell in drawn), drawn

    # The per-COB-ID view: one row per id, counts as held, rate, last data, delta.
    browser.driver.find_element(By.ID, "view-ids").click()
    assert browser.js("return document.getElementById('trace-scroll').hidden") is True
    table = browser.js("""return [...document.querySelectorAll('#ids tbody tr')].map((tr) => ({
                            id: Number(tr.dataset.id), cells: [...tr.cells].map((c) => c.textContent)}));""")
    assert [r["id"] for r in table] == sorted(by_id), table
    for r in table:
        rows = by_id[r["id"]]
        cob, _node, _service, count, rate, delta, data, detail = r["cells"]
        assert int(count.replace(",", "")) == len(rows), r
        assert data == rows[-1]["data"] and detail == rows[-1]["detail"], r
        if len(rows) > 1:
            expected = (len(rows) - 1) * 1e6 / (rows[-1]["us"] - rows[0]["us"])
            assert rate == f"{expected:.1f}/s", (r, expected)
            assert delta == f"{rows[-1]['delta'] / 1000:.3f} ms" or delta.endswith(" s"), r

    # Filters apply to the view: by node, by COB-ID, by service.
    def shown_ids():
        return browser.js("return [...document.querySelectorAll('#ids tbody tr')].map((tr) => Number(tr.dataset.id))")

    nodes = browser.driver.find_element(By.ID, "filter-nodes")
    nodes.send_keys("1")
    browser.wait(lambda _: shown_ids() and 0x080 not in shown_ids(), message=f"node filter: {shown_ids()}")
    assert all(i & 0x7F == 1 for i in shown_ids())
    nodes.clear()
    browser.driver.find_element(By.CSS_SELECTOR, "#filter-services input[value=pdo]").click()
    # (The SDO frames are the page's own reads of the node's mapping.)
    browser.wait(lambda _: 0x080 in shown_ids() and not any(0x180 <= i < 0x580 for i in shown_ids()),
                 message="the service filter left PDOs in the view")
    browser.driver.find_element(By.CSS_SELECTOR, "#filter-services input[value=pdo]").click()
    ids = browser.driver.find_element(By.ID, "filter-ids")
    ids.send_keys("181")
    browser.wait(lambda _: shown_ids() == [0x181], message=f"COB-ID filter: {shown_ids()}")

    # A bad COB-ID filter marks the COB-ID field only.
    ids.clear()
    ids.send_keys("zz")
    browser.wait(lambda _: browser.js("return document.getElementById('filters').dataset.state") == "invalid",
                 message="the bad filter was not refused")
    borders = browser.js("""return ['filter-ids', 'filter-nodes'].map((id) =>
                              getComputedStyle(document.getElementById(id)).borderTopColor);""")
    assert borders[0] != borders[1], f"both fields look the same: {borders}"
    assert borders[0] == browser.js("""const probe = document.createElement('span');
        probe.style.setProperty('color', 'var(--bad)'); document.body.append(probe);
        const c = getComputedStyle(probe).color; probe.remove(); return c;"""), borders
    assert browser.js("return document.getElementById('filter-nodes').getAttribute('aria-invalid')") is None
    assert "no hex CAN identifier" in browser.js("return document.getElementById('filter-error').textContent")
