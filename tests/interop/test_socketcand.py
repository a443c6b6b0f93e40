"""python-can's socketcand interface on `candeck vbus`, and `candeck dump`
watching the same bus (issue: CAN layer, interop)."""

import re
import socket
import threading
import time

import can
import pytest

from conftest import Process

TIMEOUT = 10


def join(vbus):
    bus = can.Bus(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
    # The server holds frames back briefly after rawmode (see ServerConfig::settle).
    time.sleep(0.2)
    return bus


def traffic(first_id, count):
    """Standard and extended identifiers, 0 to 8 data bytes."""
    messages = []
    for i in range(count):
        length = i % 9
        data = bytes((i + k) & 0xFF for k in range(length))
        if i % 2:
            messages.append(can.Message(arbitration_id=0x1ABC0000 + first_id + i, is_extended_id=True, data=data))
        else:
            messages.append(can.Message(arbitration_id=(first_id + i) & 0x7FF, is_extended_id=False, data=data))
    return messages


def key(msg):
    return (msg.arbitration_id, msg.is_extended_id, bytes(msg.data))


def receive(bus, count, timeout=TIMEOUT):
    got = []
    deadline = time.monotonic() + timeout
    while len(got) < count and time.monotonic() < deadline:
        msg = bus.recv(timeout=0.5)
        if msg is not None:
            got.append(msg)
    return got


def parse_dump(lines):
    """candump -L lines back into (id, extended, data)."""
    frames = []
    for line in lines:
        match = re.fullmatch(r"\((\d+)\.(\d{6})\) (\S+) ([0-9A-F]{3}|[0-9A-F]{8})#([0-9A-F]*)", line.strip())
        assert match, f"not a candump -L line: {line!r}"
        ident = match.group(4)
        frames.append((int(ident, 16), len(ident) == 8, bytes.fromhex(match.group(5))))
    return frames


def start_dump(vbus, count):
    dump = Process(["dump", "--bus", vbus.spec, "--count", str(count)])
    deadline = time.monotonic() + TIMEOUT
    while "writing candump" not in dump.log():
        assert dump.proc.poll() is None, dump.log()
        assert time.monotonic() < deadline, dump.log()
        time.sleep(0.05)
    time.sleep(0.2)
    return dump


def test_two_python_can_clients_exchange_frames_in_order_without_echo(vbus):
    a_to_b = traffic(0x100, 300)
    b_to_a = traffic(0x300, 120)
    dump = start_dump(vbus, len(a_to_b) + len(b_to_a))
    a = join(vbus)
    b = join(vbus)
    try:
        for msg in a_to_b:
            a.send(msg)
        got = receive(b, len(a_to_b))
        assert [key(m) for m in got] == [key(m) for m in a_to_b]
        assert all(not m.is_remote_frame and not m.is_error_frame for m in got)

        for msg in b_to_a:
            b.send(msg)
        got = receive(a, len(b_to_a))
        assert [key(m) for m in got] == [key(m) for m in b_to_a]

        # Nobody hears its own frames.
        assert a.recv(timeout=0.5) is None
        assert b.recv(timeout=0.5) is None

        out, _ = dump.proc.communicate(timeout=TIMEOUT)
        assert dump.proc.returncode == 0, dump.log()
        assert parse_dump(out.splitlines()) == [key(m) for m in a_to_b + b_to_a]
    finally:
        a.shutdown()
        b.shutdown()
        dump.stop()


def raw_client(vbus, rcvbuf=None):
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.connect((vbus.host, vbus.port))
    sock.settimeout(TIMEOUT)
    return sock


def read_until(sock, needle):
    seen = b""
    while needle not in seen:
        chunk = sock.recv(4096)
        assert chunk, f"closed before {needle!r}: {seen!r}"
        seen += chunk
    return seen


def test_garbage_and_a_stalled_client_do_not_disturb_the_others(unlimited_vbus):
    # 20,000 frames at 10,000 a second: more than a 500 kbit/s wire carries.
    vbus = unlimited_vbus
    a = join(vbus)
    b = join(vbus)
    junk = raw_client(vbus)
    stalled = raw_client(vbus, rcvbuf=4096)
    try:
        read_until(junk, b"< hi >")
        junk.sendall(b"\x00\xffGET / HTTP/1.1\r\n\r\n")
        assert read_until(junk, b">").startswith(b"< error ")
        junk.sendall(b"< open can0 >< rawmode >< send 123 9 1 >< frobnicate >")
        reply = read_until(junk, b"unknown command")
        # Upstream socketcand answers a malformed send with silence (issue
        # 32: python-can reads any `< error ... >` as an error frame), and
        # the session goes on to the next command.
        assert b"< ok >< ok >< error unknown command" in reply, reply
        assert b"error send" not in reply, reply

        read_until(stalled, b"< hi >")
        stalled.sendall(b"< open can0 >< rawmode >")
        read_until(stalled, b"< ok >< ok >")
        # From here on the stalled client never reads again.

        sent = traffic(0x10, 20000)
        got = []
        reader = threading.Thread(target=lambda: got.extend(receive(b, len(sent), timeout=60)))
        reader.start()
        for i, msg in enumerate(sent):
            a.send(msg)
            if i % 100 == 99:
                # A saturated 1 Mbit/s bus carries about 8,000 frames/s; a
                # python-can reader keeps up with that.
                time.sleep(0.01)
        reader.join()
        assert len(got) == len(sent)
        assert [key(m) for m in got] == [key(m) for m in sent]

        deadline = time.monotonic() + 15
        while "dropping it" not in vbus.log():
            assert time.monotonic() < deadline, vbus.log()
            time.sleep(0.1)
        # The junk client was answered, logged, and is still being served.
        assert "unknown command" in vbus.log()
        assert b"< frame " in read_until(junk, b"< frame ")
    finally:
        a.shutdown()
        b.shutdown()
        junk.close()
        stalled.close()


def test_a_client_that_disconnects_mid_command_leaves_the_bus_working(vbus):
    rude = raw_client(vbus)
    read_until(rude, b"< hi >")
    rude.sendall(b"< open can0 >< rawmode >< send 12")
    rude.close()
    a = join(vbus)
    b = join(vbus)
    try:
        msg = can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01\x02")
        a.send(msg)
        got = b.recv(timeout=TIMEOUT)
        assert got is not None and key(got) == key(msg)
    finally:
        a.shutdown()
        b.shutdown()
