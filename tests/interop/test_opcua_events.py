"""Python asyncua against candeck's OPC UA events (issue 34, part B): a
client subscribed to events on Machine and on a node's object receives the
EMCY and the alarm of a fault injected over REST and a node's NMT changes;
Machine.Acknowledge acknowledges the alarm in the gateway with the user's
name, as REST's acknowledge would; bad input is a status, never a dropped
connection."""

import asyncio
import contextlib
import time

import pytest
from asyncua import ua

import test_opcua as base

OPERATOR, VIEWER = base.OPERATOR, base.VIEWER


# test_opcua.py's fixtures (module-scoped: this module gets a gateway of its
# own), the client certificate trusted as there.
gateway = base.gateway
certificate = base.certificate


class Collected:
    """The events a subscription delivers, in order."""

    def __init__(self):
        self.events = []

    def event_notification(self, event):
        self.events.append(event)

    async def first(self, predicate, timeout=15, what="the event"):
        deadline = time.monotonic() + timeout
        while True:
            for event in self.events:
                if predicate(event):
                    return event
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout} s; got {self.events!r}")
            await asyncio.sleep(0.1)


async def event_types(c, ns):
    types = {}
    for name in ("NmtChangeEventType", "EmcyEventType", "AlarmEventType"):
        types[name] = c.get_node(ua.NodeId(name, ns))
    return types


@contextlib.asynccontextmanager
async def operator_session(gateway, certificate):
    """An operator's session, closed on the way out, its certificate trusted
    first (each test may run alone): the client, the namespace and axis 1 of
    node 1 (found once the tree is built)."""
    base.trust_rejected(gateway)
    c = await base.connected(gateway, certificate, OPERATOR)
    try:
        ns, axis1 = await base.axis(c)
        yield c, ns, axis1
    finally:
        await c.disconnect()


async def subscribe(c, ns, source, *names):
    """A subscription to the events of the types `names` of `source`; what
    it delivers collects in the returned Collected."""
    types = await event_types(c, ns)
    seen = Collected()
    subscription = await c.create_subscription(50, seen)
    # asyncua selects every field as BaseEventType's; the queue keeps
    # events raised in the same publishing interval (the EMCY and its
    # alarm).
    await subscription.subscribe_events(
        source,
        [types[name] for name in names],
        where_clause_generation=False,
        queuesize=100,
    )
    return seen, subscription


def test_lease_methods_hand_the_sessions_lease_to_the_client(gateway, certificate):
    async def run():
        async with operator_session(gateway, certificate) as (_, ns, axis1):
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await axis1.call_method(f"{ns}:TakeLease")
            assert refused.value.code == ua.StatusCodes.BadNotFound
            await axis1.call_method(f"{ns}:SetState", "operation_enabled")
            assert await axis1.call_method(f"{ns}:Move", "velocity", 200.0, 0.0, 0.0, 0.0, False) is True
            await base.wait_until(lambda: base.velocity(gateway) > 0, what="the axis turning")
            lease_id, period_ms = await axis1.call_method(f"{ns}:TakeLease")
            assert lease_id and period_ms == 1000, (lease_id, period_ms)
            assert await axis1.call_method(f"{ns}:RenewLease", lease_id) == 1000
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await axis1.call_method(f"{ns}:RenewLease", "no-such-lease")
            assert refused.value.code in (ua.StatusCodes.BadNotFound, ua.StatusCodes.BadInvalidState)
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await axis1.call_method(f"{ns}:RenewLease", ua.Variant(7, ua.VariantType.UInt32))
            assert refused.value.code == ua.StatusCodes.BadTypeMismatch
            # Released: the gateway's supervisor halts the axis, the session lives on.
            await axis1.call_method(f"{ns}:ReleaseLease", lease_id)
            await base.wait_until(lambda: base.velocity(gateway) == 0, timeout=5, what="the axis halted")
            assert await (await axis1.get_child(f"{ns}:State")).read_value()
        audit = gateway.request("GET", "/events?kind=audit&limit=200")
        rows = [e for e in audit if e.get("operation") == "end motion lease" and e.get("who") == OPERATOR[0]]
        assert rows and rows[-1]["channel"] == "opcua", audit

    asyncio.run(run())


