"""python-canopen RemoteNodes built from the vendor's EDS files read every
readable object of candeck's virtual devices (issue: virtual devices).

The vendor files are optional test inputs, never part of the repository: the
directory named by CANDECK_VENDOR_EDS, set by the caller; without it these
tests are reported as skipped. The devices run on candeck's own EDS, written from the manuals, so
this checks that what a real integrator's tool expects from the real device is
what the virtual one gives."""

import os

import canopen
import pytest

from conftest import Vbus

VENDOR_EDS = os.environ.get("CANDECK_VENDOR_EDS")


@pytest.fixture
def demo():
    server = Vbus("--devices", "demo")
    yield server
    server.stop()


def readable_objects(od):
    for obj in od.values():
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            entries = [obj]
        else:
            entries = list(obj.values())
        for var in entries:
            if "r" in var.access_type:
                yield var


@pytest.mark.skipif(
    not VENDOR_EDS,
    reason="CANDECK_VENDOR_EDS is not set (the directory of the vendor's EDS files; see docs/testing.md)",
)
@pytest.mark.parametrize(
    "node_id,eds",
    [(1, "umc1bds32_v1.0.4.eds"), (3, "uio1led_v1.0.0.eds")],
)
def test_every_readable_object_reads_with_its_eds_type(demo, node_id, eds):
    path = os.path.join(VENDOR_EDS, eds)
    assert os.path.isfile(path), f"CANDECK_VENDOR_EDS is set but {path} is not a file"
    network = canopen.Network()
    network.connect(interface="socketcand", host=demo.host, port=demo.port, channel=demo.channel)
    try:
        node = canopen.RemoteNode(node_id, path)
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 1.0
        failures = []
        count = 0
        for var in readable_objects(node.object_dictionary):
            count += 1
            try:
                raw = node.sdo.upload(var.index, var.subindex)
            except canopen.SdoAbortedError as err:
                failures.append(f"0x{var.index:04X} sub {var.subindex} {var.name}: abort 0x{err.code:08X}")
                continue
            size = var.data_type in canopen.objectdictionary.DATA_TYPES and len(raw)
            expected = {
                canopen.objectdictionary.BOOLEAN: 1,
                canopen.objectdictionary.INTEGER8: 1,
                canopen.objectdictionary.UNSIGNED8: 1,
                canopen.objectdictionary.INTEGER16: 2,
                canopen.objectdictionary.UNSIGNED16: 2,
                canopen.objectdictionary.INTEGER32: 4,
                canopen.objectdictionary.UNSIGNED32: 4,
                canopen.objectdictionary.REAL32: 4,
                canopen.objectdictionary.INTEGER64: 8,
                canopen.objectdictionary.UNSIGNED64: 8,
                canopen.objectdictionary.REAL64: 8,
            }.get(var.data_type)
            if expected is not None and len(raw) != expected:
                failures.append(
                    f"0x{var.index:04X} sub {var.subindex} {var.name}: {len(raw)} bytes, type needs {expected}"
                )
                continue
            # The value decodes as the EDS type.
            var.decode_raw(raw)
        assert count > 20, count
        assert failures == [], "\n".join(failures)
    finally:
        network.disconnect()
