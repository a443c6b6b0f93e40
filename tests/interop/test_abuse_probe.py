"""The attack-and-abuse probe of issue 19, re-run against the binary: one
`candeck serve` with tokens, a CiA 309-3 port and a low write rate, then
each class of abuse the issue found, and what must come of it:

- leases: another token (an admin's too) renewing an operator's lease, or
  presenting it, is refused 409 `lease_conflict`; a viewer's renewal over
  the stream is answered `forbidden` and does not keep the axis moving; the
  lease id is not in the audit log viewers read;
- DNS rebinding: a foreign `Host` (with the matching `Origin`) is refused
  on a move and on the WebSocket upgrade;
- listeners: an address other than loopback without tokens is refused at
  start for the HTTP and the CiA 309-3 port, and a share without
  `--share-public`;
- rate limits: REST and CiA 309-5 writes draw on one bucket and get 429;
- stops: STOP ALL and halt are never refused, rate limit spent or not;
- a stream rate of 1e-300 Hz is answered with an error;
- and at the end: the process still runs (0 crashes), its log has no
  `panicked` (0 task panics).
"""

import http.client
import json
import os
import re
import subprocess
import tempfile
import time
import urllib.error
import urllib.request

import pytest
from websockets.sync.client import connect

from conftest import BIN

VIEWER = "v1ewer-0123456789abcdef"
OPERATOR = "0perator-0123456789abcdef"
ADMIN = "adm1n-0123456789abcdef"
TOKENS = f"hmi:viewer:{VIEWER},line-plc:operator:{OPERATOR},engineer:admin:{ADMIN}"
LEASE_MS = 1000


def start(args, tokens=None):
    """`candeck serve ARGS`; the process, its log file, its first line."""
    log = tempfile.NamedTemporaryFile(prefix="candeck-probe-", suffix=".log", delete=False)
    env = dict(os.environ)
    env.pop("CANDECK_TOKENS", None)
    env["CANDECK_LOG"] = "info"
    if tokens:
        env["CANDECK_TOKENS"] = tokens
    proc = subprocess.Popen(
        [BIN, "serve", *args], stdout=subprocess.PIPE, stderr=log, text=True, env=env
    )
    return proc, log.name


def read_log(path):
    with open(path, encoding="utf-8", errors="replace") as f:
        return f.read()


@pytest.fixture
def gateway():
    proc, log = start(
        [
            "--listen", "127.0.0.1:0",
            "--ascii-listen", "127.0.0.1:0",
            "--lease-ms", str(LEASE_MS),
            "--write-rate", "1",
            "--write-burst", "10",
        ],
        tokens=TOKENS,
    )
    line = proc.stdout.readline()
    match = re.search(r"serving http://([0-9.]+:\d+)/", line)
    assert match, f"unexpected first line: {line!r}: {read_log(log)}"
    address = match.group(1)
    yield address, proc, log
    if proc.poll() is None:
        proc.terminate()
        proc.wait(timeout=20)
    os.unlink(log)


def call(address, method, path, token=None, body=None, headers=None):
    """One request; (status, JSON body or None)."""
    all_headers = {"Content-Type": "application/json"}
    if token:
        all_headers["Authorization"] = f"Bearer {token}"
    all_headers.update(headers or {})
    request = urllib.request.Request(
        f"http://{address}{path}",
        data=None if body is None else json.dumps(body).encode(),
        headers=all_headers,
        method=method,
    )
    try:
        with urllib.request.urlopen(request, timeout=20) as response:
            status, text = response.status, response.read()
    except urllib.error.HTTPError as err:
        status, text = err.code, err.read()
    try:
        return status, json.loads(text)
    except ValueError:
        return status, None


AXIS = "/api/v1/buses/demo/nodes/1/axes/1"


def wait_for_axes(address):
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        status, _ = call(address, "GET", "/api/v1/buses/demo/nodes/1/axes", VIEWER)
        if status == 200:
            return
        time.sleep(0.1)
    raise AssertionError("the demo UMC was not identified in 30 s")


def velocity(address):
    status, body = call(address, "GET", AXIS, VIEWER)
    assert status == 200, body
    return body["velocity"]


def stop_all(address, token=VIEWER):
    status, body = call(address, "POST", "/api/v1/stop-all", token, {})
    assert status == 200, f"STOP ALL refused: {status} {body}"
    return body


