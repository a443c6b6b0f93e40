"""Issue 21's "Machine view" item (the network manager of issue 17) on the
overview, with expected nodes: each node expected or found, its boot-up
step and supervision, a mandatory node that is missing named as such, and
the machine's state with its reasons."""

import os

import pytest

from conftest import Server, free_port
from test_machine import machine_rows, machine_state

# Node 1 expected and mandatory; node 5 expected, mandatory and absent.
MACHINE = "".join(f"[[nodes]]\nid = {node}\nmandatory = true\n\n" for node in (1, 5))


@pytest.fixture
def server(tmp_path):
    config = tmp_path / "machine.toml"
    config.write_text(MACHINE)
    s = Server(free_port(), args=["--config", str(config)])
    s.start()
    yield s
    s.stop()
    os.unlink(s.log_file.name)


def test_the_machine_view_shows_expected_and_found_nodes_their_step_and_supervision(server, browser):
    browser.driver.get(server.url + "/")

    def shown(_):
        rows = machine_rows(browser)
        return rows if {"1", "5"} <= set(rows) and rows["1"]["state"] == "ready" and rows["5"]["state"] == "missing" else None

    rows = browser.wait(shown, timeout=30, message=f"the machine was not shown: {machine_rows(browser)}")
    assert rows["1"]["Expected"] == "expected" and "mandatory" in rows["1"]["Name"], rows["1"]
    assert rows["1"]["Step"] == "supervised" and rows["1"]["Supervision"] == "heartbeat", rows["1"]
    assert rows["5"]["Expected"] == "expected" and "mandatory" in rows["5"]["Name"], rows["5"]
    # Found but not described: unexpected, left alone.
    assert rows["2"]["Expected"] == "found" and rows["2"]["state"] == "unexpected", rows["2"]
    machine = server.get("/api/v1/buses/demo/machine")
    assert machine_state(browser) == machine["state"] != "ready", machine
    said = browser.js("return document.querySelector('#machine-states p[data-bus=\"demo\"]').innerText")
    assert all(reason in said for reason in machine["reasons"]), (said, machine["reasons"])
    # A missing node has no Start to offer, only Boot again.
    actions = browser.js("return [...document.querySelectorAll('#machine tr[data-node=\"5\"] button')].map((b) => b.textContent)")
    assert actions == ["Boot again"], actions
