"""candeck as a Sparkplug B edge node, against a real broker (Debian's
mosquitto, started here on a free loopback port) and a Sparkplug host
application written with paho-mqtt and the protobuf module generated from
the same sparkplug_b.proto (grpcio-tools' protoc, into a temporary folder).

The host is the primary host (`sparkplug_primary_host`): it publishes its
STATE, so the edge node publishes only while the host listens.
"""

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

import pytest

from conftest import BIN, Process, wait_until

mqtt = pytest.importorskip("paho.mqtt.client")
pytest.importorskip("google.protobuf")
grpc_tools = pytest.importorskip("grpc_tools.protoc")

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
if not os.path.exists(MOSQUITTO):
    pytest.skip("mosquitto is not installed (Debian: apt-get install mosquitto)", allow_module_level=True)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PROTO_DIR = os.path.join(ROOT, "src", "sparkplug")
GROUP, EDGE, HOST_ID = "plant", "line1", "scada"


def _proto_module():
    out = tempfile.mkdtemp(prefix="candeck-spb-")
    rc = grpc_tools.main(["protoc", f"-I{PROTO_DIR}", f"--python_out={out}", "sparkplug_b.proto"])
    assert rc == 0, "protoc (grpcio-tools) failed on sparkplug_b.proto"
    sys.path.insert(0, out)
    import sparkplug_b_pb2  # noqa: E402

    return sparkplug_b_pb2


pb = _proto_module()
DT = pb.DataType


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Broker:
    """mosquitto on a loopback port, stopped and started again at will."""

    def __init__(self):
        self.port = free_port()
        self.dir = tempfile.mkdtemp(prefix="candeck-mosquitto-")
        self.conf = os.path.join(self.dir, "mosquitto.conf")
        with open(self.conf, "w") as f:
            f.write(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
        self.proc = None
        self.start()

    def start(self):
        self.proc = subprocess.Popen([MOSQUITTO, "-c", self.conf], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError:
                time.sleep(0.05)
        raise AssertionError("mosquitto did not start")

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=10)

    def close(self):
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)


