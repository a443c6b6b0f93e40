"""Python asyncua against candeck's OPC UA server (issue 34, point 3): the
UIO1LED's segments (`Nodes/demo/3/Leds/{n}/{field}`) and a virtual io401's
channels (`Nodes/demo/4/Io/{channel}`) browsed to, written by an operator
and read back over REST; a viewer's writes refused (BadUserAccessDenied)
and audited as REST's (`set segment`, `set outputs`); an input not
writable; values the objects cannot hold refused with the status a client
branches on; a monitored digital input fed by the module's TPDO (no SDO)
seen changing as the virtual module's running light moves, and a monitored
LED field sampled over SDO seen taking a segment write made over REST."""

import asyncio
import time

import pytest
from asyncua import ua

import test_opcua as base
from test_opcua import certificate  # noqa: F401 (the client certificate fixture)
from test_opcua_sampling import sdo_uploads

OPERATOR, VIEWER = base.OPERATOR, base.VIEWER


@pytest.fixture(scope="module")
def gateway():
    """The demo bus with a virtual io401 added at node 4."""
    server = base.Gateway()
    server.request("POST", "/buses/demo/sim/nodes", {"product": "io401", "id": 4})
    yield server
    server.close()


async def variable(c, *path):
    """The variable at `candeck/Nodes/demo/...`, waiting for the node's
    subtree (built once the node is identified)."""
    return (await base.axis(c, ("Nodes", "demo", *path)))[1]


def channel(io, kind, name):
    return next(c for c in io[kind] if c["channel"] == name)


