"""Two python-can socketcand clients through a socketcand server: one sends
N frames (id 0x181, 8 bytes), the other receives them. Prints the seconds
from the first send until the last frame arrived. Used by can_throughput.rs.

The sender keeps at most WINDOW frames ahead of the receiver, as the Rust
side of the benchmark does, so the figure is a rate without loss.
"""

import struct
import sys
import threading
import time

import can

WINDOW = 4096


def main():
    port, total = int(sys.argv[1]), int(sys.argv[2])
    sender = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
    receiver = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
    time.sleep(0.2)
    received = 0
    failure = []

    def receive():
        nonlocal received
        while received < total:
            msg = receiver.recv(timeout=10)
            if msg is None:
                failure.append(f"timed out after {received} frames")
                return
            (value,) = struct.unpack("<Q", bytes(msg.data))
            if value != received:
                failure.append(f"expected frame {received}, got {value}")
                return
            received += 1

    thread = threading.Thread(target=receive)
    thread.start()
    start = time.perf_counter()
    for i in range(total):
        while i >= received + WINDOW and not failure:
            time.sleep(0.0005)
        sender.send(can.Message(arbitration_id=0x181, is_extended_id=False, data=struct.pack("<Q", i)))
    thread.join()
    elapsed = time.perf_counter() - start
    sender.shutdown()
    receiver.shutdown()
    if failure:
        print(failure[0], file=sys.stderr)
        sys.exit(1)
    print(f"{elapsed:.6f}")


if __name__ == "__main__":
    main()
