"""The machine panel of the overview (issue 17, point 8) in headless
Chromium against `candeck serve` on the demo bus: the network manager's view
of every node (state, step, supervision, NMT, reason), kept live by the
`machine` stream topic, and its actions "boot again" and "start"."""

from selenium.webdriver.common.by import By


def machine_rows(browser):
    """{node id: {column: text}} of the machine table."""
    return browser.js(
        """
        const rows = {};
        for (const tr of document.querySelectorAll('#machine tbody tr[data-node]')) {
          const cells = {state: tr.dataset.state};
          for (const td of tr.querySelectorAll('td')) cells[td.dataset.label] = td.innerText.trim();
          rows[tr.dataset.node] = cells;
        }
        return rows;
        """
    )


def click(browser, button):
    """Clicks a button after scrolling it to the middle of the window."""
    browser.js("arguments[0].scrollIntoView({block: 'center'})", button)
    button.click()


def machine_state(browser):
    return browser.js(
        "const b = document.querySelector('#machine-states [data-state]'); return b ? b.dataset.state : null"
    )


def all_ready(browser):
    rows = machine_rows(browser)
    return len(rows) == 3 and all(
        r["state"] == "ready" and r["Supervision"] == "heartbeat" and r["NMT"] == "operational"
        for r in rows.values()
    ) and machine_state(browser) == "ready"


def test_the_overview_shows_the_machine_live_with_its_actions(server, browser):
    browser.driver.get(server.url + "/")
    browser.wait(lambda _: all_ready(browser), message=f"the machine is not ready: {machine_rows(browser)}")
    rows = machine_rows(browser)
    assert rows["1"]["Step"] == "supervised"
    assert rows["3"]["Expected"] == "found"

    # Unplugged: offline, with the reason, without reloading the page.
    server.request("DELETE", "/api/v1/buses/demo/sim/nodes/3")
    browser.wait(
        lambda _: machine_rows(browser).get("3", {}).get("state") == "offline",
        message=f"node 3 not offline: {machine_rows(browser)}",
    )
    assert "no heartbeat" in machine_rows(browser)["3"]["Reason"]
    # Plugged back: booted again by the gateway by itself.
    server.post("/api/v1/buses/demo/sim/nodes", {"product": "uio1led", "id": 3})
    browser.wait(lambda _: all_ready(browser), message=f"node 3 not back: {machine_rows(browser)}")

    # "Boot again" on node 2 runs its boot-up once more.
    row = browser.driver.find_element(By.CSS_SELECTOR, '#machine tbody tr[data-node="2"]')
    click(browser, row.find_element(By.CSS_SELECTOR, 'button[data-action="boot-again"]'))
    browser.wait(
        lambda _: "demo node 2: boot again sent" in browser.driver.find_element(By.ID, "events").text,
        message="the boot was not acknowledged",
    )
    browser.wait(
        lambda _: server.get("/api/v1/buses/demo/machine")["nodes"][1]["boots_ok"] >= 2,
        message="node 2 was not booted again",
    )
    browser.wait(lambda _: all_ready(browser), message=f"not ready after the boot: {machine_rows(browser)}")

    # "Start" sends NMT start to the node.
    server.post("/api/v1/buses/demo/nodes/1/nmt", {"command": "pre_operational"})
    browser.wait(
        lambda _: machine_rows(browser).get("1", {}).get("NMT") == "pre-operational",
        message=f"node 1 not pre-operational: {machine_rows(browser)}",
    )
    row = browser.driver.find_element(By.CSS_SELECTOR, '#machine tbody tr[data-node="1"]')
    click(browser, row.find_element(By.CSS_SELECTOR, 'button[data-action="start"]'))
    browser.wait(lambda _: all_ready(browser), message=f"node 1 not started: {machine_rows(browser)}")


def test_a_change_of_one_node_leaves_the_other_rows_and_the_buttons_in_place(server, browser):
    """The overview redraws its tables at each machine and node event and
    at each poll of the buses: what did not change stays the same element,
    so a link or a button is never replaced between touch and release."""
    browser.driver.get(server.url + "/")
    browser.wait(lambda _: all_ready(browser), message=f"the machine is not ready: {machine_rows(browser)}")
    browser.js("""window.kept = {
        rows: [...document.querySelectorAll('#machine tbody tr[data-node="1"], #machine tbody tr[data-node="3"]')],
        buttons: [...document.querySelectorAll('#machine tbody button')],
        links: [...document.querySelectorAll('#buses a, #nodes tr[data-node="1"] a, #nodes tr[data-node="3"] a, #nodes tr[data-node="2"] td[data-label="Node"] a')],
    };""")
    frames = browser.js("return document.querySelector('#buses tbody tr td[data-label=\"Rx\"]').innerText")
    boot_again = browser.driver.find_element(By.CSS_SELECTOR, '#machine tbody tr[data-node="2"] button[data-action="boot-again"]')

    # Node 2 changes: its row shows it, the rest is what it was.
    server.post("/api/v1/buses/demo/nodes/2/nmt", {"command": "pre_operational"})
    browser.wait(lambda _: machine_rows(browser).get("2", {}).get("NMT") == "pre-operational",
                 message=f"node 2 not pre-operational: {machine_rows(browser)}")
    browser.wait(lambda _: browser.js("return document.querySelector('#buses tbody tr td[data-label=\"Rx\"]').innerText") != frames,
                 message="the bus counters were not read again")
    gone = browser.js("""return Object.entries(window.kept).flatMap(([what, els]) =>
        els.filter((el) => !el.isConnected).map((el) => `${what}: ${el.outerHTML.slice(0, 120)}`));""")
    assert gone == [], gone

    # A button found before the change is the one on the page.
    click(browser, boot_again)
    browser.wait(lambda _: "demo node 2: boot again sent" in browser.driver.find_element(By.ID, "events").text,
                 message="the boot was not acknowledged")
    browser.wait(lambda _: all_ready(browser), message=f"node 2 not booted again: {machine_rows(browser)}")
