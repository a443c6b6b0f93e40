"""Issue 31's "Enable all" on a machine with a description: the axes of the
drives the `[[nodes]]` tables start are the machine's to bring back, so a
gateway that enabled nothing since it started (after a restart) still
returns two faulted axes to operation enabled in at most three taps."""

import os

import pytest

from conftest import Server, free_port
from test_alarms import axis_states, fault_both_axes_and_recover_in_three_taps

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
    fault_both_axes_and_recover_in_three_taps(browser, server)
