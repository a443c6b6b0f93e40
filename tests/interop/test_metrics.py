"""`GET /metrics` of `candeck serve`, read by the Prometheus project's own
parser (PyPI `prometheus-client`, `text_string_to_metric_families`): the
families docs/deployment.md documents are there, with the right types and sane
values, and SDO reads through the REST API show up in the counters and
the latency histogram of node 1.
"""

import json
import math
import re
import time
import urllib.error
import urllib.request

import pytest
from prometheus_client.parser import text_string_to_metric_families

from conftest import Process

READS = 10


@pytest.fixture
def gateway():
    server = Process(["serve", "--listen", "127.0.0.1:0"])
    line = server.first_line()
    match = re.search(r"serving (http://[0-9.]+:\d+)/", line)
    assert match, f"unexpected first line: {line!r}"
    yield match.group(1)
    server.stop()


def scrape(base):
    """The page parsed: {family name: (type, [(sample name, labels, value)])}."""
    with urllib.request.urlopen(f"{base}/metrics", timeout=10) as response:
        content_type = response.headers["Content-Type"]
        text = response.read().decode("utf-8")
    assert content_type.startswith("text/plain"), content_type
    assert "version=0.0.4" in content_type, content_type
    families = {}
    for family in text_string_to_metric_families(text):
        assert family.name not in families, f"family {family.name} twice"
        families[family.name] = (
            family.type,
            [(s.name, s.labels, s.value) for s in family.samples],
        )
    return families


def value(families, family, name=None, **labels):
    kind, samples = families[family]
    name = name or family
    found = [v for (n, l, v) in samples if n == name and l == labels]
    assert len(found) == 1, f"{name}{labels}: {found} in {samples}"
    return found[0]


def get_status(base, path):
    try:
        with urllib.request.urlopen(f"{base}{path}", timeout=10) as response:
            json.load(response)
            return response.status
    except urllib.error.HTTPError as error:
        return error.code


def wait_for_nodes(base, count, timeout=15.0):
    deadline = time.monotonic() + timeout
    while True:
        families = scrape(base)
        if value(families, "candeck_nodes_online", bus="demo") == count:
            return families
        if time.monotonic() > deadline:
            raise AssertionError(f"the demo bus has not {count} nodes online: {families}")
        time.sleep(0.05)


def test_metrics_parse_with_the_prometheus_parser(gateway):
    before = wait_for_nodes(gateway, 3)
    for _ in range(READS):
        assert get_status(gateway, "/api/v1/buses/demo/nodes/1/od/0x1000/0") == 200
    assert get_status(gateway, "/api/v1/buses/demo/nodes/1/od/0x5FFF/0") == 422
    families = scrape(gateway)

    # Counter families are named without `_total` by the parser.
    expected = {
        "candeck_build_info": "gauge",
        "candeck_bus_up": "gauge",
        "candeck_bus_frames": "counter",
        "candeck_bus_bits": "counter",
        "candeck_bus_load_ratio": "gauge",
        "candeck_frame_log_lost_frames": "counter",
        "candeck_tpdo_malformed_frames": "counter",
        "candeck_nodes_known": "gauge",
        "candeck_nodes_online": "gauge",
        "candeck_sdo_transactions": "counter",
        "candeck_sdo_aborts": "counter",
        "candeck_sdo_timeouts": "counter",
        "candeck_sdo_duration_seconds": "histogram",
        "candeck_stream_clients": "gauge",
        "candeck_stream_messages": "counter",
        "candeck_stream_coalesced": "counter",
        "candeck_stream_lagged": "counter",
        "process_resident_memory_bytes": "gauge",
        "candeck_process_resident_memory_peak_bytes": "gauge",
        "process_start_time_seconds": "gauge",
    }
    for family, kind in expected.items():
        assert family in families, f"{family} missing: {sorted(families)}"
        assert families[family][0] == kind, f"{family}: {families[family][0]}"

    assert value(families, "candeck_bus_up", bus="demo") == 1
    for direction in ("rx", "tx"):
        frames = value(families, "candeck_bus_frames", "candeck_bus_frames_total",
                       bus="demo", direction=direction)
        assert frames > 0, direction
    load = value(families, "candeck_bus_load_ratio", bus="demo")
    assert 0 <= load < 1
    assert value(families, "candeck_nodes_known", bus="demo") == 3

    def node1(family, name=None):
        return value(families, family, name, bus="demo", node="1") - value(
            before, family, name, bus="demo", node="1"
        )

    assert node1("candeck_sdo_transactions", "candeck_sdo_transactions_total") >= READS + 1
    assert node1("candeck_sdo_aborts", "candeck_sdo_aborts_total") == 1
    assert node1("candeck_sdo_timeouts", "candeck_sdo_timeouts_total") == 0
    assert node1("candeck_sdo_duration_seconds", "candeck_sdo_duration_seconds_count") >= READS + 1

    # Node 1's histogram: buckets rising in le, cumulative, +Inf == _count.
    _, samples = families["candeck_sdo_duration_seconds"]
    buckets = [
        (float(labels["le"]), v)
        for (name, labels, v) in samples
        if name.endswith("_bucket") and labels["node"] == "1"
    ]
    assert len(buckets) >= 10
    assert buckets[0][0] <= 0.00025 and 2.5 <= buckets[-2][0]
    assert buckets[-1][0] == math.inf
    assert all(a[0] < b[0] and a[1] <= b[1] for a, b in zip(buckets, buckets[1:]))
    count = value(families, "candeck_sdo_duration_seconds",
                  "candeck_sdo_duration_seconds_count", bus="demo", node="1")
    total = value(families, "candeck_sdo_duration_seconds",
                  "candeck_sdo_duration_seconds_sum", bus="demo", node="1")
    assert buckets[-1][1] == count
    # Answers from an in-process device come within a second each.
    assert 0 < total < count

    assert value(families, "candeck_stream_clients") == 0
    rss = value(families, "process_resident_memory_bytes")
    peak = value(families, "candeck_process_resident_memory_peak_bytes")
    assert 1e6 < rss <= peak < 4e9
    started = value(families, "process_start_time_seconds")
    assert time.time() - 600 < started <= time.time() + 60
