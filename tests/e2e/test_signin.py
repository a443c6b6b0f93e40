"""Signing in to a gateway that asks for tokens, in headless Chromium: the
overview without a token shows the sign-in form (after one 401, the
whoami, which the browser logs and this test takes out and checks), a
wrong token is told so, the right one lists the nodes over REST and the
stream, and the top bar names the token until it signs out."""

import os
import re
import tempfile
import time
import urllib.error
import urllib.request

import pytest

from conftest import Server, free_port
from test_overview import connection, wait_for_demo_nodes

OPERATOR = "line-plc-5b0e9f2c41d7a8e3"
ADMIN = "engineer-c7d1a92e46b03f58"
CONFIG = f"""
[[tokens]]
name = "line-plc"
role = "operator"
token = "{OPERATOR}"

[[tokens]]
name = "engineer"
role = "admin"
token = "{ADMIN}"
"""
WHOAMI_401 = [
    re.compile(r"console: http://127\.0\.0\.1:\d+/api/v1/auth/whoami - Failed to load resource: "
               r"the server responded with a status of 401 \(Unauthorized\)"),
    re.compile(r"request: http://127\.0\.0\.1:\d+/api/v1/auth/whoami answered 401"),
]


class TokenServer(Server):
    """The conftest's server with a config file of tokens; its own requests
    carry the admin token."""

    def __init__(self, port):
        self.config = tempfile.NamedTemporaryFile("w", prefix="candeck-auth-", suffix=".toml", delete=False)
        self.config.write(CONFIG)
        self.config.close()
        super().__init__(port, args=["--config", self.config.name], token=ADMIN)


@pytest.fixture
def server():
    # Overrides the conftest's: the browser fixture gets this one.
    s = TokenServer(free_port())
    s.start()
    yield s
    s.stop()
    os.unlink(s.log_file.name)
    os.unlink(s.config.name)


def take_whoami_401(browser):
    """Drains the browser's log and asserts that it holds the whoami's 401
    and nothing else."""
    found = browser.drain()
    assert len(found) == len(WHOAMI_401), found
    for pattern in WHOAMI_401:
        assert any(pattern.fullmatch(line) for line in found), (pattern.pattern, found)


def signin_visible(browser):
    return browser.js("const d = document.getElementById('signin'); return !!(d && d.open)")


def sign_in(browser, token, remember=False):
    field = browser.driver.find_element("id", "signin-token")
    field.send_keys(token)
    if remember:
        browser.driver.find_element("id", "signin-remember").click()
    browser.driver.find_element("css selector", "#signin button[type=submit]").click()


def test_without_a_token_the_overview_asks_for_one_and_shows_no_data(server, browser):
    # Without a token the API refuses: what the page must ask for.
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(server.url + "/api/v1/buses/demo/nodes", timeout=10)
    assert refused.value.code == 401
    assert refused.value.headers["WWW-Authenticate"].startswith("Bearer")

    browser.driver.get(server.url + "/")
    browser.wait(lambda _: signin_visible(browser), message="no sign-in form")
    time.sleep(0.5)  # anything else the page might ask would be logged by now
    take_whoami_401(browser)
    # Nothing was asked in vain: no data, no stream.
    assert browser.js("return document.querySelectorAll('#nodes tbody tr[data-node]').length") == 0
    assert connection(browser) == "connecting"
    assert browser.js("return document.activeElement.id") == "signin-token"
    assert browser.js("return document.getElementById('user')") is None


def test_signing_in_lists_the_nodes_and_names_the_token_until_sign_out(server, browser):
    browser.driver.get(server.url + "/")
    browser.wait(lambda _: signin_visible(browser), message="no sign-in form")
    take_whoami_401(browser)

    # A token the gateway does not know: said in words, the form stays.
    sign_in(browser, "not-a-token-of-this-gateway")
    browser.wait(
        lambda _: browser.js("const e = document.getElementById('signin-error'); return e && !e.hidden && e.textContent"),
        message="no error for a wrong token",
    )
    assert "does not know this token" in browser.js("return document.getElementById('signin-error').textContent")
    take_whoami_401(browser)

    sign_in(browser, OPERATOR)
    rows = wait_for_demo_nodes(browser)
    assert sorted(int(i) for i in rows) == [1, 2, 3]
    browser.wait(lambda _: connection(browser) == "connected", message="the stream did not connect with the token")
    assert not signin_visible(browser)
    user = browser.js(
        "const u = document.getElementById('user');"
        "return [u.querySelector('.user-name').textContent, u.querySelector('.role').textContent,"
        " u.querySelector('.signout').textContent]"
    )
    assert user == ["line-plc", "operator", "Sign out"], user
    # The token lives for this tab only (no "remember").
    assert browser.js("return sessionStorage.getItem('candeck.token')") == OPERATOR
    assert browser.js("return localStorage.getItem('candeck.token')") is None
    browser.check()

    browser.driver.find_element("css selector", "#user .signout").click()
    browser.wait(lambda _: signin_visible(browser), message="no sign-in form after signing out")
    assert browser.js("return sessionStorage.getItem('candeck.token')") is None
    take_whoami_401(browser)
    # Signed in again for the screenshot, with "remember".
    sign_in(browser, OPERATOR, remember=True)
    wait_for_demo_nodes(browser)
    browser.wait(lambda _: connection(browser) == "connected", message="the stream did not connect")
    assert browser.js("return localStorage.getItem('candeck.token')") == OPERATOR
