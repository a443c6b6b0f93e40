"""node-opcua (a second OPC UA stack no one here wrote; its client in
tests/interop/opcua_node/client.mjs, pinned by that folder's
package-lock.json) against candeck's OPC UA server (issue 34): Basic256Sha256
SignAndEncrypt with a user name and password; the browse tree down to a UMC
axis; identity; a subscription to Axes/1/Position while the axis moves;
SetState and Move by an operator, seen over REST; a viewer's Move refused
(BadUserAccessDenied) and audited; a dictionary write read back over REST;
an unknown client certificate refused until moved to trusted/; a client
killed mid-move losing its lease within the lease period; anonymous refused
on a listener beyond loopback.

Needs Node.js and npm (Debian: apt-get install nodejs npm; scripts/test
installs them and runs `npm ci` in the folder): skipped without them unless
CANDECK_REQUIRE_PEERS is set, where a missing peer is a failure."""

import json
import os
import select
import shutil
import signal
import subprocess
import time

import pytest

from conftest import wait_until
from test_opcua import ADMIN, OPERATOR, VIEWER, Gateway, trust_rejected

PEER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "opcua_node")
NODE, NPM = shutil.which("node"), shutil.which("npm")
AXIS = ["candeck", "Nodes", "demo", "1", "Axes", "1"]
NODE_PATH = ["candeck", "Nodes", "demo", "1"]
# What marks client.mjs's result lines on its stdout.
MARK = "@candeck "

if not (NODE and NPM):
    reason = "node-opcua needs Node.js and npm (Debian: apt-get install nodejs npm)"
    if os.environ.get("CANDECK_REQUIRE_PEERS", "").lower() not in ("", "0", "false", "no"):
        raise RuntimeError(f"CANDECK_REQUIRE_PEERS is set: {reason}")
    pytest.skip(reason, allow_module_level=True)


@pytest.fixture(scope="module", autouse=True)
def node_opcua():
    """node-opcua as package-lock.json pins it (scripts/test installs it
    first; a test run alone installs it here)."""
    if not os.path.isdir(os.path.join(PEER, "node_modules", "node-opcua-client")):
        subprocess.run([NPM, "ci", "--no-audit", "--no-fund", "--quiet"], cwd=PEER, check=True)


RUNNING = []


@pytest.fixture(autouse=True)
def no_client_left_running():
    """A test that failed midway leaves no client holding a lease for the
    next one."""
    yield
    while RUNNING:
        peer = RUNNING.pop()
        if peer.proc.poll() is None:
            peer.kill()


