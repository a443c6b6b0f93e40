"""Python asyncua against candeck's monitored dictionary variables (issue 34
point 4): an SDO-only object (0x1017, the heartbeat time) is sampled over
SDO at the item's interval; many items asking 1 ms on one node share the
per-node bound (`opcua_sdo_samples_per_s`): the SDO requests the bus saw stay
within it and the values say GoodOverload; an object a running TPDO carries
takes no SDO; deleting the items stops the sampling."""

import asyncio
import json
import os
import shutil
import tempfile
import time
import urllib.request

import pytest
from asyncua import Client, ua

from conftest import Process

BOUND = 5


class Gateway(Process):
    """An open gateway (no tokens) on the demo bus: REST and OPC UA on
    loopback, anonymous sessions over the `None` endpoint, a bound of
    BOUND samples a second per node, SYNC every 200 ms (slow enough for
    the 1,000 frames `GET .../frames` keeps to span the test)."""

    def __init__(self):
        self.dir = tempfile.mkdtemp(prefix="candeck-opcua-sampling-")
        config = os.path.join(self.dir, "candeck.toml")
        with open(config, "w", encoding="utf-8") as f:
            # The UMC's TPDOs are synchronous: a SYNC producer runs them.
            f.write(f"opcua_sdo_samples_per_s = {BOUND}\nsync_period_ms = 200\n")
        super().__init__(
            [
                "serve",
                "--listen",
                "127.0.0.1:0",
                "--opcua-listen",
                "127.0.0.1:0",
                "--data-dir",
                self.dir,
                "--config",
                config,
            ]
        )
        line = self.first_line()
        self.base = "http://" + line.split("http://")[1].split("/")[0] + "/api/v1"
        while True:
            line = self.first_line()
            if "OPC UA server on " in line:
                self.url = line.split("OPC UA server on ")[1].split()[0].rstrip("/")
                break

    def request(self, method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(
            self.base + path, data=data, method=method, headers={"Content-Type": "application/json"}
        )
        with urllib.request.urlopen(req, timeout=30) as resp:
            return json.loads(resp.read())

    def close(self):
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture(scope="module")
def gateway():
    server = Gateway()
    yield server
    server.close()


class Changes:
    """The data changes a subscription delivers: (node, value, status, when)."""

    def __init__(self):
        self.changes = []

    def datachange_notification(self, node, value, data):
        dv = data.monitored_item.Value
        self.changes.append((node.nodeid.Identifier, value, dv.StatusCode.value, time.monotonic()))

    def of(self, identifier):
        return [change for change in self.changes if change[0] == identifier]


async def variable(c, ns, entry, node="1"):
    path = ["candeck", "Nodes", "demo", node, "Dictionary", entry]
    deadline = time.monotonic() + 20
    while True:
        try:
            return await c.nodes.objects.get_child([f"{ns}:{p}" for p in path])
        except ua.UaError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)


def sdo_uploads(gateway, node=1):
    """The SDO upload requests to `node` in the bus's recent frames, as
    (index, sub, time in seconds)."""
    frames = gateway.request("GET", "/buses/demo/frames?limit=1000")
    frames = frames.get("frames", frames) if isinstance(frames, dict) else frames
    uploads = []
    for frame in frames:
        cob_id = frame["id"]
        cob_id = int(cob_id, 16) if isinstance(cob_id, str) else cob_id
        if cob_id != 0x600 + node:
            continue
        data = bytes.fromhex(frame["data"])
        if len(data) == 8 and data[0] == 0x40:
            stamp = frame.get("timestamp_us", frame.get("t_us", 0)) / 1e6
            uploads.append((data[1] | data[2] << 8, data[3], stamp))
    return uploads


def carried_object(gateway):
    """An object node 1's running TPDOs carry, as the gateway decodes them.
    The demo's nodes wait in pre-operational: node 1 is started first."""
    gateway.request("POST", "/buses/demo/nodes/1/nmt", {"command": "start"})
    deadline = time.monotonic() + 20
    while True:
        values = gateway.request("GET", "/buses/demo/nodes/1/values")["values"]
        if values:
            value = values[0]
            return int(value["index"], 16), value["sub"]
        if time.monotonic() > deadline:
            raise AssertionError("node 1 sends no TPDO")
        time.sleep(0.2)


def test_many_items_on_one_node_share_its_bound_and_tpdo_values_take_no_sdo(gateway):
    async def run():
        async with Client(gateway.url, timeout=10) as c:
            ns = await c.get_namespace_index("urn:candeck")
            index, sub = carried_object(gateway)
            carried = await variable(c, ns, f"0x{index:04X}sub{sub}")
            sdo_only = [
                await variable(c, ns, entry)
                for entry in ("0x1017sub0", "0x1000sub0", "0x1018sub1", "0x1018sub2", "0x1018sub3", "0x1018sub4")
            ]
            changes = Changes()
            sub_ = await c.create_subscription(100, changes)
            before = time.monotonic()
            # Frame stamps are wall-clock: the gateway's own reads before
            # this (identification, boot-up) are not the sampler's.
            since = time.time()
            params = []
            for node in [*sdo_only, *sdo_only, carried]:
                params.append(
                    ua.MonitoredItemCreateRequest(
                        ItemToMonitor=ua.ReadValueId(NodeId=node.nodeid, AttributeId=ua.AttributeIds.Value),
                        MonitoringMode=ua.MonitoringMode.Reporting,
                        RequestedParameters=ua.MonitoringParameters(
                            ClientHandle=len(params) + 1, SamplingInterval=1.0, QueueSize=1
                        ),
                    )
                )
            results = await sub_.create_monitored_items(params)
            assert all(not isinstance(result, ua.StatusCode) for result in results), results
            # async-opcua lets the node manager shorten a revised interval,
            # never lengthen it: the bound shows in the values' status and
            # their spacing (docs/opcua.md), checked below.
            await asyncio.sleep(4)
            seen = changes.of(sdo_only[0].nodeid.Identifier)
            # Sampled (its first value at least) and slowed down, said so.
            assert seen, changes.changes
            overload = ua.StatusCodes.GoodOverload
            uploads = [up for up in sdo_uploads(gateway) if up[2] >= since]
            window = time.monotonic() - before
            # Per node at most BOUND a second (one more for the one under way).
            assert len(uploads) <= BOUND * window + 1, (len(uploads), window)
            assert len(uploads) >= BOUND, uploads
            # Six objects asking 1000/s each of BOUND: each slowed, said so.
            values_of_first = [status for (_, _, status, _) in seen]
            assert overload in values_of_first or len(values_of_first) == 1, values_of_first
            # The TPDO's object: not one SDO upload.
            assert not [up for up in uploads if (up[0], up[1]) == (index, sub)], uploads
            await sub_.delete()
            # Deleted: no more sampling.
            await asyncio.sleep(0.5)
            after = time.time()
            await asyncio.sleep(2)
            # A sampler still running would upload 2 × BOUND in these 2 s;
            # the gateway's own reads (a node's resync) may add one or two.
            later = [up for up in sdo_uploads(gateway) if up[2] >= after]
            assert len(later) < BOUND, later

    asyncio.run(run())


def test_a_read_still_reads_over_sdo_when_asked(gateway):
    async def run():
        async with Client(gateway.url, timeout=10) as c:
            ns = await c.get_namespace_index("urn:candeck")
            heartbeat = await variable(c, ns, "0x1017sub0")
            over_rest = gateway.request("GET", "/buses/demo/nodes/1/od/0x1017/0")
            assert await heartbeat.read_value() == over_rest["value"]

    asyncio.run(run())
