"""candeck's Sparkplug B edge node on the compose demo's secured broker
(deploy/mosquitto/: its password file and ACL, on a free loopback port),
with hosts written with paho-mqtt and the official protobuf module
(issue 33): only the scada account commands, STATE per Sparkplug 3.0,
commands in the spec's form (alias alone, no datatype), a 20 MB DCMD that
leaves the session up, and births that say what a host may write.
"""

import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
import urllib.request

import pytest

from conftest import Process
from test_sparkplug import MOSQUITTO, ROOT, free_port, pb, wait_until

mqtt = pytest.importorskip("paho.mqtt.client")

GROUP, EDGE, HOST_ID = "plant", "line-a", "scada"
DEPLOY = os.path.join(ROOT, "deploy", "mosquitto")
PASSWORDS = {"line-a": "line-a-demo", "scada": "scada-demo", "viewer": "viewer-demo"}


class SecuredBroker:
    """mosquitto with the compose demo's password file and ACL."""

    def __init__(self):
        self.port = free_port()
        self.dir = tempfile.mkdtemp(prefix="candeck-mosquitto-acl-")
        for name in ("passwd", "acl"):
            shutil.copy(os.path.join(DEPLOY, name), os.path.join(self.dir, name))
        # mosquitto started as root reads its files as the user mosquitto.
        os.chmod(self.dir, 0o755)
        for name in os.listdir(self.dir):
            os.chmod(os.path.join(self.dir, name), 0o644)
        conf = os.path.join(self.dir, "mosquitto.conf")
        # The compose file's settings, on this port; without its
        # message_size_limit, so that a 20 MB command reaches the edge node.
        with open(os.path.join(DEPLOY, "mosquitto.conf")) as f:
            lines = [
                line
                for line in f.read().splitlines()
                if not line.startswith(("listener", "message_size_limit", "log_dest"))
            ]
        text = "\n".join(lines).replace("/mosquitto/config/", self.dir + "/")
        with open(conf, "w") as f:
            f.write(f"listener {self.port} 127.0.0.1\n{text}\n")
        self.proc = subprocess.Popen([MOSQUITTO, "-c", conf], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        import socket

        deadline = time.monotonic() + 10
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "mosquitto did not start"
                time.sleep(0.05)

    def close(self):
        self.proc.terminate()
        self.proc.wait(timeout=10)
        shutil.rmtree(self.dir, ignore_errors=True)


class Client:
    """An MQTT client of one account (None: anonymous), recording what it
    receives (Sparkplug payloads decoded, names resolved by alias)."""

    def __init__(self, port, account, subscribe=None, state_ts=None):
        self.messages, self.aliases = [], {}
        self.cond = threading.Condition()
        self.refused = None
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"test-{account}-{time.monotonic_ns()}")
        if account:
            self.client.username_pw_set(account, PASSWORDS[account])
        self.state_ts = state_ts
        if state_ts is not None:
            self.client.will_set(
                f"spBv1.0/STATE/{HOST_ID}", json.dumps({"online": False, "timestamp": state_ts}), qos=1, retain=True
            )
        self.subscribe = subscribe
        self.connected = threading.Event()
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", port, keepalive=5)
        self.client.loop_start()

    def _on_connect(self, client, userdata, flags, reason, properties):
        if reason.is_failure:
            self.refused = str(reason)
            return
        if self.subscribe:
            client.subscribe(self.subscribe, qos=0)
        if self.state_ts is not None:
            self.state(True, self.state_ts)
        self.connected.set()

    def state(self, online, ts):
        self.client.publish(
            f"spBv1.0/STATE/{HOST_ID}", json.dumps({"online": online, "timestamp": ts}), qos=1, retain=True
        ).wait_for_publish(5)

    def _on_message(self, client, userdata, msg):
        parts = msg.topic.split("/")
        record = {"topic": msg.topic, "kind": parts[2] if len(parts) > 2 else None, "device": parts[4] if len(parts) > 4 else None}
        if record["kind"] in ("NBIRTH", "NDEATH", "NDATA", "DBIRTH", "DDATA", "DCMD", "NCMD"):
            payload = pb.Payload()
            payload.ParseFromString(msg.payload)
            record["payload"] = payload
            for m in payload.metrics:
                if record["kind"] in ("NBIRTH", "DBIRTH") and m.HasField("alias"):
                    self.aliases[(record["device"], m.alias)] = m.name
        with self.cond:
            self.messages.append(record)
            self.cond.notify_all()

    def wait_for(self, predicate, timeout=30, start=0):
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for i, m in enumerate(self.messages[start:], start):
                    if predicate(m):
                        return i, m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no such message within {timeout} s: {[(m['kind'], m['device']) for m in self.messages]}")
                self.cond.wait(left)

    def publish(self, topic, payload):
        info = self.client.publish(topic, payload, qos=1)
        info.wait_for_publish(30)

    def close(self):
        self.client.loop_stop()
        self.client.disconnect()


