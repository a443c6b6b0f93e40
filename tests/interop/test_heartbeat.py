"""The virtual JMC drive's heartbeat, measured on the bus by a python-can
client: the manual's default 1000 ms, within 10 % (issue: virtual devices)."""

import time

import can

from conftest import Vbus


def test_the_jmc_heartbeats_every_second_within_ten_percent():
    vbus = Vbus("--devices", "jmc@2")
    bus = can.Bus(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
    try:
        times = []
        deadline = time.monotonic() + 6
        while len(times) < 5 and time.monotonic() < deadline:
            msg = bus.recv(timeout=0.5)
            if msg is not None and msg.arbitration_id == 0x702 and bytes(msg.data) == b"\x7f":
                times.append(msg.timestamp)
        assert len(times) == 5, times
        periods = [b - a for a, b in zip(times, times[1:])]
        assert all(0.9 <= p <= 1.1 for p in periods), periods
    finally:
        bus.shutdown()
        vbus.stop()