class Host:
    """A Sparkplug primary host: STATE online (retained, its will offline),
    every message of the group recorded with the metrics' names resolved
    from the births' aliases."""

    def __init__(self, port):
        self.messages = []
        self.cond = threading.Condition()
        self.aliases = {}
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"host-{HOST_ID}")
        state = f"spBv1.0/STATE/{HOST_ID}"
        # Sparkplug 3.0: the will's timestamp is the online STATE's (an
        # offline older than the last online is stale, and ignored).
        self.born = int(time.time() * 1000)
        self.client.will_set(state, json.dumps({"online": False, "timestamp": self.born}), qos=1, retain=True)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.reconnect_delay_set(min_delay=1, max_delay=1)
        self.client.connect("127.0.0.1", port, keepalive=5)
        self.client.loop_start()

    def _on_connect(self, client, userdata, flags, reason, properties):
        client.subscribe(f"spBv1.0/{GROUP}/#", qos=0)
        client.publish(
            f"spBv1.0/STATE/{HOST_ID}",
            json.dumps({"online": True, "timestamp": self.born}),
            qos=1,
            retain=True,
        )

    def _on_message(self, client, userdata, msg):
        payload = pb.Payload()
        payload.ParseFromString(msg.payload)
        parts = msg.topic.split("/")
        kind = parts[2]
        device = parts[4] if len(parts) > 4 else None
        metrics = []
        for m in payload.metrics:
            if kind in ("NBIRTH", "DBIRTH") and m.HasField("alias"):
                self.aliases[(device, m.alias)] = m.name
            name = m.name if m.name else self.aliases.get((device, m.alias))
            which = m.WhichOneof("value")
            metrics.append(
                {
                    "name": name,
                    "datatype": m.datatype,
                    "value": getattr(m, which) if which else None,
                    "historical": m.is_historical,
                    "timestamp": m.timestamp,
                }
            )
        with self.cond:
            self.messages.append(
                {
                    "kind": kind,
                    "device": device,
                    "seq": payload.seq if payload.HasField("seq") else None,
                    "metrics": metrics,
                }
            )
            self.cond.notify_all()

    def wait_for(self, predicate, timeout=30, start=0):
        """The first message from index `start` on that satisfies `predicate`."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for i, message in enumerate(self.messages[start:], start):
                    if predicate(message):
                        return i, message
                left = deadline - time.monotonic()
                if left <= 0:
                    kinds = [(m["kind"], m["device"]) for m in self.messages]
                    raise AssertionError(f"no such message within {timeout} s; got {kinds}")
                self.cond.wait(left)

    def send_dcmd(self, device, metrics):
        payload = pb.Payload()
        payload.timestamp = int(time.time() * 1000)
        for name, datatype, field, value in metrics:
            m = payload.metrics.add()
            m.name = name
            m.datatype = datatype
            setattr(m, field, value)
        self.client.publish(f"spBv1.0/{GROUP}/DCMD/{EDGE}/{device}", payload.SerializeToString(), qos=0)

    def close(self):
        self.client.loop_stop()
        self.client.disconnect()


def metric(message, name):
    for m in message["metrics"]:
        if m["name"] == name:
            return m
    return None


class Gateway(Process):
    def __init__(self, broker_port, extra=(), settings=""):
        self.dir = tempfile.mkdtemp(prefix="candeck-spb-gw-")
        config = os.path.join(self.dir, "candeck.toml")
        with open(config, "w") as f:
            f.write(
                f'mqtt_url = "mqtt://127.0.0.1:{broker_port}"\n'
                f'sparkplug_group_id = "{GROUP}"\n'
                f'sparkplug_edge_node_id = "{EDGE}"\n'
                f'sparkplug_primary_host = "{HOST_ID}"\n'
                'sparkplug_role = "operator"\n'
                # This broker takes anonymous clients: commands from it only
                # with the override (test_sparkplug_acl.py runs the broker of
                # the compose demo, with its passwords and ACL).
                'sparkplug_insecure = true\n'
                # The demo drives send their TPDOs on SYNC.
                + (settings or "sync_period_ms = 50\n")
            )
        super().__init__(["serve", "--listen", "127.0.0.1:0", "--config", config, *extra])
        line = self.first_line()
        self.base = "http://" + line.split("http://")[1].split("/")[0] + "/api/v1"

    def request(self, method, path, body=None):
        data = json.dumps(body).encode() if body is not None else None
        req = urllib.request.Request(self.base + path, data=data, method=method)
        req.add_header("content-type", "application/json")
        with urllib.request.urlopen(req, timeout=30) as resp:
            text = resp.read()
            return json.loads(text) if text else None

    def close(self):
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture
def broker():
    b = Broker()
    yield b
    b.close()


@pytest.fixture
def host(broker):
    h = Host(broker.port)
    yield h
    h.close()


@pytest.fixture
def gateway(broker, host):
    g = Gateway(broker.port)
    yield g
    g.close()


def started(gateway, host):
    """The demo nodes started: the index of the first message of node 1
    with its statusword's value (a DBIRTH or, its mapping born typed and
    null, a DDATA), and the DBIRTH of node 1 that names its TPDO values."""
    host.wait_for(lambda m: m["kind"] == "DBIRTH" and m["device"] == "demo-1")
    gateway.request("POST", "/buses/demo/nmt", {"command": "start"})
    at, _ = host.wait_for(
        lambda m: m["kind"] in ("DBIRTH", "DDATA")
        and m["device"] == "demo-1"
        and (metric(m, "TPDO/a1_Statusword") or {}).get("value") is not None
    )
    with host.cond:
        births = [
            m
            for m in host.messages[: at + 1]
            if m["kind"] == "DBIRTH" and m["device"] == "demo-1" and metric(m, "TPDO/a1_Statusword") is not None
        ]
    return at, births[-1]


def test_births_carry_typed_metrics_and_a_tpdo_change_comes_as_ddata(gateway, host):
    at, nbirth = host.wait_for(lambda m: m["kind"] == "NBIRTH")
    assert nbirth["seq"] == 0
    # One connection: no will of a connection the edge node made twice.
    assert not any(m["kind"] == "NDEATH" for m in host.messages[:at])
    assert metric(nbirth, "bdSeq")["datatype"] == DT.Int64
    assert metric(nbirth, "Node Control/Rebirth")["value"] is False
    assert metric(nbirth, "Buses/demo/State")["value"] == "up"
    # The network manager's machine state (the demo's nodes are booted).
    assert metric(nbirth, "Machine State")["value"] in ("booting", "ready")
    for device in ("demo-1", "demo-2", "demo-3"):
        _, birth = host.wait_for(lambda m, d=device: m["kind"] == "DBIRTH" and m["device"] == d)
        assert metric(birth, "Online") == metric(birth, "Online") | {"datatype": DT.Boolean, "value": True}
        assert metric(birth, "Identity/Vendor ID")["datatype"] == DT.UInt32
        assert metric(birth, "NMT State")["datatype"] == DT.String
    at, birth = started(gateway, host)
    assert metric(birth, "TPDO/a1_Statusword")["datatype"] == DT.UInt16
    status = metric(host.messages[at], "TPDO/a1_Statusword")
    gateway.request("POST", "/buses/demo/nodes/1/axes/1/state", {"target": "operation_enabled"})
    _, data = host.wait_for(
        lambda m: m["kind"] == "DDATA"
        and m["device"] == "demo-1"
        and metric(m, "TPDO/a1_Statusword") is not None
        # CiA 402: operation enabled is xxxx xxxx x01x 0111 (the walk
        # there may show the states between first).
        and metric(m, "TPDO/a1_Statusword")["value"] & 0x6F == 0x27,
        start=at,
    )
    assert status["value"] & 0x6F != 0x27
    changed = metric(data, "TPDO/a1_Statusword")
    # Typed by the birth: Sparkplug 3.0 says a DDATA SHOULD NOT repeat it.
    assert changed["datatype"] == 0
    assert changed["historical"] is False
    # The axis's own metrics follow it.
    host.wait_for(
        lambda m: m["device"] == "demo-1"
        and m["kind"] in ("DBIRTH", "DDATA")
        and (metric(m, "Axis 1/State") or {}).get("value") == "operation_enabled",
        start=at,
    )
    # The LED controller's segments, as JSON text.
    _, leds = host.wait_for(
        lambda m: m["device"] == "demo-3" and m["kind"] in ("DBIRTH", "DDATA") and metric(m, "Segments")
    )
    assert metric(leds, "Segments")["datatype"] == DT.String
    json.loads(metric(leds, "Segments")["value"])


def machine_node(gateway, node):
    machine = gateway.request("GET", "/buses/demo/machine")
    return next(n for n in machine["nodes"] if n["id"] == node)


def test_a_dcmd_write_of_0x1017_reaches_the_device_and_is_audited(gateway, host):
    host.wait_for(lambda m: m["kind"] == "DBIRTH" and m["device"] == "demo-1")
    deadline = time.monotonic() + 15
    while machine_node(gateway, 1)["state"] != "ready" and time.monotonic() < deadline:
        time.sleep(0.2)
    before = machine_node(gateway, 1)
    assert before["state"] == "ready", before
    # Twice the period the network manager set (500 ms), past its old
    # supervision timeout (750 ms).
    host.send_dcmd("demo-1", [("OD/0x1017:0", DT.UInt16, "int_value", 1000)])
    deadline = time.monotonic() + 15
    while True:
        value = gateway.request("GET", "/buses/demo/nodes/1/od/0x1017/0")["value"]
        if value == 1000 or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert value == 1000
    # Long enough for the old supervision to lose the node and boot it
    # again, writing its 500 back: the written value stays, and the
    # manager supervises the node with it.
    time.sleep(2.5)
    assert gateway.request("GET", "/buses/demo/nodes/1/od/0x1017/0")["value"] == 1000
    after = machine_node(gateway, 1)
    assert after["state"] == "ready", after
    assert after["heartbeat_ms"] == 1000, after
    assert after["boots"] == before["boots"], after
    events = gateway.request("GET", "/events?kind=audit&limit=50")
    writes = [e for e in events if e.get("operation") == "write object" and e.get("item") == "0x1017:0"]
    assert writes, events
    assert writes[-1]["who"].startswith("mqtt:")
    assert writes[-1]["method"] == "DCMD"
    # A Sparkplug row says what was done: its channel and outcome, not an
    # HTTP status it never had.
    assert writes[-1]["channel"] == "sparkplug", writes[-1]
    assert writes[-1]["outcome"] == "ok", writes[-1]
    assert "status" not in writes[-1], writes[-1]


def test_an_unplugged_node_gives_ddeath(gateway, host):
    host.wait_for(lambda m: m["kind"] == "DBIRTH" and m["device"] == "demo-2")
    at = len(host.messages)
    # Node 2 (the JMC) sends a heartbeat: its silence is noticed.
    gateway.request("DELETE", "/buses/demo/sim/nodes/2")
    _, death = host.wait_for(lambda m: m["kind"] == "DDEATH" and m["device"] == "demo-2", start=at)
    assert death["seq"] is not None


def test_killing_the_gateway_gives_its_will_ndeath_with_the_births_bdseq(gateway, host):
    _, nbirth = host.wait_for(lambda m: m["kind"] == "NBIRTH")
    bd_seq = metric(nbirth, "bdSeq")["value"]
    at = len(host.messages)
    gateway.proc.send_signal(signal.SIGKILL)
    gateway.proc.wait()
    _, death = host.wait_for(lambda m: m["kind"] == "NDEATH", start=at, timeout=30)
    assert metric(death, "bdSeq")["value"] == bd_seq
    assert death["seq"] is None


def test_a_clean_stop_publishes_ndeath_with_the_births_bdseq(gateway, host):
    _, nbirth = host.wait_for(lambda m: m["kind"] == "NBIRTH")
    at = len(host.messages)
    gateway.proc.send_signal(signal.SIGTERM)
    gateway.proc.wait(timeout=30)
    _, death = host.wait_for(lambda m: m["kind"] == "NDEATH", start=at, timeout=10)
    assert metric(death, "bdSeq")["value"] == metric(nbirth, "bdSeq")["value"]


def offline(gateway):
    text = urllib.request.urlopen(gateway.base.replace("/api/v1", "") + "/metrics", timeout=10).read().decode()
    for line in text.splitlines():
        if line.startswith("candeck_sparkplug_connected "):
            return line.split()[1] == "0"
    raise AssertionError("no candeck_sparkplug_connected in /metrics")


def test_a_broker_outage_is_bridged_by_store_and_forward(broker, gateway, host):
    at, _ = started(gateway, host)
    # Enabled first: from then on each toggle is one transition of the CiA
    # 402 state machine (disable operation, enable operation), with no
    # state between.
    gateway.request("POST", "/buses/demo/nodes/1/axes/1/state", {"target": "operation_enabled"})
    host.wait_for(
        lambda m: m["kind"] == "DDATA"
        and m["device"] == "demo-1"
        and ((metric(m, "TPDO/a1_Statusword") or {}).get("value") or 0) & 0x6F == 0x27,
        start=at,
    )
    broker.stop()
    deadline = time.monotonic() + 15
    while not offline(gateway):
        assert time.monotonic() < deadline, "the gateway did not notice the broker went"
        time.sleep(0.1)
    # 10 s of TPDO changes while the broker is away: the axis enabled and
    # disabled in turn, each state held long enough for a SYNC TPDO.
    targets = []
    outage_end = time.monotonic() + 10
    target = "switched_on"
    while time.monotonic() < outage_end:
        gateway.request("POST", "/buses/demo/nodes/1/axes/1/state", {"target": target})
        targets.append(target)
        target = "switched_on" if target == "operation_enabled" else "operation_enabled"
        time.sleep(0.5)
    assert len(targets) >= 10
    first_after = len(host.messages)
    broker.start()
    nbirth_at, nbirth = host.wait_for(lambda m: m["kind"] == "NBIRTH", start=first_after, timeout=30)

    # Every state walked to while away, in order: operation enabled and
    # switched on (xxxx xxxx x01x 0011) in turn.
    def state(word):
        if word & 0x6F == 0x27:
            return "operation_enabled"
        if word & 0x6F == 0x23:
            return "switched_on"
        return None

    def replayed():
        with host.cond:
            session = list(host.messages[nbirth_at:])
        historical = [
            metric(m, "TPDO/a1_Statusword")
            for m in session
            if m["kind"] == "DDATA"
            and m["device"] == "demo-1"
            and metric(m, "TPDO/a1_Statusword") is not None
            and metric(m, "TPDO/a1_Statusword")["historical"]
        ]
        seen = []
        for m in historical:
            s = state(m["value"])
            if s and (not seen or seen[-1] != s):
                seen.append(s)
        return session, historical, seen

    # The queue follows the births at once; wait for all of it.
    deadline = time.monotonic() + 30
    while True:
        session, historical, seen = replayed()
        if len(seen) >= len(targets) or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert seen == targets, (seen, targets)
    seqs = [m["seq"] for m in session if m["seq"] is not None]
    assert seqs[0] == 0
    assert all(b == (a + 1) % 256 for a, b in zip(seqs, seqs[1:])), seqs
    stamps = [m["timestamp"] for m in historical]
    assert stamps == sorted(stamps)


def turning_axis_position(gateway, host):
    """The demo nodes started and node 1's axis 1 turning; the name of the
    TPDO metric of its position actual value."""
    _, birth = started(gateway, host)
    names = [m["name"] for m in birth["metrics"] if m["name"].startswith("TPDO/")]
    position = [n for n in names if "position_actual" in n.lower()]
    assert position, names
    base = "/buses/demo/nodes/1/axes/1"
    gateway.request("POST", base + "/state", {"target": "operation_enabled"})
    gateway.request("POST", base + "/move", {"mode": "velocity", "velocity": 2000})
    wait_until(lambda: axis_velocity(gateway) > 0, what="the axis turning")
    return position[0]


def test_every_tpdo_change_comes_however_many_come_within_one_publish_tick(broker, host):
    # A SYNC every 20 ms and a publish pass every 500 ms: a moving axis's
    # position changes 25 times between two passes, and each change is a
    # metric of its own, in order, all of a pass in one DDATA of the device
    # (one DDATA per device per publish tick).
    gateway = Gateway(
        broker.port,
        ["--lease-ms", "60000"],
        settings="sync_period_ms = 20\nsparkplug_publish_tick_ms = 500\n",
    )
    try:
        position = turning_axis_position(gateway, host)
        from_here = len(host.messages)
        time.sleep(3)
        with host.cond:
            session = list(host.messages[from_here:])
        data = [m for m in session if m["kind"] == "DDATA" and m["device"] == "demo-1"]
        # 3 s of passes every 500 ms: 6, and one more for a pass that
        # straddles the window's edges.
        assert len(data) <= 8, [len(m["metrics"]) for m in data]
        values = []
        for message in data:
            values += [m for m in message["metrics"] if m["name"] == position]
        # 3 s of 50 SYNC/s is 150 positions (a pass every 500 ms would give
        # 6 with only the newest value of each).
        assert len(values) >= 100, len(values)
        stamps = [m["timestamp"] for m in values]
        assert stamps == sorted(stamps)
        positions = [m["value"] for m in values]
        assert len(set(positions)) == len(positions), "a position reported twice"
        assert positions == sorted(positions), positions
        seqs = [m["seq"] for m in session if m["seq"] is not None]
        assert all(b == (a + 1) % 256 for a, b in zip(seqs, seqs[1:])), seqs
    finally:
        gateway.close()


def test_no_change_is_lost_when_the_edge_node_is_born_again_after_an_outage(broker, host):
    # A publish pass every second: when the broker comes back, up to a
    # second of changes waits to be taken. They go out with the store and
    # forward queue, not lost with the session the new births end.
    gateway = Gateway(
        broker.port,
        ["--lease-ms", "60000"],
        settings="sync_period_ms = 20\nsparkplug_publish_tick_ms = 1000\n",
    )
    try:
        position = turning_axis_position(gateway, host)
        time.sleep(1.5)
        broker.stop()
        wait_until(lambda: offline(gateway), what="the gateway noticing the broker went")
        time.sleep(2)
        first_after = len(host.messages)
        broker.start()
        nbirth_at, _ = host.wait_for(lambda m: m["kind"] == "NBIRTH", start=first_after, timeout=30)
        time.sleep(3)
        with host.cond:
            session = list(host.messages[nbirth_at:])
        values = [
            m
            for message in session
            if message["device"] == "demo-1" and message["kind"] in ("DBIRTH", "DDATA")
            for m in message["metrics"]
            if m["name"] == position and m["value"] is not None
        ]
        historical = [m for m in values if m["historical"]]
        assert historical, "nothing was kept while the broker was away"
        stamps = sorted({m["timestamp"] for m in values})
        # From the first value kept while away to the end: a position every
        # SYNC (20 ms), no hole where the changes waiting at the rebirth were.
        stamps = [t for t in stamps if t >= historical[0]["timestamp"]]
        gaps = [b - a for a, b in zip(stamps, stamps[1:])]
        assert len(stamps) > 150, len(stamps)
        assert max(gaps) <= 200, max(gaps)
    finally:
        gateway.close()


def axis_velocity(gateway):
    return gateway.request("GET", "/buses/demo/nodes/1/axes/1")["velocity"]


ENABLE = ("Axis 1/State", DT.String, "string_value", "operation_enabled")
VELOCITY = ("Axis 1/Move", DT.String, "string_value", json.dumps({"mode": "velocity", "velocity": 100}))
RENEW = ("Axis 1/Lease", DT.Boolean, "boolean_value", True)
# The host's lease id, of its choosing: MQTT carries no sender identity, so
# the id is what the gateway knows the lease's holder by.
LEASE_ID = ("Axis 1/Lease Id", DT.String, "string_value", secrets.token_hex(16))


def names(event, operation):
    """Whether an audit row names `operation`: a command message is one row,
    its operations named together (`drive state change, move`)."""
    return operation in (event.get("operation") or "").split(", ")


def test_a_dcmd_move_runs_while_its_lease_is_renewed_by_metric_and_stops_when_not(broker, host):
    gateway = Gateway(broker.port, ["--lease-ms", "1000"])
    try:
        _, nbirth = host.wait_for(lambda m: m["kind"] == "NBIRTH")
        assert metric(nbirth, "Properties/Lease Period")["value"] == 1000
        host.wait_for(lambda m: m["kind"] == "DBIRTH" and m["device"] == "demo-1")
        # Without the lease promise, a velocity move is refused.
        host.send_dcmd("demo-1", [ENABLE, VELOCITY])

        def refused():
            events = gateway.request("GET", "/events?kind=audit&limit=50")
            return [e for e in events if names(e, "move") and e.get("status") != 200]

        wait_until(lambda: refused(), what="the refused move in the audit log")
        assert refused()[-1]["who"] == "mqtt:candeck-plant-line1"
        assert refused()[-1]["axis"] == 1
        assert axis_velocity(gateway) == 0
        # With it, the axis turns, as long as the host renews.
        host.send_dcmd("demo-1", [VELOCITY, RENEW, LEASE_ID])
        wait_until(lambda: axis_velocity(gateway) > 0, what="the axis turning")
        # Another client of the broker, without the host's lease id, is
        # refused the axis (it would reverse it).
        reverse = ("Axis 1/Move", DT.String, "string_value", json.dumps({"mode": "velocity", "velocity": -300}))
        other_id = ("Axis 1/Lease Id", DT.String, "string_value", secrets.token_hex(16))
        host.send_dcmd("demo-1", [reverse, RENEW, other_id])

        def conflicts():
            events = gateway.request("GET", "/events?kind=audit&limit=50")
            return [e for e in events if names(e, "move") and e.get("error_code") == "lease_conflict"]

        wait_until(lambda: conflicts(), what="the other client's move refused in the audit log")
        until = time.monotonic() + 3
        while time.monotonic() < until:
            host.send_dcmd("demo-1", [RENEW, LEASE_ID])
            time.sleep(0.25)
        assert axis_velocity(gateway) > 0, "halted or reversed while the host renewed"
        # The host stops renewing: the gateway halts the axis.
        wait_until(lambda: axis_velocity(gateway) == 0, what="the axis halted after its lease lapsed")

        def lapses():
            events = gateway.request("GET", "/events?kind=audit&limit=100")
            return [e for e in events if e.get("who") == "gateway" and "lapsed" in e.get("operation", "")]

        # The lapse is audited once its stop is done, which may be a moment
        # after the velocity reads 0.
        wait_until(lambda: lapses(), what="the lapse in the audit log")
        assert "mqtt:candeck-plant-line1" in lapses()[-1]["item"], lapses()
        events = gateway.request("GET", "/events?kind=audit&limit=100")
        renewals = [e for e in events if names(e, "renew motion lease")]
        assert renewals and renewals[0]["method"] == "DCMD"
    finally:
        gateway.close()


def test_a_broker_outage_does_not_leave_a_dcmd_move_running(broker, host):
    # A lease of a minute: only the lost connection can stop it this soon.
    gateway = Gateway(broker.port, ["--lease-ms", "60000"])
    try:
        host.wait_for(lambda m: m["kind"] == "DBIRTH" and m["device"] == "demo-1")
        host.send_dcmd("demo-1", [ENABLE, VELOCITY, RENEW, LEASE_ID])
        wait_until(lambda: axis_velocity(gateway) > 0, what="the axis turning")
        broker.stop()
        wait_until(lambda: axis_velocity(gateway) == 0, timeout=20, what="the axis stopped after the broker went away")
        events = gateway.request("GET", "/events?kind=audit&limit=100")
        assert any(e.get("who") == "gateway" and "lapsed" in e.get("operation", "") for e in events), events
    finally:
        gateway.close()


# --- mqtts:// ---------------------------------------------------------------

OPENSSL = shutil.which("openssl")
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"


def openssl(*args, cwd):
    subprocess.run([OPENSSL, *args], cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def make_pki(folder):
    """A CA, a server certificate for 127.0.0.1 and a client certificate,
    made now (EC P-256), in `folder`."""
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    openssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "2", "-subj", "/CN=candeck test CA", cwd=folder)
    with open(os.path.join(folder, "server.ext"), "w") as f:
        f.write("subjectAltName=IP:127.0.0.1\nbasicConstraints=CA:FALSE\n")
    with open(os.path.join(folder, "client.ext"), "w") as f:
        f.write("basicConstraints=CA:FALSE\nextendedKeyUsage=clientAuth\n")
    for name, cn in (("server", "127.0.0.1"), ("client", "line-tls")):
        openssl("req", *ec, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={cn}", cwd=folder)
        openssl(
            "x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", f"{name}.pem", "-days", "2", "-extfile", f"{name}.ext", cwd=folder,
        )
    # A CA file of another CA: the broker's certificate does not check.
    openssl("req", "-x509", *ec, "-keyout", "other.key", "-out", "other.pem", "-days", "2", "-subj", "/CN=other CA", cwd=folder)


class TlsBroker:
    """mosquitto with two TLS listeners on loopback (one that wants a client
    certificate), users by password only."""

    def __init__(self):
        self.dir = tempfile.mkdtemp(prefix="candeck-mosquitto-tls-")
        make_pki(self.dir)
        self.pki = lambda name: os.path.join(self.dir, name)
        subprocess.run([MOSQUITTO_PASSWD, "-b", "-c", self.pki("passwd"), "line", "s3cret"], check=True)
        subprocess.run([MOSQUITTO_PASSWD, "-b", self.pki("passwd"), "scada", "h0st"], check=True)
        # mosquitto started as root reads its files as the user mosquitto.
        os.chmod(self.dir, 0o755)
        for name in os.listdir(self.dir):
            os.chmod(self.pki(name), 0o644)
        self.port, self.cert_port = free_port(), free_port()
        tls = f"cafile {self.pki('ca.pem')}\ncertfile {self.pki('server.pem')}\nkeyfile {self.pki('server.key')}\n"
        with open(self.pki("mosquitto.conf"), "w") as f:
            f.write(
                f"allow_anonymous false\npassword_file {self.pki('passwd')}\npersistence false\n"
                f"listener {self.port} 127.0.0.1\n{tls}require_certificate false\n"
                f"listener {self.cert_port} 127.0.0.1\n{tls}require_certificate true\n"
            )
        self.proc = subprocess.Popen([MOSQUITTO, "-c", self.pki("mosquitto.conf")], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.cert_port), timeout=0.2).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "mosquitto (TLS) did not start"
                time.sleep(0.05)

    def close(self):
        self.proc.terminate()
        self.proc.wait(timeout=10)
        shutil.rmtree(self.dir, ignore_errors=True)


class TlsWatcher:
    """A plain subscriber over TLS (user scada): every NBIRTH's edge node."""

    def __init__(self, broker):
        self.births = []
        self.cond = threading.Condition()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="tls-watcher")
        self.client.tls_set(ca_certs=broker.pki("ca.pem"))
        self.client.username_pw_set("scada", "h0st")
        self.client.on_connect = lambda c, u, f, r, p: c.subscribe(f"spBv1.0/{GROUP}/NBIRTH/+")
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", broker.port, keepalive=5)
        self.client.loop_start()

    def _on_message(self, client, userdata, msg):
        with self.cond:
            self.births.append(msg.topic.split("/")[3])
            self.cond.notify_all()

    def born(self, edge, timeout):
        deadline = time.monotonic() + timeout
        with self.cond:
            while edge not in self.births:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(left)
            return True

    def close(self):
        self.client.loop_stop()
        self.client.disconnect()


