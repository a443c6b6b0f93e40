"""python-canopen's RemoteNode reading a candeck SDO server: expedited
uploads per second (0x2003, 4 bytes) and segmented upload throughput
(0x2007, a 1,000-byte OCTET_STRING). Used by benches/sdo.rs:
`python python_sdo_reader.py HOST PORT CHANNEL NODE EDS EXPEDITED SEGMENTED`.
Prints `expedited_per_s segmented_bytes_per_s`.
"""

import sys
import time

import canopen


def main():
    host, port, channel, node_id, eds = sys.argv[1:6]
    expedited, segmented = int(sys.argv[6]), int(sys.argv[7])
    network = canopen.Network()
    network.connect(interface="socketcand", host=host, port=int(port), channel=channel)
    node = canopen.RemoteNode(int(node_id), eds)
    network.add_node(node)
    time.sleep(0.2)
    try:
        start = time.perf_counter()
        for _ in range(expedited):
            node.sdo.upload(0x2003, 0)
        expedited_rate = expedited / (time.perf_counter() - start)

        size = len(node.sdo.upload(0x2007, 0))
        start = time.perf_counter()
        for _ in range(segmented):
            node.sdo.upload(0x2007, 0)
        segmented_rate = segmented * size / (time.perf_counter() - start)
    finally:
        network.disconnect()
    print(f"{expedited_rate:.1f} {segmented_rate:.1f}")


if __name__ == "__main__":
    main()
