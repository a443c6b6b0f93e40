"""Python asyncua (a client no one here wrote) against candeck's OPC UA server
(issue 34): Basic256Sha256 SignAndEncrypt with a user name and password (a
token's name and secret); the browse tree down to a UMC axis; identity;
a subscription to Axes/1/Position while the axis moves; SetState and Move
by an operator; a viewer's Move refused (BadUserAccessDenied) and audited;
a dictionary write read back over REST; an unknown client certificate
refused until moved to trusted/; a closed session halting its leased move;
anonymous refused where the gateway has tokens, and on a listener beyond
loopback (no endpoint without security there either)."""

import asyncio
import glob
import json
import os
import shutil
import tempfile
import time
import urllib.request

import pytest
from asyncua import Client, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID

from conftest import Process

OPERATOR = ("line-hmi", "0p3rat0r-s3cret-0123456789")
VIEWER = ("scada", "v13w3r-s3cret-abcdefghijkl")
ADMIN = ("admin", "adm1n-s3cret-mnopqrstuvwx")
CLIENT_URI = "urn:candeck:interop-test"


class Gateway(Process):
    """`candeck serve` on the demo bus with tokens, REST on loopback, OPC UA
    on `opcua_listen` (loopback unless told), motion leases of one second.
    `url` is the OPC UA server's over 127.0.0.1 whatever it listens on."""

    def __init__(self, opcua_listen="127.0.0.1:0"):
        self.dir = tempfile.mkdtemp(prefix="candeck-opcua-")
        os.environ["CANDECK_TOKENS"] = ",".join(
            f"{name}:{role}:{secret}"
            for (name, secret), role in ((OPERATOR, "operator"), (VIEWER, "viewer"), (ADMIN, "admin"))
        )
        try:
            super().__init__(
                [
                    "serve",
                    "--listen",
                    "127.0.0.1:0",
                    "--opcua-listen",
                    opcua_listen,
                    "--data-dir",
                    self.dir,
                    "--lease-ms",
                    "1000",
                ]
            )
        finally:
            del os.environ["CANDECK_TOKENS"]
        line = self.first_line()
        self.base = "http://" + line.split("http://")[1].split("/")[0] + "/api/v1"
        while True:
            line = self.first_line()
            if "OPC UA server on " in line:
                url = line.split("OPC UA server on ")[1].split()[0].rstrip("/")
                # On every address the URL names the machine: connect over
                # loopback, which a non-loopback listener serves alike.
                self.url = "opc.tcp://127.0.0.1:" + url.rsplit(":", 1)[1]
                break
        self.pki = os.path.join(self.dir, "opcua-pki")

    def request(self, method, path, body=None):
        data = json.dumps(body).encode() if body is not None else None
        req = urllib.request.Request(self.base + path, data=data, method=method)
        req.add_header("content-type", "application/json")
        req.add_header("authorization", f"Bearer {ADMIN[1]}")
        with urllib.request.urlopen(req, timeout=30) as resp:
            text = resp.read()
            return json.loads(text) if text else None

    def close(self):
        self.stop()
        shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture(scope="module")
def gateway():
    server = Gateway()
    yield server
    server.close()


@pytest.fixture(scope="module")
def certificate(tmp_path_factory):
    """A client application certificate, trusted by moving it from the
    server's rejected/ to trusted/ (docs/opcua.md), as an administrator
    would."""
    folder = tmp_path_factory.mktemp("client-pki")
    key, cert = folder / "key.pem", folder / "cert.der"
    asyncio.run(
        setup_self_signed_certificate(
            key,
            cert,
            CLIENT_URI,
            "localhost",
            [ExtendedKeyUsageOID.CLIENT_AUTH],
            {"countryName": "FR", "organizationName": "candeck tests", "commonName": "interop"},
        )
    )
    return str(cert), str(key)


def client(gateway, certificate, user):
    c = Client(gateway.url, timeout=10)
    c.application_uri = CLIENT_URI
    c.session_timeout = 30_000
    if user:
        c.set_user(user[0])
        c.set_password(user[1])
    return c


async def secured(gateway, certificate, user):
    c = client(gateway, certificate, user)
    await c.set_security(
        SecurityPolicyBasic256Sha256,
        certificate=certificate[0],
        private_key=certificate[1],
        mode=ua.MessageSecurityMode.SignAndEncrypt,
    )
    return c