class Peer:
    """One run of client.mjs, its JSON lines read as they come."""

    def __init__(self, gateway, pki, user, steps, mode="SignAndEncrypt"):
        spec = {"url": gateway.url, "pki": pki, "user": list(user) if user else None, "mode": mode, "steps": steps}
        self.proc = subprocess.Popen(
            [NODE, os.path.join(PEER, "client.mjs"), json.dumps(spec)],
            cwd=PEER,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        RUNNING.append(self)

    def line(self, timeout=60):
        """The client's next result (other output, node-opcua's log, is
        skipped)."""
        deadline = time.monotonic() + timeout
        while True:
            ready, _, _ = select.select([self.proc.stdout], [], [], max(0, deadline - time.monotonic()))
            text = self.proc.stdout.readline() if ready else ""
            if not text:
                self.proc.kill()
                raise AssertionError(f"node-opcua said nothing more: {self.proc.stderr.read()[-3000:]}")
            if text.startswith(MARK):
                return json.loads(text[len(MARK) :])

    def lines(self):
        """Every result to the end, the process waited for."""
        out, err = self.proc.communicate(timeout=120)
        return [json.loads(line[len(MARK) :]) for line in out.splitlines() if line.startswith(MARK)], err

    def kill(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()


def untrusted(lines):
    """Whether the server refused the client's certificate: at the secure
    channel, or (async-opcua's way) at CreateSession."""
    return bool(lines) and (
        lines[0].get("connected") is False
        or (len(lines) > 1 and lines[1].get("status") == "BadCertificateUntrusted")
    )


def run(gateway, pki, user, steps, mode="SignAndEncrypt"):
    """The steps' results, in order, after a session opened (the client's
    certificate trusted first if it was refused, so each test may run
    alone)."""
    for attempt in range(2):
        lines, err = Peer(gateway, pki, user, steps, mode).lines()
        if untrusted(lines) and attempt == 0:
            assert trust_rejected(gateway), f"refused with nothing in rejected/: {lines}"
            continue
        break
    assert lines[:2] == [{"connected": True}, {"session": True}], (lines, err[-3000:])
    results = lines[2:]
    assert [r["step"] for r in results] == list(range(len(steps))), (results, err[-3000:])
    return results


@pytest.fixture(scope="module")
def gateway():
    server = Gateway()
    yield server
    server.close()


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """node-opcua's own PKI: it makes its application certificate there."""
    return str(tmp_path_factory.mktemp("node-opcua-pki"))


def velocity(gateway):
    return gateway.request("GET", "/buses/demo/nodes/1/axes/1")["velocity"]


def enable(gateway, pki, user=OPERATOR):
    [state] = run(gateway, pki, user, [{"do": "call", "path": AXIS, "method": "SetState", "args": [["String", "operation_enabled"]]}])
    assert state["ok"], state
    wait_until(
        lambda: gateway.request("GET", "/buses/demo/nodes/1/axes/1")["state"] == "operation_enabled",
        what="the axis enabled",
    )


def move(speed):
    args = [["String", "velocity"], ["Double", speed], ["Double", 0], ["Double", 0], ["Double", 0], ["Boolean", False]]
    return {"do": "call", "path": AXIS, "method": "Move", "args": args}


def test_an_unknown_client_certificate_is_refused_until_moved_to_trusted(gateway, tmp_path):
    pki = str(tmp_path / "pki")
    steps = [{"do": "read", "path": [*NODE_PATH, "Profile"]}]
    refused, err = Peer(gateway, pki, OPERATOR, steps).lines()
    assert untrusted(refused), (refused, err[-3000:])
    moved = trust_rejected(gateway)
    assert moved, "the refused certificate did not land in rejected/"
    [profile] = run(gateway, pki, OPERATOR, steps)
    assert profile == {"step": 0, "ok": True, "value": "umc"}


def test_an_operator_browses_reads_subscribes_and_moves_a_umc_axis(gateway, pki):
    enable(gateway, pki)
    identification = [*NODE_PATH, "Identification"]
    peer = Peer(
        gateway,
        pki,
        OPERATOR,
        [
            {"do": "browse", "path": AXIS},
            {"do": "read", "path": [*identification, "Manufacturer"]},
            {"do": "read", "path": [*identification, "SerialNumber"]},
            {"do": "read", "path": [*NODE_PATH, "Profile"]},
            {"do": "read", "path": [*AXIS, "Position", "EngineeringUnits"]},
            move(300.0),
            {"do": "subscribe", "path": [*AXIS, "Position"], "interval_ms": 50, "for_ms": 2500},
            {"do": "call", "path": AXIS, "method": "Halt"},
        ],
    )
    # enable() had the client's certificate trusted.
    assert peer.line() == {"connected": True}
    assert peer.line() == {"session": True}
    children = peer.line()
    for name in ("State", "Position", "Velocity", "Move", "SetState", "Halt"):
        assert name in children["value"], children
    manufacturer, serial, profile, units = (peer.line() for _ in range(4))
    assert manufacturer["ok"] and manufacturer["value"], manufacturer
    assert serial["ok"] and serial["value"], serial
    assert profile["value"] == "umc", profile
    assert units["ok"] and units["value"]["displayName"], units
    moved = peer.line()
    assert moved == {"step": 5, "ok": True, "value": [True]}, (moved, gateway.request("GET", "/buses/demo/nodes/1/axes/1"), gateway.log()[-4000:])
    # The drive turns: REST sees it while the client subscribes.
    wait_until(lambda: velocity(gateway) > 0, what="the axis turning")
    positions = peer.line()
    assert positions["ok"] and len(set(positions["value"])) > 5, positions
    halted = peer.line()
    assert halted["ok"], halted
    peer.lines()
    wait_until(lambda: velocity(gateway) == 0, what="the axis halted")


def test_the_identification_has_the_devices_hardware_and_software_versions(gateway, pki):
    """HardwareRevision and SoftwareRevision are 0x1009 and 0x100A as the
    device answers them (REST reads the same objects); DeviceRevision is
    0x1018 sub 3."""
    identification = [*NODE_PATH, "Identification"]
    hardware = gateway.request("GET", "/buses/demo/nodes/1/od/0x1009/0")["value"]
    software = gateway.request("GET", "/buses/demo/nodes/1/od/0x100A/0")["value"]
    revision = gateway.request("GET", "/buses/demo/nodes/1/od/0x1018/3")["value"]
    assert hardware and software, (hardware, software)
    deadline = time.monotonic() + 15
    while True:
        read = run(
            gateway,
            pki,
            VIEWER,
            [{"do": "read", "path": [*identification, name]} for name in ("HardwareRevision", "SoftwareRevision", "DeviceRevision")],
        )
        values = [r.get("value") for r in read]
        # Read once the node is identified: empty for a moment at most.
        if all(values) or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    assert values == [hardware, software, f"{revision >> 16}.{revision & 0xFFFF}"], values


def test_a_viewers_move_is_refused_and_audited(gateway, pki):
    refused, position, stop_all = run(
        gateway,
        pki,
        VIEWER,
        [move(100.0), {"do": "read", "path": [*AXIS, "Position"]}, {"do": "call", "path": ["candeck"], "method": "StopAll"}],
    )
    assert refused["ok"] is False and refused["status"] == "BadUserAccessDenied", refused
    # A viewer reads, and may stop everything, as over REST.
    assert position["ok"], position
    assert stop_all["ok"], stop_all
    events = gateway.request("GET", "/events?kind=audit&limit=100")
    rows = [e for e in events if e.get("operation") == "move" and e.get("who") == VIEWER[0]]
    assert rows, events
    assert rows[-1]["channel"] == "opcua"
    assert rows[-1]["error_code"] == "forbidden"


def test_a_dictionary_write_is_read_back_over_rest(gateway, pki):
    heartbeat = [*NODE_PATH, "Dictionary", "0x1017sub0"]
    [before] = run(gateway, pki, OPERATOR, [{"do": "read", "path": heartbeat}])
    assert before["ok"], before
    value = before["value"] + 100
    written, read = run(
        gateway,
        pki,
        OPERATOR,
        [{"do": "write", "path": heartbeat, "type": "UInt16", "value": value}, {"do": "read", "path": heartbeat}],
    )
    assert written == {"step": 0, "ok": True}, written
    assert read["value"] == value, read
    over_rest = gateway.request("GET", "/buses/demo/nodes/1/od/0x1017/0")
    assert over_rest["value"] == value, over_rest
    # A value of the wrong type is refused before the bus.
    [wrong] = run(gateway, pki, OPERATOR, [{"do": "write", "path": heartbeat, "type": "String", "value": "often"}])
    assert wrong["ok"] is False and wrong["status"] == "BadTypeMismatch", wrong
    [restored] = run(
        gateway, pki, OPERATOR, [{"do": "write", "path": heartbeat, "type": "UInt16", "value": before["value"]}]
    )
    assert restored["ok"], restored


def test_a_client_killed_mid_move_loses_its_lease_within_the_lease_period(gateway, pki):
    enable(gateway, pki)
    peer = Peer(gateway, pki, OPERATOR, [move(200.0), {"do": "hold", "path": [*AXIS, "Position"]}])
    assert peer.line() == {"connected": True}
    assert peer.line() == {"session": True}
    assert peer.line() == {"step": 0, "ok": True, "value": [True]}
    assert peer.line() == {"holding": True}
    wait_until(lambda: velocity(gateway) > 0, what="the axis turning")
    # Twice the lease period (1 s): a session that talks keeps its lease.
    time.sleep(2.0)
    assert velocity(gateway) > 0, "halted while the session talked"
    peer.kill()
    killed = time.monotonic()
    # No close, no publish from now on: the lease lapses within the lease
    # period and the keeper's round, not at the session timeout (30 s).
    wait_until(lambda: velocity(gateway) == 0, timeout=20, what="the axis halted after the client vanished")
    assert time.monotonic() - killed < 4, f"halted {time.monotonic() - killed:.1f} s after the kill"
    events = gateway.request("GET", "/events?kind=audit&limit=100")
    assert any(e.get("who") == "gateway" and "lapsed" in e.get("operation", "") for e in events), events


@pytest.fixture(scope="module")
def network_gateway():
    """A gateway whose OPC UA server listens on every address (0.0.0.0),
    reached here over 127.0.0.1."""
    server = Gateway(opcua_listen="0.0.0.0:0")
    yield server
    server.close()


def test_anonymous_is_refused_on_a_listener_beyond_loopback(network_gateway, pki):
    # A user is served there, once the client's certificate is trusted.
    [profile] = run(network_gateway, pki, ADMIN, [{"do": "read", "path": [*NODE_PATH, "Profile"]}])
    assert profile["ok"], profile
    lines, err = Peer(network_gateway, pki, None, []).lines()
    assert lines[0] == {"connected": True}, (lines, err[-3000:])
    assert lines[1]["session"] is False, lines
