"""python-canopen's CiA 402 master (BaseNode402) drives both axes of the
virtual UMC1BDS32 of `candeck vbus --devices demo` (node 1): each axis to
OPERATION ENABLED, then profile-position moves to target reached (issue:
UMC motion controller behaviour, acceptance).

BaseNode402 knows axis 1's objects only (0x6040, 0x6041, 0x6060, ...). Axis 2
answers at +0x800 (UMC manual, Table 2.1), so its node is built from the same
EDS with each 0x6000-0x67FF entry pointing at axis 2's object: the master
code is unchanged, its SDOs go to 0x6840, 0x6841, ..."""

import os
import time

import canopen
import pytest
from canopen.profiles.p402 import BaseNode402

from conftest import Vbus

EDS = os.path.join(os.path.dirname(__file__), "..", "..", "eds", "umc1bds32.eds")
AXIS_STEP = 0x800

# Statusword bits of profile position (UMC manual Table 2.33).
TARGET_REACHED = 1 << 10
SET_POINT_ACKNOWLEDGE = 1 << 12
# Controlword: enable operation, plus new set-point (bit 4).
ENABLE_OPERATION = 0x000F
NEW_SET_POINT = 0x0010


@pytest.fixture
def demo():
    server = Vbus("--devices", "demo")
    yield server
    server.stop()


@pytest.fixture
def network(demo):
    network = canopen.Network()
    network.connect(interface="socketcand", host=demo.host, port=demo.port, channel=demo.channel)
    yield network
    network.disconnect()


def axis_dictionary(axis):
    """The UMC1BDS32 EDS with axis `axis`'s CiA 402 objects where axis 1's are."""
    od = canopen.import_od(EDS, 1)
    shift = AXIS_STEP * (axis - 1)
    if shift:
        for index in range(0x6000, 0x6800):
            if index + shift in od.indices:
                od.indices[index] = od.indices[index + shift]
    return od


def make_node(network, axis):
    node = BaseNode402(1, axis_dictionary(axis))
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 1.0
    # The statusword comes by SDO: the demo's TPDOs are not read.
    node.setup_402_state_machine(read_pdos=False)
    return node


def wait_for(predicate, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def move_to(node, target):
    """One profile-position set-point with the CiA 402 handshake."""
    node.sdo[0x607A].raw = target
    node.controlword = ENABLE_OPERATION | NEW_SET_POINT
    wait_for(lambda: node.statusword & SET_POINT_ACKNOWLEDGE, 1.0, "set-point acknowledge")
    node.controlword = ENABLE_OPERATION
    wait_for(lambda: node.statusword & TARGET_REACHED, 10.0, f"target {target} reached")
    return node.sdo[0x6064].raw


def test_base_node_402_runs_profile_position_moves_on_axis_1_then_axis_2(network):
    network.nmt.send_command(0x01)  # start all nodes
    window = None
    positions = {}
    for axis, targets in ((1, (200_000, -50_000)), (2, (120_000, 30_000))):
        node = make_node(network, axis)
        assert node.sdo[0x6041].od.index == 0x6041 + AXIS_STEP * (axis - 1)
        assert node.state == "SWITCH ON DISABLED"
        node.op_mode = "PROFILED POSITION"
        assert node.op_mode == "PROFILED POSITION"
        node.sdo[0x6081].raw = 500  # increments/ms
        node.sdo[0x6083].raw = 20  # increments/ms²
        node.sdo[0x6084].raw = 20
        node.state = "OPERATION ENABLED"
        assert node.state == "OPERATION ENABLED"
        window = node.sdo[0x6067].raw
        for target in targets:
            actual = move_to(node, target)
            assert abs(actual - target) <= window, (axis, target, actual)
            assert node.sdo[0x6062].raw == target
        positions[axis] = actual
        node.state = "SWITCH ON DISABLED"
        network.nodes.pop(1)
    # Each axis kept its own position: axis 2's moves did not move axis 1.
    sdo = make_node(network, 1).sdo
    assert abs(sdo[0x6064].raw - positions[1]) <= window
    axis2 = int.from_bytes(sdo.upload(0x6864, 0), "little", signed=True)
    assert abs(axis2 - positions[2]) <= window


def test_the_ip_buffer_refuses_a_33rd_set_point(network):
    node = make_node(network, 1)
    node.op_mode = "INTERPOLATED POSITION"
    for n in range(32):
        node.sdo[0x60C1][1].raw = n * 10
    assert node.sdo[0x60C4][2].raw == 32
    with pytest.raises(canopen.SdoAbortedError) as aborted:
        node.sdo[0x60C1][1].raw = 999
    assert aborted.value.code == 0x08000022
    node.sdo[0x60C4][6].raw = 0
    assert node.sdo[0x60C4][2].raw == 0
