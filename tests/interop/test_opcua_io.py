"""Python asyncua against candeck's OPC UA server (issue 34, point 3): the
UIO1LED's segments (`Nodes/demo/3/Leds/{n}/{field}`) and a virtual io401's
channels (`Nodes/demo/4/Io/{channel}`) browsed to, written by an operator
and read back over REST; a viewer's writes refused (BadUserAccessDenied)
and audited as REST's (`set segment`, `set outputs`); an input not
writable; values the objects cannot hold refused with the status a client
branches on."""

import asyncio

import pytest
from asyncua import ua

import test_opcua as base
from test_opcua import certificate  # noqa: F401 (the client certificate fixture)

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
