"""Fixtures for the dashboard's end-to-end tests: the real `candeck serve`
binary and headless Chromium driven through chromedriver (Debian's
`chromium` and `chromium-driver`, which scripts/test installs).

One Chromium serves every test of a test process (starting one took about
a second of the machine's time, a third of an average test); each test gets
it as new: a new tab, no cookies, an empty cache, nothing logged, and at its
end the storage of its server's origin cleared. At a test's end: a
screenshot in target/e2e/<test>.png and a check of everything the browser
logged: any console error, any request that failed or answered 4xx/5xx
fails the test.
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
from selenium.common.exceptions import WebDriverException
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
        self.wait_for(
            "/api/v1/buses/demo/nodes",
            lambda nodes: len(nodes) >= 3 and all(n["identification"]["state"] == "done" for n in nodes),
            "the demo nodes did not appear",
        )

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

    def wait_for(self, path, done, what, timeout=20):
        """GETs `path` until `done(answer)` (at most `timeout` s), and
        returns that answer; else fails with `what`, the last answer and
        the server's log."""
        deadline = time.monotonic() + timeout
        while True:
            answer = self.get(path)
            if done(answer):
                return answer
            if time.monotonic() >= deadline:
                raise AssertionError(f"{what}: {answer}\n{self.log()}")
            time.sleep(0.05)

    def wait_operational(self, bus="demo"):
        """Waits for the network manager to have started the bus's nodes:
        identified nodes are pre-operational until then."""
        self.wait_for(f"/api/v1/buses/{bus}/nodes", lambda nodes: all(n["nmt"] == "operational" for n in nodes),
                      f"the nodes of {bus} were not started")

    def wait_ready(self, bus="demo"):
        """Waits for the machine to be `ready`: its first scan of the bus
        over (about 1.5 s after the start, the absent node IDs' probes
        timing out), its nodes booted, and the change audited."""
        self.wait_for(f"/api/v1/buses/{bus}/machine", lambda machine: machine["state"] == "ready",
                      f"the machine of {bus} is not ready")

@pytest.fixture
def server():
    s = Server(free_port())
    s.start()
    s.wait_operational()
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
        self.requests = {}  # requestId -> url, from the performance log
        self.problems = []
        self.tolerated = []
        self.fresh()

    def fresh(self):
        """As new for the next test. A new tab: what the last test set in
        its own (a device emulation, a script run on every page) goes with
        it. No cookies (they are per host, not per port), an empty cache,
        and what was logged until now left behind: Chromium's own new-tab
        page tries a host it cannot resolve here."""
        last = self.driver.current_window_handle
        self.driver.switch_to.new_window("tab")
        tab = self.driver.current_window_handle
        self.driver.switch_to.window(last)
        self.driver.close()
        self.driver.switch_to.window(tab)
        self.driver.set_window_size(1280, 800)
        self.driver.execute_cdp_cmd("Network.clearBrowserCookies", {})
        self.driver.execute_cdp_cmd("Network.clearBrowserCache", {})
        self.driver.get("about:blank")
        self.drain()
        self.requests = {}
        self.problems = []
        self.tolerated = []

    def tolerate(self, pattern):
        """From now on, a logged problem matching the regular expression
        `pattern` is expected, not a failure: for the one answer a test
        provokes on purpose (a read in flight when the node is stopped).
        What was logged before is checked first, without it."""
        self.check()
        self.tolerated.append(re.compile(pattern))

    def forget(self, origin):
        """Leaves the page and clears what `origin` stored (a sign-in kept
        in local storage): the next test's server may get the same port."""
        self.driver.get("about:blank")
        self.driver.execute_cdp_cmd("Storage.clearDataForOrigin", {"origin": origin, "storageTypes": "all"})

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
        self.problems.extend(
            line for line in self.drain() if not any(p.search(line) for p in self.tolerated)
        )

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
        try:
            self.driver.quit()
        except WebDriverException:
            pass  # already gone
        shutil.rmtree(self.profile, ignore_errors=True)


@pytest.fixture(scope="session")
def chromium():
    """The test process's Chromium, started at its first test."""
    holder = {}
    yield holder
    if "browser" in holder:
        holder["browser"].quit()


@pytest.fixture
def browser(request, chromium, server):
    # Asks for the server so that it is torn down after the screenshot: a
    # test's picture shows the page as the test left it, still connected.
    b = chromium.get("browser")
    if b is not None:
        try:
            b.fresh()
        except WebDriverException:
            b.quit()  # gone (crashed): a new one
            b = None
    if b is None:
        b = chromium["browser"] = Browser()
    yield b
    try:
        os.makedirs(SHOTS, exist_ok=True)
        b.driver.save_screenshot(os.path.join(SHOTS, f"{request.node.name}.png"))
        b.check()
    finally:
        try:
            b.forget(server.url)
        except WebDriverException:
            chromium.pop("browser", None)
            b.quit()
    assert not b.problems, "the browser reported:\n" + "\n".join(b.problems)