class Gateway(Process):
    def __init__(self, port, data_dir=None):
        self.dir = tempfile.mkdtemp(prefix="candeck-spb-acl-")
        config = os.path.join(self.dir, "candeck.toml")
        with open(config, "w") as f:
            f.write(
                f'mqtt_url = "mqtt://127.0.0.1:{port}"\n'
                f'mqtt_username = "line-a"\nmqtt_password = "{PASSWORDS["line-a"]}"\n'
                f'sparkplug_group_id = "{GROUP}"\nsparkplug_edge_node_id = "{EDGE}"\n'
                f'sparkplug_primary_host = "{HOST_ID}"\nsparkplug_role = "operator"\n'
                "sync_period_ms = 50\n"
            )
        args = ["serve", "--listen", "127.0.0.1:0", "--config", config]
        if data_dir:
            args += ["--data-dir", data_dir]
        super().__init__(args)
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
    b = SecuredBroker()
    yield b
    b.close()


@pytest.fixture
def scada(broker):
    h = Client(broker.port, "scada", subscribe="spBv1.0/#", state_ts=int(time.time() * 1000))
    assert h.connected.wait(10), h.refused
    yield h
    h.close()


@pytest.fixture
def gateway(broker, scada):
    g = Gateway(broker.port)
    yield g
    g.close()


def birth_of(host, device, start=0):
    return host.wait_for(lambda m: m["kind"] == "DBIRTH" and m["device"] == device, start=start)


def born_metric(message, name):
    for m in message["payload"].metrics:
        if m.name == name:
            return m
    raise AssertionError(f"{name} not born: {[m.name for m in message['payload'].metrics]}")


def read_only(metric):
    for key, value in zip(metric.properties.keys, metric.properties.values):
        if key == "readOnly":
            return value.boolean_value
    return None


def velocity(gateway):
    return gateway.request("GET", "/buses/demo/nodes/1/axes/1")["velocity"]


def dcmd(metrics):
    payload = pb.Payload()
    payload.timestamp = int(time.time() * 1000)
    for alias, field, value in metrics:
        m = payload.metrics.add()
        m.alias = alias
        setattr(m, field, value)
    return payload.SerializeToString()


def test_only_the_scada_account_commands_and_in_the_spec_s_form(broker, scada, gateway):
    _, birth = birth_of(scada, "demo-1")
    # Every writable metric is born typed, aliased and writable.
    for name in ("NMT", "Axis 1/State", "Axis 1/Move", "Axis 1/Lease", "Axis 1/Lease Id", "Axis 1/Halt", "OD/0x1017:0"):
        m = born_metric(birth, name)
        assert m.HasField("alias") and m.datatype != 0, name
        assert read_only(m) is False, name
    assert read_only(born_metric(birth, "Identity/Vendor ID")) is True
    alias = {name: born_metric(birth, name).alias for name in ("Axis 1/State", "Axis 1/Move", "Axis 1/Lease", "Axis 1/Lease Id")}
    gateway.request("POST", "/buses/demo/nmt", {"command": "start"})
    topic = f"spBv1.0/{GROUP}/DCMD/{EDGE}/demo-1"
    lease = "3f2a9c0e5b7d41e8a6c2f0d9b8e7a615"
    command = dcmd(
        [
            (alias["Axis 1/State"], "string_value", "operation_enabled"),
            (alias["Axis 1/Move"], "string_value", '{"mode":"velocity","velocity":100}'),
            (alias["Axis 1/Lease"], "boolean_value", True),
            (alias["Axis 1/Lease Id"], "string_value", lease),
        ]
    )
    # Anonymous clients are refused at CONNECT; a viewer's DCMD is dropped
    # by the broker: never delivered, nothing moves.
    anonymous = Client(broker.port, None)
    time.sleep(1)
    assert anonymous.refused is not None
    anonymous.close()
    viewer = Client(broker.port, "viewer")
    assert viewer.connected.wait(10)
    viewer.publish(topic, command)
    time.sleep(2)
    assert not [m for m in scada.messages if m["kind"] == "DCMD"]
    assert velocity(gateway) in (0, None)
    viewer.close()
    # The scada account's alias-only DCMD without datatype moves the axis,
    # under its lease, renewed the same way.
    scada.publish(topic, command)
    renew = dcmd([(alias["Axis 1/Lease"], "boolean_value", True), (alias["Axis 1/Lease Id"], "string_value", lease)])
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and not (velocity(gateway) or 0) > 0:
        scada.publish(topic, renew)
        time.sleep(0.3)
    assert (velocity(gateway) or 0) > 0
    events = gateway.request("GET", "/events?channel=sparkplug")
    rows = events["events"] if isinstance(events, dict) else events
    # The DCMD (state, move, lease, lease id) is one row naming its
    # operations.
    assert any(
        r.get("operation") == "drive state change, move" and r.get("who") == "mqtt:line-a" for r in rows
    ), rows


