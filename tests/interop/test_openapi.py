"""schemathesis against the OpenAPI document candeck serves.

Requests are generated from /api/openapi.json (its examples, then fuzzed
values) and sent to `candeck serve` on the demo bus. Every answer must be
no 5xx other than the documented 502/503/504, must have a status the
operation documents, and must match the documented schema.

Two runs on one server: first every operation but NMT and /sim, then
those. NMT commands and /sim removals change the devices for whatever runs
after them (a node stopped or unplugged answers no SDO: a documented 504,
which the not_a_server_error check counts as a failure), so they go last,
where only operations that touch no SDO follow them.

The coverage phase is left out: on CPython 3.11.7 hypothesis crashes in it
("AST constructor recursion depth mismatch", a CPython bug fixed in later
3.11 releases) before a request is sent. CANDECK_SCHEMATHESIS_EXAMPLES sets
the examples per operation (default 25) and CANDECK_SCHEMATHESIS_SEED the
seed (default fixed, so that a failure can be replayed).
"""

import os
import re
import subprocess
import sys

import pytest

from conftest import Process


@pytest.fixture
def demo_server():
    server = Process(["serve", "--listen", "127.0.0.1:0"])
    line = server.first_line()
    match = re.search(r"serving (http://[0-9.]+:\d+)/", line)
    assert match, f"unexpected first line: {line!r}"
    yield match.group(1)
    server.stop()


DISRUPTIVE = r"/nmt$|/sim/nodes"
# The gateway's own CAN controller taken bus-off (or given bit errors): every
# request that sends on the bus answers 503 `bus_down` while it lasts, as
# documented, so it runs alone, at the very end.
OFF_THE_BUS = r"\}/sim/faults$"
# A node-ID change (0x2040, save, reset) moves the demo's node to another
# ID for good: every later request to its old ID has no device to answer.
# Its behaviour is tested in src/api/tests/lss.rs and tests/e2e/test_node_ids.py.
MOVES_A_NODE = r"/node-id$"


def run_schemathesis(url, cwd, *selection):
    schemathesis = os.path.join(os.path.dirname(sys.executable), "schemathesis")
    examples = os.environ.get("CANDECK_SCHEMATHESIS_EXAMPLES", "25")
    seed = os.environ.get("CANDECK_SCHEMATHESIS_SEED", "20261123")
    result = subprocess.run(
        [
            schemathesis,
            "run",
            f"{url}/api/openapi.json",
            *selection,
            "--checks",
            "not_a_server_error,status_code_conformance,content_type_conformance,"
            "response_schema_conformance",
            "--phases",
            "examples,fuzzing",
            "--max-examples",
            examples,
            "--seed",
            seed,
            "--workers",
            "2",
            "--request-timeout",
            "10",
            "--no-color",
        ],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=900,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    tested = re.search(r"Tested: (\d+)", output)
    assert tested, output
    return int(tested.group(1))


def test_schemathesis_finds_no_server_error_and_no_schema_violation(demo_server, tmp_path):
    first = run_schemathesis(
        demo_server, tmp_path, "--exclude-path-regex", f"{DISRUPTIVE}|{OFF_THE_BUS}|{MOVES_A_NODE}"
    )
    last = run_schemathesis(demo_server, tmp_path, "--include-path-regex", DISRUPTIVE)
    off = run_schemathesis(demo_server, tmp_path, "--include-path-regex", OFF_THE_BUS)
    assert first >= 25, first
    assert last >= 6, last
    assert off >= 2, off
