"""The LED controller page in headless Chromium against `candeck serve` on
the demo bus (node 3, the virtual UIO1LED): the segment editor writes what
was changed, shows what the device read back, and the live strip follows
the device."""

import re
import time

from selenium.webdriver.support.ui import Select

# The errors Chromium logs while the gateway is down, and only those (as
# test_overview.py accepts them).
OUTAGE_ERRORS = re.compile(
    r"WebSocket connection to 'ws://127\.0\.0\.1:\d+/api/v1/stream' failed"
    r"|/api/v1/\S* failed: net::ERR_(CONNECTION_REFUSED|CONNECTION_RESET|EMPTY_RESPONSE|CONNECTION_CLOSED)"
    r"|127\.0\.0\.1:\d+/api/v1/\S* - Failed to load resource: net::ERR_(CONNECTION_REFUSED|CONNECTION_RESET|EMPTY_RESPONSE)"
)

PAGE = "/nodes/demo/3/leds"
SEGMENTS = "/api/v1/buses/demo/nodes/3/segments"


def open_leds(browser, server):
    browser.driver.get(server.url + PAGE)
    browser.wait(lambda _: browser.js("return document.querySelectorAll('#segments details.segment').length") == 10,
                 message="the ten segment editors did not appear")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")
    browser.wait(lambda _: browser.js("return window.candeckLeds.lastPreview() !== null"),
                 message="no preview came from the stream")


def editor(browser, n):
    return browser.driver.find_element("css selector", f'details.segment[data-segment="{n}"]')


def set_input(browser, element, value):
    """Sets an input as a person would (an `input` event), also for the
    colour picker and sliders selenium cannot type into."""
    browser.js(
        "arguments[0].value = arguments[1]; arguments[0].dispatchEvent(new Event('input', {bubbles: true}));",
        element, value,
    )


def canvas_pixel(browser, n, led=0):
    """The colour segment n's canvas shows at the middle of LED `led`, and
    how many LEDs it draws."""
    return browser.js(
        """
        const canvas = document.querySelector(`details.segment[data-segment="${arguments[0]}"] canvas`);
        const leds = Number(canvas.dataset.leds || 0);
        if (!leds) return {leds, rgb: null};
        const x = Math.floor((arguments[1] + 0.5) * canvas.width / leds);
        const [r, g, b] = canvas.getContext('2d').getImageData(x, Math.floor(canvas.height / 2), 1, 1).data;
        return {leds, rgb: [r, g, b]};
        """,
        n, led,
    )


def watch_apply(browser, n):
    browser.js(
        """
        window.seen = [];
        const card = document.querySelector(`details.segment[data-segment="${arguments[0]}"]`);
        const button = card.querySelector('button[type=submit]');
        const result = card.querySelector('.action-result');
        new MutationObserver(() => window.seen.push({
          busy: button.getAttribute('aria-busy'), disabled: button.disabled, label: button.textContent,
          result: result.textContent, state: result.dataset.state,
        })).observe(card, {subtree: true, childList: true, attributes: true, characterData: true});
        """,
        n,
    )


def test_a_segment_change_is_read_back_and_the_preview_follows(server, browser):
    open_leds(browser, server)
    before = server.get(SEGMENTS)[0]
    assert before["led_count"] == 0 and before["effect"] == "off", before

    card = editor(browser, 1)
    form = card.find_element("css selector", "form")
    count = form.find_element("name", "led_count")
    count.clear()
    count.send_keys("12")
    Select(form.find_element("name", "effect")).select_by_value("fix")
    set_input(browser, form.find_element("name", "color1"), "#12ab34")
    assert browser.js("return arguments[0].dataset.dirty", form) == "true"
    # Nothing is written before Apply: the device still has the old values.
    assert server.get(SEGMENTS)[0]["effect"] == "off"

    watch_apply(browser, 1)
    form.find_element("css selector", "button[type=submit]").click()
    result = card.find_element("css selector", ".action-result")
    browser.wait(lambda _: result.get_attribute("data-state") == "done", message=f"Apply gave no result: {result.text}")
    seen = browser.js("return window.seen")
    assert any(s["busy"] == "true" and s["disabled"] and s["label"] == "Applying…" and s["state"] == "busy"
               and s["result"].startswith("Writing ") for s in seen), seen
    assert result.text.startswith("Applied LEDs, effect, colour 1 ("), result.text

    # The device has it (read over REST), and the editor shows what was read.
    after = server.get(SEGMENTS)[0]
    assert after["led_count"] == 12 and after["effect"] == "fix", after
    assert after["colors"][0] == {"r": 0x12, "g": 0xAB, "b": 0x34, "w": 0}, after
    # Only what was changed was written: colour 2 and 3, dimmer and the rest stay.
    for key in ("dimmer", "speed", "smooth", "min_value", "max_value"):
        assert after[key] == before[key], (key, before, after)
    assert after["colors"][1:] == before["colors"][1:]
    assert browser.js("return arguments[0].dataset.dirty", form) == "false"
    assert form.find_element("name", "color1").get_attribute("value") == "#12ab34"
    assert card.get_attribute("data-effect") == "fix"
    assert card.find_element("css selector", ".summary-text").text == "12 LEDs · Fixed"

    # The live strip follows: twelve LEDs of the new colour on segment 1's
    # canvas, as the gateway's preview has them.
    browser.wait(lambda _: canvas_pixel(browser, 1) == {"leds": 12, "rgb": [0x12, 0xAB, 0x34]},
                 message=f"the preview did not follow: {canvas_pixel(browser, 1)}")
    assert canvas_pixel(browser, 1, 11)["rgb"] == [0x12, 0xAB, 0x34]
    preview = server.get(SEGMENTS + "/preview")
    assert preview["pixels"][0] == {"r": 0x12, "g": 0xAB, "b": 0x34, "w": 0}, preview
    last = browser.js("return window.candeckLeds.lastPreview()")
    assert last["segments"][0]["led_count"] == 12 and last["pixels"][0] == preview["pixels"][0]
    browser.check()