def test_an_operator_writes_a_segment_and_outputs_read_back_over_rest(gateway, certificate):  # noqa: F811
    async def run():
        base.trust_rejected(gateway)
        c = await base.connected(gateway, certificate, OPERATOR)
        try:
            effect = await variable(c, "3", "Leds", "2", "Effect")
            await effect.write_value(ua.DataValue(ua.Variant("breathing", ua.VariantType.String)))
            assert await effect.read_value() == "breathing"
            color = await variable(c, "3", "Leds", "2", "Color1")
            await color.write_value(ua.DataValue(ua.Variant("#00ff0010", ua.VariantType.String)))
            dimmer = await variable(c, "3", "Leds", "2", "Dimmer")
            await dimmer.write_value(ua.DataValue(ua.Variant(128, ua.VariantType.Byte)))
            assert await dimmer.read_value() == 128
            segment = gateway.request("GET", "/buses/demo/nodes/3/segments")[1]
            assert segment["effect"] == "breathing", segment
            assert segment["colors"][0] == {"r": 0, "g": 255, "b": 0, "w": 16}, segment
            assert segment["dimmer"] == 128, segment

            output = await variable(c, "4", "Io", "do3")
            await output.write_value(ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
            assert await output.read_value() is True
            analog = await variable(c, "4", "Io", "ao1")
            await analog.write_value(ua.DataValue(ua.Variant(-1000, ua.VariantType.Int16)))
            assert await analog.read_value() == -1000
            io = gateway.request("GET", "/buses/demo/nodes/4/io")
            assert channel(io, "digital_outputs", "do3")["value"] is True, io
            assert channel(io, "analog_outputs", "ao1")["value"] == -1000, io
            # An input is read, never written.
            di1 = await variable(c, "4", "Io", "di1")
            assert isinstance(await di1.read_value(), bool)
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await di1.write_value(ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
            assert refused.value.code == ua.StatusCodes.BadNotWritable

            # What the objects cannot hold: refused, the session lives on.
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await effect.write_value(ua.DataValue(ua.Variant("sparkle", ua.VariantType.String)))
            assert refused.value.code == ua.StatusCodes.BadOutOfRange
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await dimmer.write_value(ua.DataValue(ua.Variant(300, ua.VariantType.Int32)))
            assert refused.value.code == ua.StatusCodes.BadOutOfRange
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await dimmer.write_value(ua.DataValue(ua.Variant(0.5, ua.VariantType.Double)))
            assert refused.value.code == ua.StatusCodes.BadTypeMismatch
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await color.write_value(ua.DataValue(ua.Variant("green", ua.VariantType.String)))
            assert refused.value.code == ua.StatusCodes.BadTypeMismatch
            assert await effect.read_value() == "breathing"
            await output.write_value(ua.DataValue(ua.Variant(False, ua.VariantType.Boolean)))
        finally:
            await c.disconnect()
        events = gateway.request("GET", "/events?kind=audit&limit=100")
        mine = [e for e in events if e.get("who") == OPERATOR[0] and e.get("channel") == "opcua"]
        assert {"set segment", "set outputs"} <= {e.get("operation") for e in mine}, events

    asyncio.run(run())


def test_a_viewers_segment_and_output_writes_are_refused_and_audited(gateway, certificate):  # noqa: F811
    async def run():
        base.trust_rejected(gateway)
        c = await base.connected(gateway, certificate, VIEWER)
        try:
            effect = await variable(c, "3", "Leds", "1", "Effect")
            before = await effect.read_value()
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await effect.write_value(ua.DataValue(ua.Variant("off", ua.VariantType.String)))
            assert refused.value.code == ua.StatusCodes.BadUserAccessDenied
            output = await variable(c, "4", "Io", "do1")
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await output.write_value(ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))
            assert refused.value.code == ua.StatusCodes.BadUserAccessDenied
            assert await effect.read_value() == before
        finally:
            await c.disconnect()
        assert channel(gateway.request("GET", "/buses/demo/nodes/4/io"), "digital_outputs", "do1")["value"] is False
        events = gateway.request("GET", "/events?kind=audit&limit=100")
        refused = {
            e.get("operation")
            for e in events
            if e.get("who") == VIEWER[0] and e.get("channel") == "opcua" and e.get("error_code") == "forbidden"
        }
        assert {"set segment", "set outputs"} <= refused, events

    asyncio.run(run())


class Changes:
    """The values a subscription delivers, by node id."""

    def __init__(self):
        self.values = {}

    def datachange_notification(self, node, value, _data):
        self.values.setdefault(node.nodeid.Identifier, []).append(value)

    def of(self, node):
        return self.values.get(node.nodeid.Identifier, [])


def test_a_monitored_input_follows_the_tpdo_and_an_led_field_a_segment_write(gateway, certificate):  # noqa: F811
    async def run():
        # The io401's TPDOs run in operational; its digital inputs are a
        # running light (docs/virtual-devices.md): di1 is on for the first
        # quarter second of every 4 s.
        gateway.request("POST", "/buses/demo/nodes/4/nmt", {"command": "start"})
        deadline = time.monotonic() + 20
        while not any(
            value["index"] == "0x6000" and value["sub"] == 1
            for value in gateway.request("GET", "/buses/demo/nodes/4/values")["values"]
        ):
            assert time.monotonic() < deadline, "node 4 sends no TPDO with its digital inputs"
            await asyncio.sleep(0.2)
        base.trust_rejected(gateway)
        c = await base.connected(gateway, certificate, VIEWER)
        try:
            di1 = await variable(c, "4", "Io", "di1")
            dimmer = await variable(c, "3", "Leds", "5", "Dimmer")
            changes = Changes()
            subscription = await c.create_subscription(50, changes)
            since = time.time()
            await subscription.subscribe_data_change([di1, dimmer], sampling_interval=50)

            # On, then off again: each change of the bit arrives.
            await base.wait_until(
                lambda: [v for v in changes.of(di1) if v is True] and changes.of(di1)[-1] is False,
                timeout=12,
                what="di1 going on and off",
            )
            seen = changes.of(di1)
            assert all(isinstance(v, bool) for v in seen), seen
            # Only changes: never the same value twice in a row.
            assert all(a != b for a, b in zip(seen, seen[1:])), seen
            # Fed by the TPDO: no SDO upload of the inputs' object.
            assert not [up for up in sdo_uploads(gateway, node=4) if up[2] >= since and up[0] == 0x6000]

            # The LED field: its first sample, then a segment write over
            # REST arrives with the next sample.
            await base.wait_until(lambda: changes.of(dimmer), what="the Dimmer's first value")
            before = changes.of(dimmer)[-1]
            wanted = 77 if before != 77 else 78
            gateway.request("PUT", "/buses/demo/nodes/3/segments/5", {"dimmer": wanted})
            await base.wait_until(lambda: changes.of(dimmer)[-1] == wanted, timeout=10, what="the Dimmer written")
            await subscription.delete()
        finally:
            await c.disconnect()

    asyncio.run(run())
