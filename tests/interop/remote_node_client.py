"""python-canopen's RemoteNode (its SDO client) against candeck's SDO server.

Run by tests/python_peers.rs, which serves a candeck test node on a socketcand
bus: `python remote_node_client.py HOST PORT CHANNEL NODE EDS`. Every check
failing raises; success prints one line per transfer kind.
"""

import sys
import time

import canopen


def main():
    host, port, channel, node_id, eds = sys.argv[1:6]
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=int(port), channel=channel)
    node = canopen.RemoteNode(int(node_id), eds)
    network.add_node(node)
    time.sleep(0.2)
    try:
        run(node)
    finally:
        network.disconnect()


def run(node):
    # Expedited upload (4 bytes) and download.
    assert node.sdo[0x2003].raw == 0x12345678, node.sdo[0x2003].raw
    node.sdo[0x2001].raw = 200
    assert node.sdo[0x2001].raw == 200
    node.sdo[0x2004].raw = -5_000_000_000
    assert node.sdo[0x2004].raw == -5_000_000_000
    print("expedited upload and download: ok")

    # Segmented upload and download (more than 4 bytes).
    assert node.sdo[0x2000].raw == "candeck interop test string", node.sdo[0x2000].raw
    text = "python-canopen wrote this through segmented download"
    node.sdo[0x2000].raw = text
    assert node.sdo[0x2000].raw == text
    print("segmented upload and download: ok")

    # Block download then block upload, with CRC.
    data = bytes(range(256)) * 9 + b"tail"
    with node.sdo[0x2007].open("wb", size=len(data), block_transfer=True) as f:
        f.write(data)
    with node.sdo[0x2007].open("rb", block_transfer=True) as f:
        back = f.read()
    assert back == data, (len(back), len(data))
    # A block upload of a short value (the server may switch protocol).
    with node.sdo[0x2000].open("rb", block_transfer=True) as f:
        assert f.read() == text.encode()
    print("block upload and download: ok")

    # The server's aborts reach the client with their codes.
    try:
        node.sdo.upload(0x2FFF, 0)
    except canopen.SdoAbortedError as err:
        assert err.code == 0x06020000, hex(err.code)
    else:
        raise AssertionError("no abort for a missing object")
    try:
        node.sdo.download(0x2006, 0, b"\x01\x00\x00\x00")
    except canopen.SdoAbortedError as err:
        assert err.code == 0x06010002, hex(err.code)
    else:
        raise AssertionError("no abort for a read-only object")
    print("aborts: ok")


if __name__ == "__main__":
    main()
