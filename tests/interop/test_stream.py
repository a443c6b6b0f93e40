"""`/api/v1/stream` of `candeck serve` spoken to by another WebSocket
implementation than the one candeck is built on: PyPI `websockets` (the
server side is tungstenite, as is the Rust tests' client). The handshake,
text messages both ways, a ping answered with its pong, the close
handshake, and the protocol of docs/websocket.md: a
subscription acknowledged, an injected fault's EMCY and the axis topic's
updates arriving.
"""

import json
import re
import time
import urllib.request

import pytest
from websockets.sync.client import connect

from conftest import Process


@pytest.fixture
def gateway():
    server = Process(["serve", "--listen", "127.0.0.1:0"])
    line = server.first_line()
    match = re.search(r"serving http://([0-9.]+:\d+)/", line)
    assert match, f"unexpected first line: {line!r}"
    yield match.group(1)
    server.stop()


def post(address, path, body):
    request = urllib.request.Request(
        f"http://{address}{path}",
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json"},
        method="POST",
    )
    with urllib.request.urlopen(request, timeout=10) as response:
        return response.status


def wait_for_axes(address):
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(f"http://{address}/api/v1/buses/demo/nodes/1/axes", timeout=5):
                return
        except urllib.error.HTTPError:
            time.sleep(0.1)
    raise AssertionError("the demo UMC was not identified in 30 s")


def test_a_websockets_client_subscribes_and_gets_emcy_and_axis_updates(gateway):
    wait_for_axes(gateway)
    axis = "buses/demo/nodes/1/axes/1"
    with connect(f"ws://{gateway}/api/v1/stream", open_timeout=10) as ws:
        ws.send(json.dumps({"op": "subscribe", "topics": ["emcy", axis], "max_rate_hz": 10}))
        ack = json.loads(ws.recv(timeout=10))
        assert ack == {"op": "subscribed", "topics": ["emcy", axis], "max_rate_hz": 10.0}

        # The server answers a ping with its pong.
        assert ws.ping().wait(5)

        assert post(gateway, "/api/v1/buses/demo/sim/nodes/1/faults", {"kind": "over_temperature"}) == 204
        emcy = None
        axis_updates = []
        deadline = time.monotonic() + 10
        while (emcy is None or len(axis_updates) < 5) and time.monotonic() < deadline:
            message = json.loads(ws.recv(timeout=10))
            assert set(message) == {"topic", "ts", "data"}, message
            if message["topic"] == "emcy":
                emcy = message["data"]
            else:
                assert message["topic"] == axis
                axis_updates.append(message["data"])
        assert emcy is not None, "no EMCY within 10 s"
        assert (emcy["bus"], emcy["node"], emcy["code"]) == ("demo", 1, "0x4310")
        assert emcy["text"] == "Excess temperature drive"
        assert len(axis_updates) >= 5
        assert all(update["axis"] == 1 and "statusword" in update for update in axis_updates)

        # A bad request is answered, and the connection stays usable.
        ws.send("not json")
        error = json.loads(ws.recv(timeout=10))
        while error.get("op") != "error":
            error = json.loads(ws.recv(timeout=10))
        assert error["error"]["code"] == "invalid_request"
        ws.send(json.dumps({"op": "unsubscribe", "topics": [axis, "emcy"]}))
        reply = json.loads(ws.recv(timeout=10))
        while reply.get("op") != "unsubscribed":
            reply = json.loads(ws.recv(timeout=10))
        assert reply["topics"] == [axis, "emcy"]
    # Leaving the block closed the connection with the close handshake.
    assert ws.close_code == 1000
