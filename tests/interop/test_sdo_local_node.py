"""`candeck od` (our SDO client) against a python-canopen LocalNode (its SDO
server and its own object dictionary), through `candeck vbus` (issue: CANopen
core, interop)."""

import os
import subprocess
import time

import canopen
import pytest

from conftest import BIN

EDS = os.path.join(os.path.dirname(__file__), "..", "data", "testnode.eds")
NODE = 5


@pytest.fixture
def local_node(vbus):
    network = canopen.Network()
    network.connect(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
    node = canopen.LocalNode(NODE, EDS)
    network.add_node(node)
    time.sleep(0.2)
    yield node
    network.disconnect()


def od(vbus, *args):
    """Runs `candeck od ...` against node 5; returns (status, stdout, stderr)."""
    proc = subprocess.run(
        [BIN, "od", *args[:1], "--bus", vbus.spec, "--node", str(NODE), *args[1:]],
        capture_output=True,
        text=True,
        timeout=30,
    )
    return proc.returncode, proc.stdout.strip(), proc.stderr.strip()


def read(vbus, index, sub, data_type):
    status, out, err = od(vbus, "read", index, str(sub), "--type", data_type)
    assert status == 0, err
    return out


def write(vbus, index, sub, value, data_type):
    status, out, err = od(vbus, "write", index, str(sub), value, "--type", data_type)
    assert status == 0, err


def test_a_long_visible_string_is_read_segmented(vbus, local_node):
    assert read(vbus, "0x2000", 0, "vs") == "candeck interop test string"
    assert read(vbus, "0x1008", 0, "vs") == "candeck test node"


@pytest.mark.parametrize(
    "index,data_type,values,python_values",
    [
        ("0x2001", "u8", ["200", "0", "255"], [200, 0, 255]),
        ("0x2002", "i16", ["-32768", "32767", "-2"], [-32768, 32767, -2]),
        ("0x2003", "u32", ["4294967295", "0", "305419896"], [4294967295, 0, 305419896]),
        (
            "0x2004",
            "i64",
            ["-9223372036854775808", "9223372036854775807", "-5000000000"],
            [-9223372036854775808, 9223372036854775807, -5000000000],
        ),
        ("0x2005", "r32", ["-2.5", "0", "3.25"], [-2.5, 0.0, 3.25]),
    ],
)
def test_values_are_written_and_read_back(vbus, local_node, index, data_type, values, python_values):
    for value, python_value in zip(values, python_values):
        write(vbus, index, 0, value, data_type)
        # python-canopen's own dictionary holds what candeck wrote...
        assert local_node.sdo[int(index, 16)].raw == python_value
        # ...and candeck reads it back the same.
        assert read(vbus, index, 0, data_type) == value


def test_a_string_longer_than_four_bytes_is_written_segmented(vbus, local_node):
    text = "written by candeck in several segments"
    write(vbus, "0x2000", 0, text, "vs")
    assert local_node.sdo[0x2000].raw == text
    assert read(vbus, "0x2000", 0, "vs") == text


def test_the_node_s_aborts_are_reported_with_code_and_text(vbus, local_node):
    status, out, err = od(vbus, "read", "0x2FFF", "0", "--type", "u8")
    assert status == 1 and out == ""
    assert "0x06020000" in err and "does not exist" in err.lower(), err
    assert len(err.splitlines()) == 1, err

    status, out, err = od(vbus, "write", "0x2006", "0", "1", "--type", "u32")
    assert status == 1
    assert "0x06010002" in err and "read only" in err.lower(), err
    assert local_node.sdo[0x2006].raw == 0xCAFE


def test_a_node_that_does_not_answer_is_a_timeout(vbus, local_node):
    proc = subprocess.run(
        [BIN, "od", "read", "--bus", vbus.spec, "--node", "9", "0x1000", "0", "--timeout", "300"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 1
    assert proc.stdout == ""
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1, err
    assert "node 9" in err and "did not answer" in err, err


def test_with_the_eds_objects_are_named_and_typed(vbus, local_node):
    status, out, err = od(vbus, "read", "Word", "0", "--eds", EDS)
    assert status == 0, err
    assert out == "305419896"
    status, out, err = od(vbus, "read", "Identity object", "Vendor_ID", "--eds", EDS, "--json")
    assert status == 0, err
    assert out == '{"data_type":"u32","index":"0x1018","raw":"C0DEC400","sub":1,"value":12902080}'
    status, out, err = od(vbus, "write", "Short", "0", "-7", "--eds", EDS)
    assert status == 0, err
    assert local_node.sdo[0x2002].raw == -7
    status, out, err = od(vbus, "read", "NoSuchThing", "0", "--eds", EDS)
    assert status == 1 and "NoSuchThing" in err, err
