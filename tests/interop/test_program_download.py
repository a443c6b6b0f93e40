"""Program download (CiA 302-3) to a virtual UIO1LED by python-canopen's
SDO block download: 0x1F56 sub 1 gives the image's CRC-32 (zlib's), a
reset of the program (0x1F51 = 2) brings the header's version into 0x100A,
and the image is kept under `--data-dir`."""

import os
import struct
import time
import zlib

import canopen

from conftest import Vbus

EDS = os.path.join(os.path.dirname(__file__), "..", "..", "eds", "uio1led.eds")


def image():
    version = b"5.4.3"
    head = b"CDKI" + bytes([len(version)]) + version
    body = bytes((i * 2654435761 >> 24) & 0xFF for i in range(64 * 1024 - len(head)))
    return head + body


def test_python_canopen_block_downloads_a_program_to_the_uio1led(tmp_path):
    vbus = Vbus("--devices", "uio1led@3", "--data-dir", str(tmp_path))
    network = canopen.Network()
    try:
        network.connect(interface="socketcand", host=vbus.host, port=vbus.port, channel=vbus.channel)
        node = canopen.RemoteNode(3, EDS)
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 2.0
        data = image()
        node.sdo.download(0x1F51, 1, b"\x00")
        node.sdo.download(0x1F51, 1, b"\x03")
        started = time.monotonic()
        with node.sdo.open(0x1F50, 1, "wb", block_transfer=True, size=len(data)) as f:
            f.write(data)
        elapsed = time.monotonic() - started
        print(f"python-canopen block download: {len(data)} bytes in {elapsed:.2f} s ({len(data) / elapsed:.0f} bytes/s)")
        (crc,) = struct.unpack("<I", node.sdo.upload(0x1F56, 1))
        assert crc == zlib.crc32(data)
        assert struct.unpack("<I", node.sdo.upload(0x1F57, 1))[0] == 0
        node.sdo.download(0x1F51, 1, b"\x02")
        assert node.sdo.upload(0x100A, 0) == b"5.4.3"
        assert node.sdo.upload(0x1F51, 1) == b"\x01"
    finally:
        network.disconnect()
        vbus.stop()
    kept = tmp_path / "devices" / "uio1led-3.program.bin"
    assert kept.read_bytes() == data
