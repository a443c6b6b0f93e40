"""Issue 31's "Enable all" on a machine with a description: the axes of the
drives the `[[nodes]]` tables start are the machine's to bring back, so a
gateway that enabled nothing since it started (after a restart) still
returns two faulted axes to operation enabled in at most three taps."""

import os

import pytest
from selenium.webdriver.common.by import By

from conftest import Server, free_port
from test_alarms import NODE1, axis_states, clear, heard, inject, tap

# The demo's three nodes described (started, the default); nothing enabled.
MACHINE = "".join(f"[[nodes]]\nid = {node}\n\n" for node in (1, 2, 3))


@pytest.fixture
def server(tmp_path):
    config = tmp_path / "machine.toml"
    config.write_text(MACHINE)
    s = Server(free_port(), args=["--config", str(config)])
    s.start()
    s.wait_ready()
    yield s
    s.stop()
    os.unlink(s.log_file.name)


def test_a_described_drive_s_faulted_axes_return_in_three_taps_though_nothing_was_enabled(browser, server):
    # As after a restart: this gateway has enabled no axis.
    assert "operation_enabled" not in axis_states(server)
    inject(server)
    try:
        server.wait_for(NODE1 + "/axes/1", lambda a: a["state"] == "fault", "axis 1 did not fault")
        server.wait_for(NODE1 + "/axes/2", lambda a: a["state"] == "fault", "axis 2 did not fault")
    finally:
        clear(server)  # the cause is gone; the faults stay until reset
    browser.driver.get(server.url + "/")
    heard(browser)
    browser.wait(lambda _: browser.js("return !!document.querySelector('#machine-recovery button.reset-faults')"),
                 message="the machine card offers no Reset all faults")
    taps = 0
    tap(browser, browser.driver.find_element(By.CSS_SELECTOR, "#machine-recovery button.reset-faults"))
    taps += 1
    browser.wait(lambda _: browser.js("return !!document.querySelector('dialog.recovery-confirm[open]')"),
                 message="no confirmation asked")
    tap(browser, browser.driver.find_element(By.CSS_SELECTOR, "dialog.recovery-confirm button[data-choice='reset-enable']"))
    taps += 1
    assert taps <= 3
    server.wait_for(NODE1 + "/axes/1", lambda a: a["state"] == "operation_enabled", "axis 1 is not enabled again")
    server.wait_for(NODE1 + "/axes/2", lambda a: a["state"] == "operation_enabled", "axis 2 is not enabled again")
    said = browser.wait(lambda _: browser.js(
        "const r = document.querySelector('#machine-recovery .recovery-result'); return r && !r.hidden && r.innerText.includes('Enable all') ? r.innerText : null"),
        message="the result of the recovery is not shown")
    assert "node 1 axis 1: done" in said and "node 1 axis 2: done" in said, said