def trust_rejected(gateway):
    """The one move that trusts a client: rejected/ to trusted/."""
    rejected = glob.glob(os.path.join(gateway.pki, "rejected", "*"))
    for path in rejected:
        shutil.move(path, os.path.join(gateway.pki, "trusted", os.path.basename(path)))
    return rejected


async def connected(gateway, certificate, user):
    """A session, the client's certificate trusted first if it was refused
    (each test may run alone)."""
    c = await secured(gateway, certificate, user)
    try:
        await c.connect()
    except Exception:
        assert trust_rejected(gateway), "refused, with no certificate in rejected/"
        c = await secured(gateway, certificate, user)
        await c.connect()
    return c


async def axis(c, path=("Nodes", "demo", "1", "Axes", "1")):
    ns = await c.get_namespace_index("urn:candeck")
    deadline = time.monotonic() + 20
    while True:
        try:
            return ns, await c.nodes.objects.get_child([f"{ns}:candeck", *(f"{ns}:{p}" for p in path)])
        except ua.UaError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)


def velocity(gateway):
    return gateway.request("GET", "/buses/demo/nodes/1/axes/1")["velocity"]


async def wait_until(predicate, timeout=15, what="the condition"):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s")
        await asyncio.sleep(0.1)


async def wait_until_async(read, expected, timeout=10, what="the value"):
    deadline = time.monotonic() + timeout
    while (value := await read()) != expected:
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: {value!r}, not {expected!r} within {timeout} s")
        await asyncio.sleep(0.1)


def test_an_unknown_client_certificate_is_refused_until_moved_to_trusted(gateway, certificate):
    async def run():
        c = await secured(gateway, certificate, OPERATOR)
        with pytest.raises(Exception):
            await c.connect()
        moved = trust_rejected(gateway)
        assert moved, "the refused certificate did not land in rejected/"
        c = await connected(gateway, certificate, OPERATOR)
        await c.disconnect()
        # Only the owner may read the PKI (the server's private key).
        for folder in ("", "own", "private", "trusted", "rejected"):
            assert os.stat(os.path.join(gateway.pki, folder)).st_mode & 0o077 == 0, folder

    asyncio.run(run())


def test_an_operator_browses_reads_subscribes_and_moves_a_umc_axis(gateway, certificate):
    async def run():
        trust_rejected(gateway)
        c = await connected(gateway, certificate, OPERATOR)
        try:
            ns, axis1 = await axis(c)
            node = await c.nodes.objects.get_child([f"{ns}:candeck", f"{ns}:Nodes", f"{ns}:demo", f"{ns}:1"])
            identification = await node.get_child(f"{ns}:Identification")
            manufacturer = await (await identification.get_child(f"{ns}:Manufacturer")).read_value()
            serial = await (await identification.get_child(f"{ns}:SerialNumber")).read_value()
            assert manufacturer and serial, (manufacturer, serial)
            assert await (await node.get_child(f"{ns}:Profile")).read_value() == "umc"
            units = await (await axis1.get_child([f"{ns}:Position", "0:EngineeringUnits"])).read_value()
            assert units.DisplayName.Text

            positions = []

            class Handler:
                def datachange_notification(self, _node, value, _data):
                    if value is not None:
                        positions.append(value)

            subscription = await c.create_subscription(50, Handler())
            await subscription.subscribe_data_change(await axis1.get_child(f"{ns}:Position"))
            await axis1.call_method(f"{ns}:SetState", "operation_enabled")
            state = await axis1.get_child(f"{ns}:State")
            await wait_until_async(lambda: state.read_value(), "operation_enabled", what="the axis enabled")
            leased = await axis1.call_method(
                f"{ns}:Move", "velocity", ua.Variant(300.0, ua.VariantType.Double), 0.0, 0.0, 0.0, False
            )
            assert leased is True
            await wait_until(lambda: len(set(positions)) > 5, what="position changes while the axis turns")
            # The lease is the session's: renewed while it lives.
            await asyncio.sleep(2.5)
            assert velocity(gateway) > 0, "halted while the session lived"
            await axis1.call_method(f"{ns}:Halt")
            await wait_until(lambda: velocity(gateway) == 0, what="the axis halted")
            await subscription.delete()
        finally:
            await c.disconnect()

    asyncio.run(run())


