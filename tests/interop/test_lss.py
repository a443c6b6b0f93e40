"""LSS (CiA 305) with python-canopen's LssMaster as the peer of candeck's
virtual LSS slaves, and the UniSwarm node-ID change (0x2040, save, reset)
done with python-canopen, over `candeck vbus` (issue 17, points 6 and 7)."""

import time

import canopen
import pytest

from conftest import Vbus

UIO1LED = [0x4A2, 0x4101, 1]
JMC = [0x2D9, 0, 0]


def connect(vbus):
    network = canopen.Network()
    network.connect(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
    # Fastscan waits this long for each bit that is 1; the bus is local.
    network.lss.RESPONSE_TIMEOUT = 0.2
    return network


def remote(network, node_id):
    node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 0.5
    return node


def answers(network, node_id):
    try:
        return remote(network, node_id).sdo.upload(0x1000, 0) is not None
    except canopen.SdoCommunicationError:
        return False


@pytest.fixture
def line():
    server = Vbus("--devices", "umc1bds32@1,uio1led@lss,jmc@lss/77")
    yield server
    server.stop()


def test_lss_master_finds_and_configures_unconfigured_devices(line):
    network = connect(line)
    try:
        lss = network.lss
        # An unconfigured device answers nothing but LSS.
        assert not answers(network, 10)
        found, address = lss.fast_scan()
        assert found
        # Fastscan finds the lowest LSS address first: the JMC's vendor-ID.
        assert address == [*JMC, 77]
        lss.configure_node_id(11)
        lss.store_configuration()
        assert lss.inquire_lss_address(0x5D) == 77
        lss.send_switch_state_global(lss.WAITING_STATE)
        time.sleep(0.1)
        assert remote(network, 11).sdo.upload(0x1018, 4) == (77).to_bytes(4, "little")

        # The other one by selective switch.
        assert lss.send_switch_state_selective(*UIO1LED, 0x101)
        assert lss.inquire_node_id() == 0xFF
        lss.configure_node_id(10)
        lss.store_configuration()
        lss.send_switch_state_global(lss.WAITING_STATE)
        time.sleep(0.1)
        node = remote(network, 10)
        assert node.sdo.upload(0x1018, 2) == (0x4101).to_bytes(4, "little")
        assert node.sdo.upload(0x2040, 1) == bytes([10])

        # Nothing unconfigured is left; the stored node-IDs survive a reset.
        found, _ = lss.fast_scan()
        assert not found
        network.nmt.send_command(0x81)
        time.sleep(0.2)
        assert answers(network, 10) and answers(network, 11) and answers(network, 1)
    finally:
        network.disconnect()


def test_node_id_change_by_0x2040_save_and_reset(tmp_path):
    vbus = Vbus("--devices", "uio1led@3", "--data-dir", str(tmp_path))
    try:
        network = connect(vbus)
        try:
            node = remote(network, 3)
            node.sdo.download(0x2040, 1, bytes([9]))
            node.sdo.download(0x1010, 1, b"save")
            node.nmt.send_command(0x81)
            time.sleep(0.2)
            # It boots as node 9, no longer as node 3.
            assert remote(network, 9).sdo.upload(0x2040, 1) == bytes([9])
            assert not answers(network, 3)
        finally:
            network.disconnect()
    finally:
        vbus.stop()
    # A restart of vbus with the same device list keeps node 9.
    vbus = Vbus("--devices", "uio1led@3", "--data-dir", str(tmp_path))
    try:
        network = connect(vbus)
        try:
            assert answers(network, 9)
            assert not answers(network, 3)
        finally:
            network.disconnect()
    finally:
        vbus.stop()
