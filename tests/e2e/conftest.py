"""Fixtures for the dashboard's end-to-end tests: the real `candeck serve`
binary and headless Chromium driven through chromedriver (Debian's
`chromium` and `chromium-driver`, which scripts/test installs).

Every test gets a fresh browser profile, and at its end a screenshot in
target/e2e/<test>.png and a check of everything the browser logged: any
console error, any request that failed or answered 4xx/5xx fails the test.
"""

import json
import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.error
import urllib.request

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.support.ui import WebDriverWait

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BIN = os.environ.get("CANDECK_BIN", os.path.join(ROOT, "target", "debug", "candeck"))
SHOTS = os.path.join(ROOT, "target", "e2e")
CHROMIUM = os.environ.get("CANDECK_CHROMIUM") or shutil.which("chromium")
CHROMEDRIVER = os.environ.get("CANDECK_CHROMEDRIVER") or shutil.which("chromedriver")
# As ARCHITECTURE.md lists them; --user-data-dir (empty, per test) is added.
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """`candeck serve` on the demo bus, on a port of our choosing so that a
    test can stop it and start it again on the same address."""

    def __init__(self, port, args=(), token=None):
        """`args`: more arguments of `candeck serve`; `token`: sent as a
        bearer token with the test's own requests."""
        self.port = port
        self.url = f"http://127.0.0.1:{port}"
        self.args = list(args)
        self.token = token
        self.log_file = tempfile.NamedTemporaryFile(prefix="candeck-e2e-", suffix=".log", delete=False)
        self.proc = None

    def start(self):
        self.proc = subprocess.Popen(
            [BIN, "serve", "--listen", f"127.0.0.1:{self.port}", *self.args],
            stdout=subprocess.PIPE,
            stderr=self.log_file,
            text=True,
        )
        line = self.proc.stdout.readline()
        if not re.search(r"serving http://127\.0\.0\.1:\d+/", line or ""):
            raise AssertionError(f"candeck did not start: {line!r}\n{self.log()}")
        # The demo devices boot after the server listens: wait for the three
        # to be identified (until then a node's profile is `generic`).
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            nodes = self.get("/api/v1/buses/demo/nodes")
            if len(nodes) >= 3 and all(n["identification"]["state"] == "done" for n in nodes):
                return
            time.sleep(0.1)
        raise AssertionError(f"the demo nodes did not appear: {self.log()}")

    def kill(self):
        """Ends the process at once, as a crash or a power cut would."""
        self.proc.kill()
        self.proc.wait()

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def log(self):
        with open(self.log_file.name, encoding="utf-8", errors="replace") as f:
            return f.read()

    def request(self, method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.url + path, data=data, method=method)
        if self.token:
            req.add_header("authorization", f"Bearer {self.token}")
        if data is not None:
            req.add_header("content-type", "application/json")
        try:
            with urllib.request.urlopen(req, timeout=30) as resp:
                text = resp.read().decode()
        except urllib.error.HTTPError as err:
            raise AssertionError(f"{method} {path}: {err.code} {err.read().decode()}") from None
        return json.loads(text) if text else None

    def get(self, path):
        return self.request("GET", path)

    def post(self, path, body=None):
        return self.request("POST", path, {} if body is None else body)


@pytest.fixture
def server():
    s = Server(free_port())
    s.start()
    yield s
    s.stop()
    os.unlink(s.log_file.name)


class Browser:
    """A headless Chromium and what it logged, checked as the test goes."""

    def __init__(self):
        if not (CHROMIUM and CHROMEDRIVER):
            pytest.fail(
                "the end-to-end tests need Chromium and chromedriver "
                "(Debian: apt-get install chromium chromium-driver; scripts/test does it as root), "
                "or CANDECK_CHROMIUM and CANDECK_CHROMEDRIVER naming them"
            )
        self.profile = tempfile.mkdtemp(prefix="candeck-chromium-")
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in CHROMIUM_FLAGS:
            options.add_argument(flag)
        options.add_argument(f"--user-data-dir={self.profile}")
        options.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
        self.driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
        self.driver.set_window_size(1280, 800)
        self.requests = {}  # requestId -> url, from the performance log
        self.problems = []
        # Chromium's own new-tab page, open before the test navigates,
        # tries a host it cannot resolve here: leave it, and what it
        # logged, behind before the test starts.
        self.driver.get("about:blank")
        self.drain()

    def drain(self):
        """What went wrong since the last call: console errors, failed
        requests and 4xx/5xx answers, as readable lines."""
        found = []
        for entry in self.driver.get_log("browser"):
            if entry["level"] == "SEVERE":
                found.append(f"console: {entry['message']}")
        for entry in self.driver.get_log("performance"):
            message = json.loads(entry["message"])["message"]
            method, params = message.get("method"), message.get("params", {})
            if method == "Network.requestWillBeSent":
                self.requests[params["requestId"]] = params["request"]["url"]
            elif method == "Network.responseReceived":
                status = params["response"]["status"]
                if status >= 400:
                    found.append(f"request: {params['response']['url']} answered {status}")
            elif method == "Network.loadingFailed" and not params.get("canceled"):
                url = self.requests.get(params["requestId"], params["requestId"])
                found.append(f"request: {url} failed: {params.get('errorText')}")
        return found

    def check(self):
        self.problems.extend(self.drain())

    def wait(self, condition, timeout=15, message=""):
        return WebDriverWait(self.driver, timeout, poll_frequency=0.1).until(
            lambda d: condition(d), message
        )

    def phone(self):
        """Emulates a phone's screen: 390 px wide, touch, twice the pixels."""
        self.driver.execute_cdp_cmd(
            "Emulation.setDeviceMetricsOverride",
            {"width": 390, "height": 844, "deviceScaleFactor": 2, "mobile": True},
        )

    def loaded_files(self):
        """[{url, bytes}]: the page and every file of its origin it loaded
        but the API's, decoded sizes: what issue 7's weight counts."""
        return self.js(
            """
        const nav = performance.getEntriesByType('navigation')[0];
        const files = [{url: nav.name, bytes: nav.decodedBodySize}];
        for (const r of performance.getEntriesByType('resource')) {
          const url = new URL(r.name);
          if (url.origin === location.origin && !url.pathname.startsWith('/api/')) {
            files.push({url: url.pathname, bytes: r.decodedBodySize});
          }
        }
        return files;
            """
        )

    def js(self, script, *args):
        return self.driver.execute_script(script, *args)

    def quit(self):
        self.driver.quit()
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture
def browser(request, server):
    # Asks for the server so that it is torn down after the screenshot: a
    # test's picture shows the page as the test left it, still connected.
    b = Browser()
    yield b
    try:
        os.makedirs(SHOTS, exist_ok=True)
        b.driver.save_screenshot(os.path.join(SHOTS, f"{request.node.name}.png"))
        b.check()
    finally:
        b.quit()
    assert not b.problems, "the browser reported:\n" + "\n".join(b.problems)
