"""Issue 21 point 4 on the drive page: every value with its unit (the UMC's
increments and increments/ms, the JMC's steps and 0.1 rps, with the
conversion to revolutions), the limits the drive applies next to the inputs
(0x607F, 0x6046, 0x607D), and a request beyond one said before it is sent
and, once the drive ran it, said clipped."""

from test_drive import UMC_AXIS, click, disable, drive_state, open_drive, text

JMC_AXIS = "/api/v1/buses/demo/nodes/2/axes/1"


def tap(browser, css):
    """Clicks `css` once it is enabled, scrolled to the middle of the
    screen (the sticky top bar and stop bar cover the top)."""
    element = browser.wait(
        lambda d: next((e for e in d.find_elements("css selector", css) if e.is_enabled()), None),
        message=f"no enabled {css}",
    )
    browser.js("arguments[0].scrollIntoView({block: 'center'})", element)
    element.click()


def limits_text(browser):
    return browser.js("return document.getElementById('axis-limits').innerText")


def test_umc_readouts_and_limits_carry_their_units(server, browser):
    axis = server.get(UMC_AXIS)
    assert axis["units"]["position"] == "increments" and axis["units"]["velocity"] == "increments/ms"
    open_drive(browser, server)
    browser.wait(lambda _: text(browser, "unit-position") == "increments", message="no position unit")
    assert text(browser, "unit-velocity") == "increments/ms"
    assert text(browser, "conv-velocity") == "= 0 rps (0 rpm)"
    assert text(browser, "conv-position") == "= 0 rev"
    limits = limits_text(browser)
    assert "Max profile velocity (0x607F)\n16,384 increments/ms (250 rps)" in limits, limits
    assert f"VL min / max (0x6046)\n0 / {axis['limits']['vl_max']:,} vl units" in limits, limits
    assert "Encoder resolution (0x608F)" in limits and "Gear ratio (0x6091)" in limits, limits
    # 0x6081 and 0x606C are both increments/ms: the page says so, and why
    # a short move never reaches the profile velocity.
    assert "both in increments/ms" in text(browser, "units-note")
    click(browser, '#mode-tabs button[data-mode="profile_position"]')
    hints = browser.js("return [...document.querySelectorAll('form[data-mode=\"profile_position\"] .hint')].map((h) => h.textContent)")
    assert any("increments/ms" in h and "at most 16,384 (0x607F)" in h for h in hints), hints
    browser.check()


def test_a_request_beyond_a_limit_is_said_clipped_before_and_after(server, browser):
    server.post(f"{UMC_AXIS}/state", {"target": "operation_enabled"})
    try:
        open_drive(browser, server)
        browser.wait(lambda _: drive_state(browser) == "operation_enabled", message="not enabled")
        # Profile position: 20000 increments/ms is over 0x607F; 200,000
        # increments at 0x6083 = 1 increment/ms² peak near 447.
        click(browser, '#mode-tabs button[data-mode="profile_position"]')
        form = browser.driver.find_element("css selector", 'form[data-mode="profile_position"]')
        form.find_element("name", "target").clear()
        form.find_element("name", "target").send_keys("200000")
        form.find_element("name", "velocity").send_keys("20000")
        note = form.find_element("css selector", ".clip-note")
        browser.wait(lambda _: note.is_displayed(), message="no clip notice")
        assert "The drive will clip profile velocity 20,000 to 16,384 increments/ms (0x607F)." in note.text, note.text
        assert "peaks near 447 increments/ms" in note.text, note.text

        # Velocity (VL) 1202 over 0x6046.2 = 1000.
        tap(browser, '#mode-tabs button[data-mode="velocity"]')
        form = browser.driver.find_element("css selector", 'form[data-mode="velocity"]')
        field = form.find_element("name", "velocity")
        field.clear()
        field.send_keys("1202")
        note = form.find_element("css selector", ".clip-note")
        browser.wait(lambda _: note.is_displayed(), message="no clip notice for the velocity")
        assert note.text == "The drive will clip velocity 1,202 to 1,000 vl units (0x6046.2).", note.text
        tap(browser, 'form[data-mode="velocity"] button.start')
        browser.wait(lambda _: browser.js("return document.getElementById('move-result').dataset.state") == "done",
                     message=f"the move gave no result: {text(browser, 'move-result')}")
        assert "Velocity 1,202 clipped to 1,000 vl units by 0x6046.2." in text(browser, "move-result")
        # The drive applied it: it runs at 1000, not 1202.
        browser.wait(lambda _: text(browser, "value-velocity") == "1,000", message="the drive did not run at its limit")
        tap(browser, 'form[data-mode="velocity"] button.stop')
        browser.wait(lambda _: text(browser, "value-velocity") == "0", message="the stop did not show")
        # Within the limit: no notice.
        field.clear()
        field.send_keys("500")
        assert not note.is_displayed()
    finally:
        disable(server)
    browser.check()


def test_jmc_readouts_in_steps_and_tenths_of_rps(server, browser):
    axis = server.get(JMC_AXIS)
    assert axis["units"]["velocity"] == "0.1 rps" and axis["units"]["position"] == "steps"
    open_drive(browser, server, node=2, axis=1)
    browser.wait(lambda _: text(browser, "unit-velocity") == "0.1 rps", message="no JMC velocity unit")
    assert text(browser, "unit-position") == "steps"
    assert text(browser, "conv-velocity") == "= 0 rps (0 rpm)"
    assert text(browser, "conv-position") == ""  # steps per revolution: the drive's subdivision, unknown
    limits = limits_text(browser)
    assert "Velocity\n0.1 rps, 1 = 0.1 rps" in limits, limits
    click(browser, '#mode-tabs button[data-mode="profile_position"]')
    hints = browser.js("return [...document.querySelectorAll('form[data-mode=\"profile_position\"] .hint')].map((h) => h.textContent)")
    assert any("0.1 rps" in h for h in hints) and any("steps" in h for h in hints), hints
    browser.check()
