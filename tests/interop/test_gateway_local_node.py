"""The gateway's REST API (`candeck serve`) against a python-canopen LocalNode
on a bus shared through `candeck vbus` (issue 5, acceptance: a real CANopen
peer that candeck did not write).

    LocalNode (python-can socketcand) --\
                                         candeck vbus --devices none
    candeck serve --bus lab=socketcand:... --eds-dir tests/data --/

The node boots after the gateway's first scan is over, so the gateway can
only know it from its boot-up message. Every wait polls with a deadline.
"""

import json
import os
import re
import time
import urllib.error
import urllib.parse
import urllib.request

import canopen
import pytest
from canopen.sdo.exceptions import SdoAbortedError

from conftest import Process

DATA = os.path.join(os.path.dirname(__file__), "..", "data")
EDS = os.path.join(DATA, "testnode.eds")
NODE = 42
BUS = "lab"
# A value 0x2001 (UNSIGNED8 in the EDS, so 0–255 passes the gateway's
# checks) that the node refuses with its own abort code.
REFUSED_ABOVE = 100
VALUE_RANGE_EXCEEDED = 0x06090030


def wait_for(what, check, timeout=10.0, interval=0.02):
    """Polls `check` until it returns something truthy; fails after `timeout`."""
    deadline = time.monotonic() + timeout
    while True:
        result = check()
        if result:
            return result
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


def quote(part):
    return urllib.parse.quote(str(part), safe="")


