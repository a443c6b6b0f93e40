"""Issue 21's smaller items: a Scan bus button on the overview (it runs
the gateway's node scan, POST /buses/{bus}/scan), the same breadcrumbs on
every page (overview › bus › node › axis or page), and the API docs with
a way back to the dashboard that render at a phone's width."""

import re
import urllib.request

from test_overview import open_overview

CRUMBS = re.compile(r'<nav class="crumbs" aria-label="Breadcrumb">(.*?)</nav>', re.S)
CRUMB = re.compile(r'<(a|span) (?:href="([^"]*)"[^>]*|aria-current="page")>([^<]*)</\1>')


def crumbs(server, path):
    """[(label, href or None for the current page)] of the page at `path`."""
    with urllib.request.urlopen(server.url + path, timeout=30) as resp:
        html = resp.read().decode()
    found = CRUMBS.findall(html)
    assert len(found) == 1, f"{path}: {len(found)} breadcrumb trails"
    return [(label, href or None) for _, href, label in CRUMB.findall(found[0])]


def test_every_page_has_the_same_breadcrumbs(server, browser):
    overview = ("Overview", "/")
    bus = ("Bus demo", "/buses/demo/trace")
    node = ("Node 1", "/nodes/demo/1")
    axis = ("Axis 1", "/nodes/demo/1/axes/1")
    expected = {
        "/nodes/demo/1": [overview, bus, ("Node 1", None)],
        "/nodes/demo/1/axes/1": [overview, bus, node, ("Axis 1", None)],
        "/nodes/demo/1/axes/1/tune": [overview, bus, node, axis, ("Tuning", None)],
        "/nodes/demo/1/axes/1/commissioning/motor": [overview, bus, node, axis, ("Motor", None)],
        "/nodes/demo/1/pdos": [overview, bus, node, ("PDOs", None)],
        "/nodes/demo/1/io": [overview, bus, node, ("I/O", None)],
        "/nodes/demo/3/leds": [overview, bus, ("Node 3", "/nodes/demo/3"), ("LEDs", None)],
        "/buses/demo/trace": [overview, bus, ("Trace", None)],
        "/events": [overview, ("Events", None)],
        "/loggers": [overview, ("Logger", None)],
        "/eds": [overview, ("Device descriptions", None)],
    }
    for path, trail in expected.items():
        assert crumbs(server, path) == trail, path
    # In the browser: the drive page's trail, its links where they say.
    browser.driver.get(server.url + "/nodes/demo/1/axes/1")
    links = browser.wait(lambda _: browser.js(
        "return [...document.querySelectorAll('main > nav.crumbs a')].map((a) => [a.textContent, a.getAttribute('href')])"))
    assert links == [["Overview", "/"], ["Bus demo", "/buses/demo/trace"], ["Node 1", "/nodes/demo/1"]], links
    browser.check()


def test_scan_bus_from_the_overview(server, browser):
    open_overview(browser, server)
    button = browser.driver.find_element("id", "scan-bus")
    assert button.size["height"] >= 44
    button.click()
    browser.wait(lambda _: browser.js("return document.getElementById('scan-result').dataset.state") == "done",
                 timeout=30, message="the scan gave no result")
    text = browser.js("return document.getElementById('scan-result').textContent")
    assert re.fullmatch(r"Scanned \(\d\d:\d\d:\d\d\): demo: 3 nodes\.", text), text
    scans = [e for e in server.get("/api/v1/events?kind=audit&limit=200") if e.get("path") == "/api/v1/buses/demo/scan"]
    assert scans and scans[0]["status"] == 200, scans
    browser.check()


def test_the_api_docs_fit_a_phone_and_lead_back(server, browser):
    browser.phone()
    browser.driver.get(server.url + "/api/docs/")
    browser.wait(lambda _: browser.js("return !!document.querySelector('#swagger-ui .info .title')"), timeout=30,
                 message="the docs UI did not render")
    browser.wait(lambda _: browser.js("return document.querySelectorAll('#swagger-ui .opblock').length") > 10,
                 timeout=30, message="no operations drawn")
    assert browser.js("return window.innerWidth") == 390
    width = browser.js("return document.documentElement.scrollWidth")
    assert width <= 390, f"the docs are {width} px wide on a 390 px phone"
    back = browser.driver.find_element("id", "back-to-dashboard")
    assert back.get_attribute("href") == server.url + "/"
    assert back.size["height"] >= 44, back.size
    back.click()
    browser.wait(lambda _: browser.js("return location.pathname") == "/" and browser.js(
        "return !!document.getElementById('nodes')"), message="the back link did not lead to the dashboard")
    browser.check()
