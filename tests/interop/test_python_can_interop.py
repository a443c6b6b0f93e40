"""python-can 4.x and python-canopen against `candeck vbus` as against
upstream socketcand (linux-can/socketcand `src/state_raw.c`), issue 32
point 5: a malformed send is answered with nothing, remote frames reach
python-can in a form its socketcand interface parses without a warning,
and python-canopen's node guarding (which python-can sends as zero-length
frames) gets answers from a virtual UIO1LED."""

import logging
import time

import can
import canopen
import pytest

from conftest import Vbus

TIMEOUT = 5


def join(vbus):
    bus = can.Bus(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
    # The server holds frames back briefly after rawmode (ServerConfig::settle).
    time.sleep(0.2)
    return bus


def receive_until(bus, predicate, timeout=TIMEOUT):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = bus.recv(timeout=0.2)
        if msg is not None and predicate(msg):
            return msg
    return None


@pytest.fixture
def led():
    server = Vbus("--devices", "uio1led@3")
    yield server
    server.stop()


def python_can_warnings(caplog):
    """What python-can says of a message it cannot read. (It also warns
    when a TCP read ends inside a message, "Got incomplete message", which
    is the transport's doing and is left out.)"""
    return [
        r
        for r in caplog.records
        if r.name.startswith("can.")
        and r.levelno >= logging.WARNING
        and "incomplete message" not in r.getMessage()
    ]


def test_a_malformed_send_gets_no_reply_and_the_client_reads_on(led, caplog):
    caplog.set_level(logging.WARNING)
    a = join(led)
    b = join(led)
    try:
        # A length that says one byte and none follow: upstream socketcand
        # logs it and answers nothing; an `< error >` reply would reach
        # python-can's receive as an error frame it cannot parse.
        a._tcp_send("< send 123 1 >")
        b.send(can.Message(arbitration_id=0x321, is_extended_id=False, data=[1, 2]))
        msg = receive_until(a, lambda m: m.arbitration_id == 0x321)
        assert msg is not None and bytes(msg.data) == b"\x01\x02"
        assert not msg.is_error_frame
        # Nothing else came: no error frame on the way.
        while (extra := a.recv(timeout=0.3)) is not None:
            assert not extra.is_error_frame, extra
        assert python_can_warnings(caplog) == []
    finally:
        a.shutdown()
        b.shutdown()


def test_node_guarding_from_python_canopen_gets_answers_and_remote_frames_parse(led, caplog):
    caplog.set_level(logging.WARNING)
    watcher = join(led)
    network = canopen.Network()
    network.connect(interface="socketcand", host=led.host, port=led.port, channel=led.channel)
    try:
        node = canopen.RemoteNode(3, canopen.ObjectDictionary())
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 1.0
        # CiA 301: a device answers node guarding while its heartbeat is off.
        node.sdo.download(0x1017, 0, (0).to_bytes(2, "little"))
        time.sleep(0.1)
        node.nmt.start_node_guarding(0.1)
        try:
            # The guarding answer: 0x703, one byte, toggle bit and the state
            # (pre-operational, 0x7F).
            assert node.nmt.wait_for_heartbeat(timeout=TIMEOUT) == "PRE-OPERATIONAL"
            answers = []
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                msg = watcher.recv(timeout=0.2)
                if msg is not None and msg.arbitration_id == 0x703:
                    answers.append(msg)
        finally:
            node.nmt.stop_node_guarding()
        # The watcher saw the guarding requests (remote frames, as python-can
        # can only show them: without data) and the device's answers.
        # The device's boot-up message (0x703, one byte 0x00) can reach the
        # watcher too, when the device booted after it joined (a loaded
        # machine): it is no guarding answer, whose state is never 0.
        requests = [m for m in answers if len(m.data) == 0]
        replies = [m for m in answers if len(m.data) == 1 and m.data[0] != 0x00]
        assert requests, answers
        assert replies, answers
        assert all(m.data[0] & 0x7F == 0x7F for m in replies), replies
        toggles = {m.data[0] & 0x80 for m in replies}
        assert len(replies) < 2 or toggles == {0x00, 0x80}, replies
        assert python_can_warnings(caplog) == []
    finally:
        network.disconnect()
        watcher.shutdown()
