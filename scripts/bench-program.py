#!/usr/bin/env python3
"""Program download throughput (BENCHMARKS.md, issue 22): a 64 KiB image to a
virtual UIO1LED by the gateway (virtual bus, then socketcand) and by
python-canopen on the same device. Run from the repository root:
`scripts/bench-program.py target/release/candeck [BITRATE]` with
python-canopen installed; BITRATE (default the virtual bus's 500000, or
`unlimited`: frames cross at once) is the wire timing of both virtual buses.
CANDECK_BENCH_SMOKE=1 (scripts/bench's smoke run): a 4 KiB image. Any failed
request or download ends it with an exception, status 1."""
import json, os, re, socket, subprocess, sys, time, urllib.request, zlib, struct
import canopen
BIN = sys.argv[1]
BITRATE = sys.argv[2] if len(sys.argv) > 2 else None
SMOKE = os.environ.get("CANDECK_BENCH_SMOKE", "") not in ("", "0")
def free():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p
version = b"1.0"
image = b"CDKI" + bytes([len(version)]) + version
image += bytes((i * 2654435761 >> 24) & 0xFF for i in range((4 if SMOKE else 64) * 1024 - len(image)))
def post(port, node):
    req = urllib.request.Request(f"http://127.0.0.1:{port}/api/v1/buses/demo/nodes/{node}/program", data=image, method="POST",
                                 headers={"content-type": "application/octet-stream"})
    t = time.monotonic()
    with urllib.request.urlopen(req, timeout=120) as r:
        a = json.load(r)
    return a, time.monotonic() - t
def wait_http(port):
    for _ in range(300):
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/buses/demo/nodes/3", timeout=2).read(); return
        except Exception:
            time.sleep(0.1)
    raise SystemExit("serve did not come up")
# 1. the gateway on its own virtual bus (the demo), node 3.
port = free()
wire = ["--bus", f"demo=virtual:demo?bitrate={BITRATE}"] if BITRATE else []
serve = subprocess.Popen([BIN, "serve", "--listen", f"127.0.0.1:{port}"] + wire, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
try:
    wait_http(port)
    a, t = post(port, 3)
    print(f"virtual bus, gateway: {a['bytes']} B, download {a['download_ms']} ms, {a['bytes_per_s']} B/s (HTTP round trip {t:.2f} s)")
finally:
    serve.terminate(); serve.wait()
# 2. one vbus shared over socketcand: the gateway, then python-canopen, same device.
vbus = subprocess.Popen([BIN, "vbus", "--listen", "127.0.0.1:0", "--devices", "uio1led@3"]
                        + (["--bitrate", BITRATE] if BITRATE else []), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
line = vbus.stdout.readline()
m = re.search(r"socketcand on ([0-9.]+):(\d+) channel (\S+)", line)
host, sport, channel = m.group(1), int(m.group(2)), m.group(3)
port = free()
serve = subprocess.Popen([BIN, "serve", "--listen", f"127.0.0.1:{port}", "--bus", f"demo=socketcand:{host}:{sport}/{channel}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
try:
    wait_http(port)
    a, t = post(port, 3)
    print(f"socketcand, gateway: {a['bytes']} B, download {a['download_ms']} ms, {a['bytes_per_s']} B/s")
    serve.terminate(); serve.wait()
    net = canopen.Network(); net.connect(interface="socketcand", host=host, port=sport, channel=channel)
    node = canopen.RemoteNode(3, "eds/uio1led.eds"); net.add_node(node); node.sdo.RESPONSE_TIMEOUT = 2.0
    node.sdo.download(0x1F51, 1, b"\x00"); node.sdo.download(0x1F51, 1, b"\x03")
    t = time.monotonic()
    with node.sdo.open(0x1F50, 1, "wb", block_transfer=True, size=len(image)) as f:
        f.write(image)
    t = time.monotonic() - t
    assert struct.unpack("<I", node.sdo.upload(0x1F56, 1))[0] == zlib.crc32(image)
    print(f"socketcand, python-canopen {canopen.__version__}: {len(image)} B in {t*1000:.0f} ms, {len(image)/t:.0f} B/s")
    net.disconnect()
finally:
    serve.kill(); vbus.terminate(); vbus.wait()