def test_a_fault_is_an_emcy_and_an_alarm_event_and_acknowledge_is_the_gateways(gateway, certificate):
    async def run():
        async with operator_session(gateway, certificate) as (c, ns, _):
            try:
                root = await c.nodes.objects.get_child(f"{ns}:candeck")
                machine = await root.get_child(f"{ns}:Machine")
                seen, subscription = await subscribe(c, ns, machine, "EmcyEventType", "AlarmEventType")

                gateway.request("POST", "/buses/demo/sim/nodes/1/faults", {"kind": "over_temperature"})
                emcy = await seen.first(lambda e: getattr(e, "ErrorCode", None) == 0x4310, what="the EMCY event")
                assert (emcy.Bus, emcy.Node) == ("demo", 1)
                assert emcy.Severity >= 600 and "0x4310" in emcy.Message.Text
                assert emcy.SourceNode == ua.NodeId("candeck/Nodes/demo/1/Axes/1", ns) or emcy.SourceNode == ua.NodeId(
                    "candeck/Nodes/demo/1", ns
                )
                raised = await seen.first(
                    lambda e: getattr(e, "AlarmStep", None) == "raised" and e.Node == 1, what="the alarm raised"
                )
                assert raised.AlarmState == "active_unacknowledged"
                assert raised.AlarmSeverity in ("critical", "high", "medium", "low")
                alarm = gateway.request("GET", f"/alarms/{raised.AlarmId}")
                assert alarm["state"] == "active_unacknowledged"
                assert raised.Severity >= 1 and raised.EventId

                state = await machine.call_method(f"{ns}:Acknowledge", raised.AlarmId, "seen on the HMI")
                assert state in ("active_acknowledged", "normal"), state
                alarm = gateway.request("GET", f"/alarms/{raised.AlarmId}")
                assert alarm["acknowledged_by"] == OPERATOR[0], alarm
                assert alarm["comment"] == "seen on the HMI", alarm
                acknowledged = await seen.first(
                    lambda e: getattr(e, "AlarmStep", None) == "acknowledged" and e.AlarmId == raised.AlarmId,
                    what="the acknowledged event",
                )
                assert acknowledged.AcknowledgedBy == OPERATOR[0]
                audit = gateway.request("GET", "/events?kind=audit&limit=100")
                rows = [e for e in audit if e.get("operation") == "acknowledge alarm" and e.get("who") == OPERATOR[0]]
                assert rows and rows[-1]["channel"] == "opcua", audit

                # Bad input is a status code; the session stays usable.
                with pytest.raises(ua.UaStatusCodeError) as refused:
                    await machine.call_method(f"{ns}:Acknowledge", "not-an-id", "")
                assert refused.value.code == ua.StatusCodes.BadInvalidArgument
                with pytest.raises(ua.UaStatusCodeError) as refused:
                    await machine.call_method(f"{ns}:Acknowledge", "999999", "")
                assert refused.value.code == ua.StatusCodes.BadNotFound
                with pytest.raises(ua.UaStatusCodeError) as refused:
                    await machine.call_method(f"{ns}:Acknowledge", ua.Variant(5, ua.VariantType.UInt32), "")
                assert refused.value.code == ua.StatusCodes.BadTypeMismatch
                await subscription.delete()
            finally:
                gateway.request("DELETE", "/buses/demo/sim/nodes/1/faults", {"kind": "over_temperature"})

        # A viewer may not acknowledge, as over REST.
        v = await base.connected(gateway, certificate, VIEWER)
        try:
            ns = await v.get_namespace_index("urn:candeck")
            machine = await v.nodes.objects.get_child([f"{ns}:candeck", f"{ns}:Machine"])
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await machine.call_method(f"{ns}:Acknowledge", raised.AlarmId, "")
            assert refused.value.code == ua.StatusCodes.BadUserAccessDenied
        finally:
            await v.disconnect()

    asyncio.run(run())


def test_a_nodes_nmt_change_is_an_event_of_its_object(gateway, certificate):
    async def run():
        async with operator_session(gateway, certificate) as (c, ns, _):
            node = await c.nodes.objects.get_child([f"{ns}:candeck", f"{ns}:Nodes", f"{ns}:demo", f"{ns}:1"])
            seen, subscription = await subscribe(c, ns, node, "NmtChangeEventType")
            # A reset: the node's boot-up is its NMT change (the demo's nodes
            # send no heartbeat, so a state the gateway commands is not
            # reported back; a boot-up always is).
            await node.call_method(f"{ns}:Nmt", "reset_node")
            event = await seen.first(lambda e: getattr(e, "NmtState", None) == "boot_up", what="the NMT change event")
            assert (event.Bus, event.Node) == ("demo", 1)
            assert event.PreviousState != "boot_up"
            assert event.SourceNode == ua.NodeId("candeck/Nodes/demo/1", ns)
            assert "boot_up" in event.Message.Text and event.Severity == 200
            await subscription.delete()

    asyncio.run(run())