class Api:
    """A small JSON client of `candeck serve`."""

    def __init__(self, base):
        self.base = base

    def request(self, method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(
            f"{self.base}/api/v1{path}",
            data=data,
            method=method,
            headers={"Content-Type": "application/json"} if data is not None else {},
        )
        try:
            with urllib.request.urlopen(req, timeout=10) as resp:
                return resp.status, json.loads(resp.read())
        except urllib.error.HTTPError as err:
            return err.code, json.loads(err.read())

    def get(self, path):
        return self.request("GET", path)

    def put(self, path, body):
        return self.request("PUT", path, body)

    def post(self, path, body):
        return self.request("POST", path, body)

    def node(self, node_id):
        status, nodes = self.get(f"/buses/{BUS}/nodes")
        assert status == 200, nodes
        return next((node for node in nodes if node["id"] == node_id), None)

    def od(self, index, sub):
        return self.get(f"/buses/{BUS}/nodes/{NODE}/od/{quote(index)}/{quote(sub)}")

    def write_od(self, index, sub, value):
        path = f"/buses/{BUS}/nodes/{NODE}/od/{quote(index)}/{quote(sub)}"
        return self.put(path, {"value": value})


# The gateway's network manager boots every node it finds: it would set the
# LocalNode's heartbeat and start it. These tests drive the node's NMT state
# and heartbeat themselves, so the machine describes node 42 as a node to
# leave pre-operational and unconfigured.
MACHINE = f"""
[[nodes]]
id = {NODE}
mandatory = false
heartbeat_ms = 0
consume_manager_heartbeat = false
start = false
"""


@pytest.fixture
def gateway(vbus, tmp_path):
    config = tmp_path / "machine.toml"
    config.write_text(MACHINE)
    server = Process(
        [
            "serve",
            "--config",
            str(config),
            "--listen",
            "127.0.0.1:0",
            "--bus",
            f"{BUS}={vbus.spec}",
            "--eds-dir",
            DATA,
        ]
    )
    line = server.first_line()
    match = re.search(r"serving (http://[0-9.]+:\d+)/", line)
    assert match, f"unexpected first line: {line!r}"
    api = Api(match.group(1))

    def bus_up():
        status, buses = api.get("/buses")
        return status == 200 and any(b["name"] == BUS and b["state"] == "up" for b in buses)

    # The node boots only once the gateway is connected (or the boot-up
    # would go unheard) and its first scan has ended (whether it found
    # nothing or found the bus still down), so that nothing but the boot-up
    # can make the gateway know the node.
    wait_for("bus lab up", bus_up, timeout=30)
    wait_for(
        "the gateway's first scan",
        lambda: re.search(r"bus lab: (\d+ nodes found|first scan failed)", server.log()),
        timeout=30,
    )
    yield api
    server.stop()


@pytest.fixture
def local_node(vbus, gateway):
    network = canopen.Network()
    network.connect(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
    node = canopen.LocalNode(NODE, EDS)

    def refuse_large_bytes(index, subindex, od, data):
        if index == 0x2001 and data[0] > REFUSED_ABOVE:
            raise SdoAbortedError(VALUE_RANGE_EXCEEDED)

    node.add_write_callback(refuse_large_bytes)
    network.add_node(node)
    # The gateway has not heard of it: no scan found it.
    assert gateway.node(NODE) is None
    # INITIALISING sends the boot-up message (0x700 + id, [0x00]); then
    # the node is pre-operational, as after any boot-up.
    node.nmt.state = "INITIALISING"
    node.nmt.state = "PRE-OPERATIONAL"
    yield node
    node.nmt.stop_heartbeat()
    network.disconnect()


def index_of(node, index):
    """An index given as "0x2003" or by its EDS name, as a number."""
    return int(index, 16) if index.startswith("0x") else node.object_dictionary[index].index


def identified(api):
    node = api.node(NODE)
    return node if node and node["identification"]["state"] == "done" else None


def test_the_node_is_listed_from_its_boot_up_and_identified(gateway, local_node):
    node = wait_for("node 42 identified", lambda: identified(gateway))
    assert node["nmt"] == "pre_operational"
    assert node["online"] is True
    assert node["identity"] == {
        "vendor_id": 0x00C4DEC0,
        "product_code": 1,
        "revision": 0x00010000,
        "serial": 0x42,
    }
    assert node["name"] == "candeck test node"
    assert node["eds"] == "testnode.eds"
    assert node["profile"] == "generic"


def test_the_dictionary_is_read_through_rest(gateway, local_node):
    wait_for("node 42 identified", lambda: identified(gateway))
    # Values the LocalNode holds, some changed from the EDS defaults.
    local_node.sdo[0x2003].raw = 0xDEADBEEF
    local_node.sdo[0x2002].raw = -321
    cases = [
        ("0x2003", 0, {"value": 0xDEADBEEF, "raw": "efbeadde", "data_type": "u32"}),
        ("Short", 0, {"value": -321, "raw": "bffe", "data_type": "i16"}),
        ("0x2004", 0, {"value": "-5000000000", "data_type": "i64"}),
        ("0x2005", 0, {"value": 1.5, "raw": "0000c03f", "data_type": "r32"}),
        ("0x2000", 0, {"value": "candeck interop test string", "data_type": "vs"}),
        ("0x1018", "Serial number", {"value": 0x42, "sub": 4}),
    ]
    for index, sub, expected in cases:
        status, body = gateway.od(index, sub)
        assert status == 200, body
        for key, value in expected.items():
            assert body[key] == value, (index, sub, body)
    status, body = gateway.od("0x2003", 0)
    assert body["index"] == "0x2003" and body["sub"] == 0 and body["name"] == "Word"

    # A batch read keeps each entry's own result, and the node's abort.
    status, body = gateway.post(
        f"/buses/{BUS}/nodes/{NODE}/od/read", {"entries": [["0x2001", 0], ["Word", 0]]}
    )
    assert status == 200, body
    assert [entry["value"] for entry in body] == [7, 0xDEADBEEF]


def test_writes_reach_the_node_s_data_store_and_read_back(gateway, local_node):
    wait_for("node 42 identified", lambda: identified(gateway))
    cases = [
        ("0x2001", 99, 99),
        ("0x2002", -32768, -32768),
        ("Word", 305419896, 305419896),
        ("0x2004", "9223372036854775807", 9223372036854775807),
        ("0x2005", -2.5, -2.5),
        ("0x2000", "written through REST, segmented", "written through REST, segmented"),
    ]
    for index, value, python_value in cases:
        status, body = gateway.write_od(index, 0, value)
        assert status == 200, (index, body)
        # The answer is the value read back from the node...
        assert body["value"] == value, (index, body)
        # ...which holds it in its own data store...
        assert local_node.sdo[index_of(local_node, index)].raw == python_value
        # ...and a fresh read says the same.
        status, body = gateway.od(index, 0)
        assert status == 200 and body["value"] == value, (index, body)


def test_writes_the_node_refuses_are_422_with_its_abort_code(gateway, local_node):
    wait_for("node 42 identified", lambda: identified(gateway))
    # The node's own rule, unknown to the EDS (which allows 0–255).
    status, body = gateway.write_od("0x2001", 0, REFUSED_ABOVE + 1)
    assert status == 422, body
    assert body["error"]["code"] == "sdo_abort"
    assert body["error"]["abort_code"] == "0x06090030"
    assert local_node.sdo[0x2001].raw == 7

    # A read-only object: refused with the abort the device would give
    # (before the bus, since the EDS says ro), and left as it was.
    status, body = gateway.write_od("0x2006", 0, 1)
    assert status == 422, body
    assert body["error"]["abort_code"] == "0x06010002"
    assert local_node.sdo[0x2006].raw == 0xCAFE

    # An object the node does not have.
    status, body = gateway.put(
        f"/buses/{BUS}/nodes/{NODE}/od/0x2FFF/0", {"value": 1, "data_type": "u8"}
    )
    assert status == 422, body
    assert body["error"]["abort_code"] == "0x06020000"

    # Out of the EDS type's range: refused before the bus is touched.
    status, body = gateway.write_od("0x2001", 0, 256)
    assert status == 400, body
    assert local_node.sdo[0x2001].raw == 7


def test_a_stopped_node_is_refused_sdo_until_started(gateway, local_node):
    wait_for("node 42 identified", lambda: identified(gateway))
    # Heartbeat on, written through REST: the node's NMT state reaches
    # the gateway with each heartbeat.
    status, body = gateway.write_od("0x1017", 0, 50)
    assert status == 200, body
    wait_for("heartbeat supervision", lambda: gateway.node(NODE)["heartbeat_ms"] is not None)

    status, body = gateway.post(f"/buses/{BUS}/nodes/{NODE}/nmt", {"command": "stop"})
    assert status == 200, body
    wait_for("node 42 stopped", lambda: gateway.node(NODE)["nmt"] == "stopped")
    assert local_node.nmt.state == "STOPPED"
    # CiA 301: no SDO in the stopped state; the gateway refuses it itself.
    status, body = gateway.od("0x2003", 0)
    assert status == 409, body
    assert body["error"]["code"] == "wrong_nmt_state"
    assert body["error"]["nmt"] == "stopped"

    status, body = gateway.post(f"/buses/{BUS}/nodes/{NODE}/nmt", {"command": "start"})
    assert status == 200, body
    wait_for("node 42 operational", lambda: gateway.node(NODE)["nmt"] == "operational")
    status, body = gateway.od("0x2003", 0)
    assert status == 200 and body["value"] == 0x12345678, body
