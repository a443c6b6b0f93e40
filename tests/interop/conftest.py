"""Fixtures that run candeck's own binary for the interop tests.

The binary comes from CANDECK_BIN (scripts/test builds it); every server binds
port 0 on loopback and tells its port on its first line of output.
"""

import os
import re
import subprocess
import tempfile
import time

import pytest

BIN = os.environ.get("CANDECK_BIN", os.path.join("target", "debug", "candeck"))


def wait_until(predicate, timeout=15, what="the condition"):
    """Polls `predicate` every 0.1 s until it holds; fails saying `what`
    did not come within `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s")
        time.sleep(0.1)


class Process:
    """A candeck process whose stderr (the log) goes to a file we can read."""

    def __init__(self, args):
        self.log_file = tempfile.NamedTemporaryFile(prefix="candeck-", suffix=".log", delete=False)
        self.proc = subprocess.Popen(
            [BIN, *args],
            stdout=subprocess.PIPE,
            stderr=self.log_file,
            text=True,
        )

    def first_line(self, timeout=30):
        deadline = time.monotonic() + timeout
        line = self.proc.stdout.readline()
        if not line:
            raise AssertionError(f"candeck exited early: {self.log()}")
        assert time.monotonic() < deadline
        return line

    def log(self):
        with open(self.log_file.name, encoding="utf-8", errors="replace") as f:
            return f.read()

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        os.unlink(self.log_file.name)


class Vbus(Process):
    def __init__(self, *extra):
        super().__init__(["vbus", "--listen", "127.0.0.1:0", *extra])
        line = self.first_line()
        match = re.search(r"socketcand on ([0-9.]+):(\d+) channel (\S+)", line)
        assert match, f"unexpected first line: {line!r}"
        self.host, self.port, self.channel = match.group(1), int(match.group(2)), match.group(3)

    @property
    def spec(self):
        return f"socketcand:{self.host}:{self.port}/{self.channel}"


@pytest.fixture
def vbus():
    server = Vbus("--devices", "none")
    yield server
    server.stop()


@pytest.fixture
def unlimited_vbus():
    """A vbus without wire timing, for floods beyond what a 500 kbit/s bus
    carries (a test of the server, not of the wire)."""
    server = Vbus("--devices", "none", "--bitrate", "unlimited")
    yield server
    server.stop()