def test_the_probe_finds_every_case_refused_and_no_crash(gateway):
    address, proc, log = gateway
    wait_for_axes(address)
    refused = {}

    # Leases: an operator's velocity move.
    status, body = call(address, "POST", f"{AXIS}/state", OPERATOR, {"target": "operation_enabled"})
    assert status == 200, body
    status, body = call(address, "POST", f"{AXIS}/move", OPERATOR, {"mode": "velocity", "velocity": 500})
    assert status == 200, body
    lease = body["lease"]["id"]
    status, body = call(address, "POST", f"{AXIS}/lease", ADMIN, {"lease": lease})
    refused["admin renews the operator's lease"] = (status, body["error"]["code"])
    status, body = call(
        address, "POST", f"{AXIS}/move", ADMIN, {"mode": "velocity", "velocity": 900},
        headers={"Candeck-Lease": lease},
    )
    refused["admin presents the operator's lease"] = (status, body["error"]["code"])
    status, body = call(address, "POST", f"{AXIS}/lease", VIEWER, {"lease": lease})
    refused["viewer renews over REST"] = (status, body["error"]["code"])
    # A viewer renews over the stream every 300 ms for 4 lease periods.
    with connect(
        f"ws://{address}/api/v1/stream",
        additional_headers={"Authorization": f"Bearer {VIEWER}"},
        open_timeout=10,
    ) as ws:
        codes = set()
        deadline = time.monotonic() + 4 * LEASE_MS / 1000
        while time.monotonic() < deadline:
            ws.send(json.dumps({"op": "renew", "leases": [lease]}))
            renewed = json.loads(ws.recv(timeout=10))
            assert renewed == {"op": "renewed", "leases": []}, renewed
            error = json.loads(ws.recv(timeout=10))
            codes.add(error["error"]["code"])
            time.sleep(0.3)
        refused["viewer renews over the stream"] = (None, ",".join(sorted(codes)))
        moving = velocity(address)
        # max_rate_hz 1e-300: an error, the session goes on.
        ws.send('{"op":"subscribe","topics":["buses/demo/nodes/1/axes/1"],"max_rate_hz":1e-300}')
        error = json.loads(ws.recv(timeout=10))
        refused["max_rate_hz 1e-300"] = (None, error["error"]["code"])
    assert moving == 0, f"a viewer's renewals kept the axis at velocity {moving}"
    status, events = call(address, "GET", "/api/v1/events?kind=audit&limit=1000", VIEWER)
    assert status == 200
    assert lease not in json.dumps(events), "the lease id in clear in the audit log"

    # DNS rebinding: a foreign Host with the matching Origin.
    port = address.split(":")[1]
    foreign = {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"}
    status, body = call(
        address, "POST", f"{AXIS}/move", OPERATOR, {"mode": "velocity", "velocity": 100}, headers=foreign
    )
    refused["rebinding: move"] = (status, body["error"]["code"])
    host, _ = address.split(":")
    upgrade = http.client.HTTPConnection(host, int(port), timeout=10)
    upgrade.putrequest("GET", "/api/v1/stream", skip_host=True)
    for name, value in {
        **foreign,
        "Authorization": f"Bearer {VIEWER}",
        "Upgrade": "websocket",
        "Connection": "Upgrade",
        "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
        "Sec-WebSocket-Version": "13",
    }.items():
        upgrade.putheader(name, value)
    upgrade.endheaders()
    answer = upgrade.getresponse()
    refused["rebinding: stream"] = (answer.status, "upgraded" if answer.status == 101 else "refused")
    upgrade.close()

    # One write bucket for REST and CiA 309-5: spend it, then both are 429.
    statuses = []
    for i in range(30):
        path = "/api/v1/buses/demo/nodes/1/od/0x6081/0" if i % 2 else "/cia309-5/1.0/1/1/1/w/0x6081/0"
        body = {"value": 1000} if i % 2 else {"value": "1000", "datatype": "u32"}
        status, _ = call(address, "PUT", path, OPERATOR, body)
        statuses.append(status)
    rest_429 = any(s == 429 for i, s in enumerate(statuses) if i % 2)
    cia309_429 = any(s == 429 for i, s in enumerate(statuses) if not i % 2)
    refused["rate limit: REST"] = (429 if rest_429 else None, "rate_limited")
    refused["rate limit: CiA 309-5"] = (429 if cia309_429 else None, "rate_limited")
    # Stops are never refused, the bucket spent or not.
    stop_all(address, OPERATOR)
    stop_all(address, VIEWER)
    status, body = call(address, "POST", f"{AXIS}/halt", OPERATOR, {"halt": True})
    assert status == 200, f"halt refused: {status} {body}"

    assert refused == {
        "admin renews the operator's lease": (409, "lease_conflict"),
        "admin presents the operator's lease": (409, "lease_conflict"),
        "viewer renews over REST": (403, "forbidden"),
        "viewer renews over the stream": (None, "forbidden"),
        "max_rate_hz 1e-300": (None, "value_out_of_range"),
        "rebinding: move": (421, "host_not_allowed"),
        "rebinding: stream": (421, "refused"),
        "rate limit: REST": (429, "rate_limited"),
        "rate limit: CiA 309-5": (429, "rate_limited"),
    }, refused
    assert proc.poll() is None, f"candeck exited: {read_log(log)}"
    text = read_log(log)
    assert "panicked" not in text, text
    assert lease not in text, "the lease id in clear in the gateway's log"


@pytest.mark.parametrize(
    "args, tokens, words",
    [
        (["--listen", "0.0.0.0:0"], None, "without tokens"),
        (["--listen", "127.0.0.1:0", "--ascii-listen", "0.0.0.0:0"], None, "without tokens"),
        (["--listen", "127.0.0.1:0", "--share", "0.0.0.0:0"], TOKENS, "--share-public"),
    ],
)
def test_a_listener_off_loopback_is_refused_at_start(args, tokens, words):
    proc, log = start(args, tokens=tokens)
    try:
        code = proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"candeck serve {args} started: {read_log(log)}")
    text = read_log(log) + proc.stdout.read()
    os.unlink(log)
    assert code != 0, text
    assert words in text, text
    assert "panicked" not in text, text