def tls_gateway(folder, edge, port, ca, cert=None, password="s3cret"):
    config = os.path.join(folder, f"{edge}.toml")
    with open(config, "w") as f:
        f.write(
            f'mqtt_url = "mqtts://127.0.0.1:{port}"\n'
            f'mqtt_ca_file = "{ca}"\n'
            'mqtt_username = "line"\n'
            f'mqtt_password = "{password}"\n'
            f'sparkplug_group_id = "{GROUP}"\n'
            f'sparkplug_edge_node_id = "{edge}"\n'
        )
        if cert:
            f.write(f'mqtt_client_cert = "{cert[0]}"\nmqtt_client_key = "{cert[1]}"\n')
    return Process(["serve", "--listen", "127.0.0.1:0", "--config", config])


@pytest.fixture
def tls_broker():
    if not OPENSSL or not os.path.exists(MOSQUITTO_PASSWD):
        pytest.skip("openssl and mosquitto_passwd are needed for the TLS broker")
    b = TlsBroker()
    yield b
    b.close()


def test_mqtts_with_and_without_a_client_certificate_and_a_password(tls_broker):
    watcher = TlsWatcher(tls_broker)
    ca = tls_broker.pki("ca.pem")
    client = (tls_broker.pki("client.pem"), tls_broker.pki("client.key"))
    good = [
        # Server certificate checked, user and password, no client certificate.
        tls_gateway(tls_broker.dir, "tls-plain", tls_broker.port, ca),
        # The listener that wants a client certificate, given one.
        tls_gateway(tls_broker.dir, "tls-cert", tls_broker.cert_port, ca, cert=client),
    ]
    bad = [
        # No client certificate where one is wanted.
        tls_gateway(tls_broker.dir, "tls-nocert", tls_broker.cert_port, ca),
        # A wrong password.
        tls_gateway(tls_broker.dir, "tls-badpw", tls_broker.port, ca, password="wrong"),
        # A CA that did not sign the broker's certificate.
        tls_gateway(tls_broker.dir, "tls-otherca", tls_broker.port, tls_broker.pki("other.pem")),
    ]
    try:
        for gateway in good + bad:
            gateway.first_line()
        for edge in ("tls-plain", "tls-cert"):
            assert watcher.born(edge, timeout=30), f"no NBIRTH of {edge}: {watcher.births}"
        # The refused ones had time to try (they retry every second).
        time.sleep(3)
        for edge in ("tls-nocert", "tls-badpw", "tls-otherca"):
            assert edge not in watcher.births, watcher.births
        for gateway in bad:
            assert gateway.proc.poll() is None, gateway.log()
        assert "sparkplug: broker 127.0.0.1" in bad[2].log(), bad[2].log()
    finally:
        watcher.close()
        for gateway in good + bad:
            gateway.stop()


@pytest.mark.parametrize("ca", ["missing", "not a certificate"])
def test_a_missing_or_bad_ca_file_is_a_clear_startup_error(tmp_path, ca):
    path = tmp_path / "ca.pem"
    if ca != "missing":
        path.write_text("this is not PEM\n")
    config = tmp_path / "candeck.toml"
    config.write_text(
        'mqtt_url = "mqtts://127.0.0.1:8883"\n'
        f'mqtt_ca_file = "{path}"\n'
        f'sparkplug_group_id = "{GROUP}"\n'
    )
    proc = subprocess.run([BIN, "serve", "--listen", "127.0.0.1:0", "--config", str(config)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("candeck: error:")]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("candeck: error: sparkplug: mqtt_ca_file"), proc.stderr
    assert "panicked" not in proc.stderr
    assert str(path) in lines[0], proc.stderr