def test_a_flowing_effect_moves_in_the_preview(server, browser):
    open_leds(browser, server)
    form = editor(browser, 1).find_element("css selector", "form")
    count = form.find_element("name", "led_count")
    count.clear()
    count.send_keys("20")
    Select(form.find_element("name", "effect")).select_by_value("flow")
    set_input(browser, form.find_element("name", "color1"), "#ff0000")
    set_input(browser, form.find_element("name", "color2"), "#0000ff")
    for name, value in (("max_value", "999"), ("speed", "2"), ("smooth", "3")):
        field = form.find_element("name", name)
        field.clear()
        field.send_keys(value)
    form.find_element("css selector", "button[type=submit]").click()
    result = editor(browser, 1).find_element("css selector", ".action-result")
    browser.wait(lambda _: result.get_attribute("data-state") == "done", message=f"Apply gave no result: {result.text}")
    segment = server.get(SEGMENTS)[0]
    assert (segment["effect"], segment["speed"], segment["max_value"]) == ("flow", 2, 999), segment

    def strip():
        return browser.js(
            """const c = document.querySelector('details.segment[data-segment="1"] canvas');
               return Number(c.dataset.leds) === 20 ? Array.from(c.getContext('2d').getImageData(0, c.height >> 1, c.width, 1).data).join(',') : null;"""
        )

    browser.wait(lambda _: strip() is not None, message="segment 1 did not show 20 LEDs")
    first = strip()
    # Speed 2 moves Value by 2 every millisecond over 0..999: the flow
    # travels along the strip twice a second.
    browser.wait(lambda _: strip() not in (None, first), timeout=5, message="the flow did not move in the preview")
    browser.check()


def test_an_invalid_value_is_refused_before_any_write(server, browser):
    open_leds(browser, server)
    form = editor(browser, 2).find_element("css selector", "form")
    editor(browser, 2).find_element("css selector", "summary").click()
    count = form.find_element("name", "led_count")
    count.clear()
    count.send_keys("70000")
    form.find_element("css selector", "button[type=submit]").click()
    result = editor(browser, 2).find_element("css selector", ".action-result")
    browser.wait(lambda _: result.get_attribute("data-state") == "failed", message="no error shown")
    assert "LEDs must be a whole number from 0 to 65535" in result.text, result.text
    assert server.get(SEGMENTS)[1]["led_count"] == 0
    # Revert puts back what the device has.
    form.find_element("xpath", ".//button[text()='Revert']").click()
    assert count.get_attribute("value") == "0"
    assert browser.js("return arguments[0].dataset.dirty", form) == "false"
    browser.check()


def test_the_page_rereads_what_another_client_changed(server, browser):
    open_leds(browser, server)
    server.request("PUT", SEGMENTS + "/4", {"led_count": 8, "effect": "breathing", "colors": ["#00ff00"]})
    card = editor(browser, 4)
    browser.wait(lambda _: card.get_attribute("data-effect") == "breathing", timeout=10,
                 message="segment 4's editor did not read the change made over REST")
    assert card.get_attribute("data-led-count") == "8"
    assert card.find_element("name", "color1").get_attribute("value") == "#00ff00"
    browser.check()


def test_leds_phone_width(server, browser):
    browser.phone()
    open_leds(browser, server)
    time.sleep(0.3)
    layout = browser.js(
        """const apply = document.querySelector('details.segment[data-segment="1"] button[type=submit]').getBoundingClientRect();
           return {scroll: document.documentElement.scrollWidth, width: window.innerWidth, right: apply.right, height: apply.height};"""
    )
    assert layout["width"] == 390, layout
    assert layout["scroll"] <= layout["width"], f"the page scrolls sideways: {layout}"
    assert layout["right"] <= layout["width"] and layout["height"] >= 40, layout
    browser.check()


def test_the_led_page_reconnects_and_reads_the_new_gateway(server, browser):
    server.request("PUT", SEGMENTS + "/1", {"led_count": 6, "effect": "fix", "colors": ["#ff8000"]})
    open_leds(browser, server)
    card = editor(browser, 1)
    assert card.get_attribute("data-led-count") == "6"
    browser.wait(lambda _: canvas_pixel(browser, 1) == {"leds": 6, "rgb": [0xFF, 0x80, 0x00]},
                 message=f"the preview did not show segment 1: {canvas_pixel(browser, 1)}")
    browser.check()
    browser.js("window.notReloaded = true")

    # A new gateway's virtual UIO1LED starts from its defaults: no LEDs.
    server.kill()
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "disconnected",
                 message="the page did not show the outage")
    server.start()
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 timeout=20, message="the page did not reconnect")
    browser.wait(lambda _: card.get_attribute("data-led-count") == "0", timeout=10,
                 message="the editor still shows the old gateway's segment")
    browser.wait(lambda _: canvas_pixel(browser, 1)["leds"] == 0, timeout=10,
                 message=f"the preview still shows the old strip: {canvas_pixel(browser, 1)}")
    assert card.get_attribute("data-effect") == server.get(SEGMENTS)[0]["effect"]
    assert browser.js("return window.notReloaded === true"), "the page was reloaded"
    outage = browser.drain()
    unexpected = [p for p in outage if not OUTAGE_ERRORS.search(p)]
    assert not unexpected, unexpected
    browser.check()