def test_a_viewers_move_is_refused_and_audited(gateway, certificate):
    async def run():
        trust_rejected(gateway)
        c = await connected(gateway, certificate, VIEWER)
        try:
            ns, axis1 = await axis(c)
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await axis1.call_method(f"{ns}:Move", "velocity", 100.0, 0.0, 0.0, 0.0, False)
            assert refused.value.code == ua.StatusCodes.BadUserAccessDenied
            # A viewer reads, and may stop everything, as over REST.
            await (await axis1.get_child(f"{ns}:Position")).read_value()
            root = await c.nodes.objects.get_child(f"{ns}:candeck")
            await root.call_method(f"{ns}:StopAll")
        finally:
            await c.disconnect()
        events = gateway.request("GET", "/events?kind=audit&limit=100")
        rows = [e for e in events if e.get("operation") == "move" and e.get("who") == VIEWER[0]]
        assert rows, events
        assert rows[-1]["channel"] == "opcua"
        assert rows[-1]["error_code"] == "forbidden"

    asyncio.run(run())


def test_a_dictionary_write_is_read_back_over_rest(gateway, certificate):
    async def run():
        trust_rejected(gateway)
        c = await connected(gateway, certificate, OPERATOR)
        try:
            ns, heartbeat = await axis(c, ("Nodes", "demo", "1", "Dictionary", "0x1017sub0"))
            before = await heartbeat.read_value()
            await heartbeat.write_value(ua.DataValue(ua.Variant(before + 100, ua.VariantType.UInt16)))
            assert await heartbeat.read_value() == before + 100
            over_rest = gateway.request("GET", "/buses/demo/nodes/1/od/0x1017/0")
            assert over_rest["value"] == before + 100, over_rest
            # A value the entry cannot hold is refused before the bus.
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await heartbeat.write_value(ua.DataValue(ua.Variant(-1, ua.VariantType.Int32)))
            assert refused.value.code in (ua.StatusCodes.BadOutOfRange, ua.StatusCodes.BadTypeMismatch)
            await heartbeat.write_value(ua.DataValue(ua.Variant(before, ua.VariantType.UInt16)))
        finally:
            await c.disconnect()

    asyncio.run(run())


def test_a_closed_session_halts_its_leased_velocity_move(gateway, certificate):
    async def run():
        trust_rejected(gateway)
        c = await connected(gateway, certificate, OPERATOR)
        ns, axis1 = await axis(c)
        await axis1.call_method(f"{ns}:SetState", "operation_enabled")
        assert await axis1.call_method(f"{ns}:Move", "velocity", 200.0, 0.0, 0.0, 0.0, False) is True
        await wait_until(lambda: velocity(gateway) > 0, what="the axis turning")
        await c.disconnect()
        # Within the lease period (1 s) and the keeper's round.
        await wait_until(lambda: velocity(gateway) == 0, timeout=5, what="the axis halted after the session closed")
        events = gateway.request("GET", "/events?kind=audit&limit=100")
        assert any(e.get("who") == "gateway" and "lapsed" in e.get("operation", "") for e in events), events

    asyncio.run(run())


def test_anonymous_is_refused_where_the_gateway_has_tokens(gateway, certificate):
    async def run():
        trust_rejected(gateway)
        c = await secured(gateway, certificate, None)
        with pytest.raises(Exception):
            await c.connect()

    asyncio.run(run())


@pytest.fixture(scope="module")
def network_gateway():
    """A gateway whose OPC UA server listens on every address (0.0.0.0),
    reached here over 127.0.0.1."""
    server = Gateway(opcua_listen="0.0.0.0:0")
    yield server
    server.close()


def test_anonymous_is_refused_on_a_listener_beyond_loopback(network_gateway, certificate):
    async def run():
        # A user is served there, once the client's certificate is trusted.
        c = await connected(network_gateway, certificate, OPERATOR)
        await c.disconnect()
        endpoints = await Client(network_gateway.url, timeout=10).connect_and_get_server_endpoints()
        assert endpoints
        assert all(e.SecurityMode != ua.MessageSecurityMode.None_ for e in endpoints), endpoints
        anonymous = await secured(network_gateway, certificate, None)
        with pytest.raises(Exception):
            await anonymous.connect()

    asyncio.run(run())