def test_a_20_mb_dcmd_leaves_the_session_up(broker, scada, gateway):
    birth_of(scada, "demo-1")
    first = len(scada.messages)
    payload = pb.Payload()
    m = payload.metrics.add()
    m.name = "OD/0x1017:0"
    m.datatype = pb.DataType.String
    m.string_value = "x" * (20 * 1024 * 1024)
    scada.publish(f"spBv1.0/{GROUP}/DCMD/{EDGE}/demo-1", payload.SerializeToString())
    time.sleep(5)
    kinds = [m["kind"] for m in scada.messages[first:]]
    assert "NDEATH" not in kinds and "NBIRTH" not in kinds, kinds
    wait_until(lambda: "sparkplug_max_command_bytes" in gateway.log(), what="the refusal in the log")
    # Refused with its own code (413-like), the size and the limit said, in
    # one audit row of the message.
    events = gateway.request("GET", "/events?channel=sparkplug")
    rows = events["events"] if isinstance(events, dict) else events
    rows = [r for r in rows if r.get("outcome") == "command_too_large"]
    assert len(rows) == 1, rows
    assert rows[0]["operation"] == "command", rows
    assert "over the limit of 65536 bytes" in rows[0]["request"], rows


def test_state_per_sparkplug_3(broker, scada, gateway):
    _, nbirth = scada.wait_for(lambda m: m["kind"] == "NBIRTH")
    first = len(scada.messages)
    # A stale or replayed offline changes nothing.
    scada.state(False, 1)
    time.sleep(2)
    kinds = [m["kind"] for m in scada.messages[first:]]
    assert "NDEATH" not in kinds, kinds
    # A duplicate online brings no rebirth.
    scada.state(True, scada.state_ts)
    time.sleep(2)
    kinds = [m["kind"] for m in scada.messages[first:]]
    assert "NBIRTH" not in kinds, kinds
    # A valid offline: NDEATH with the birth's bdSeq, then a new connection
    # that waits for the host.
    scada.state(False, scada.state_ts)
    _, death = scada.wait_for(lambda m: m["kind"] == "NDEATH", start=first, timeout=10)
    bd = lambda msg: [m.long_value for m in msg["payload"].metrics if m.name == "bdSeq"][0]
    assert bd(death) == bd(nbirth)
    # Sparkplug 3.0: bdSeq is an Int64, in the birth and in the death.
    for message in (nbirth, death):
        (bd_seq,) = [m for m in message["payload"].metrics if m.name == "bdSeq"]
        assert bd_seq.datatype == pb.DataType.Int64, message["kind"]
    time.sleep(3)
    assert "NBIRTH" not in [m["kind"] for m in scada.messages[first:]]
    scada.state(True, scada.state_ts + 1)
    _, again = scada.wait_for(lambda m: m["kind"] == "NBIRTH", start=first, timeout=15)
    assert bd(again) == bd(nbirth) + 1


def test_births_come_before_history_after_a_restart(broker, scada):
    data_dir = tempfile.mkdtemp(prefix="candeck-spb-data-")
    try:
        g = Gateway(broker.port, data_dir)
        birth_of(scada, "demo-1")
        g.request("POST", "/buses/demo/nmt", {"command": "start"})
        # The host goes away: the data is spooled, then the gateway restarts.
        scada.state(False, scada.state_ts)
        scada.wait_for(lambda m: m["kind"] == "NDEATH")
        for target in ("operation_enabled", "switched_on", "operation_enabled"):
            g.request("POST", "/buses/demo/nodes/1/axes/1/state", {"target": target})
            time.sleep(0.5)
        g.close()
        first = len(scada.messages)
        g = Gateway(broker.port, data_dir)
        scada.state(True, scada.state_ts + 1)
        wait_until(
            lambda: any(
                m["kind"] == "DDATA" and any(x.is_historical for x in m["payload"].metrics) for m in scada.messages[first:]
            ),
            timeout=30,
            what="the history",
        )
        born = set()
        for m in scada.messages[first:]:
            if m["kind"] == "DBIRTH":
                born.add(m["device"])
            if m["kind"] == "DDATA" and any(x.is_historical for x in m["payload"].metrics):
                assert m["device"] in born, (m["device"], born)
        g.close()
    finally:
        shutil.rmtree(data_dir, ignore_errors=True)
