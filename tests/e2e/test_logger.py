"""The data logger page in headless Chromium against `candeck serve` on the
demo bus: channels picked by name, a logger started, its live chart filled
to the end, zoom, pan, the cursor's read-out, the CSV download, deletion,
and the page's weight."""

from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select


def chart(browser):
    return browser.js(
        """const c = document.getElementById('chart');
           return {rows: Number(c.dataset.rows || 0), from: Number(c.dataset.from), to: Number(c.dataset.to)};"""
    )


def add(browser, text, index):
    search = browser.driver.find_element(By.ID, "pick-search")
    search.clear()
    search.send_keys(text)
    selector = f'#pick-results li[data-index="{index}"] button'
    browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, selector), message=f"{text} not found")
    browser.driver.find_element(By.CSS_SELECTOR, selector).click()


def log_one_position_for_2_s(server, browser):
    """Node 1's 0x6064 every 20 ms for 2 s, started from the page and
    waited for; the finished logger's status."""
    browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, '#pick-node option[value="1"]'), message="no nodes")
    Select(browser.driver.find_element(By.ID, "pick-node")).select_by_value("1")
    add(browser, "a1_pc_Position_actual", "0x6064")
    for field, value in (("period", "20"), ("duration", "2")):
        element = browser.driver.find_element(By.ID, field)
        element.clear()
        element.send_keys(value)
    browser.driver.find_element(By.ID, "start").click()
    browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, '#loggers tr[data-state="done"]'), timeout=20,
                 message="the logger did not finish")
    logger = server.get("/api/v1/loggers")[0]
    assert logger["samples"] >= 50, logger
    return logger


def test_a_logger_is_picked_started_charted_and_downloaded(server, browser):
    browser.driver.get(server.url + "/loggers")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")
    assert browser.js("return document.querySelector('nav a[aria-current=\"page\"]').innerText") == "Logger"
    browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, '#pick-node option[value="1"]'), message="no nodes")
    Select(browser.driver.find_element(By.ID, "pick-node")).select_by_value("1")
    add(browser, "a1_pc_Position_actual", "0x6064")
    add(browser, "a1_pv_Velocity_actual", "0x606C")
    assert browser.driver.find_element(By.ID, "channel-count").text == "2 of 16"
    period = browser.driver.find_element(By.ID, "period")
    period.clear()
    period.send_keys("20")
    duration = browser.driver.find_element(By.ID, "duration")
    duration.clear()
    duration.send_keys("3")
    browser.driver.find_element(By.ID, "start").click()

    browser.wait(lambda _: chart(browser)["rows"] > 10, message="the chart got no live rows")
    browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, '#loggers tr[data-state="done"]'), timeout=20,
                 message="the logger did not finish")
    logger = server.get("/api/v1/loggers")[0]
    assert logger["state"] == "done", logger
    assert [c["index"] for c in logger["channels"]] == ["0x6064", "0x606C"]
    browser.wait(lambda _: chart(browser)["rows"] == logger["samples"],
                 message=f"the chart holds {chart(browser)['rows']} of {logger['samples']} rows")
    assert logger["samples"] >= 100, logger

    # Zoom in around the middle, then everything again.
    whole = chart(browser)
    assert whole["from"] == 0 and whole["to"] > 2000, whole
    browser.driver.find_element(By.ID, "zoom-in").click()
    browser.wait(lambda _: chart(browser)["to"] - chart(browser)["from"] < (whole["to"] - whole["from"]) * 0.6,
                 message="zoom in did not narrow the view")
    canvas = browser.driver.find_element(By.ID, "chart")
    zoomed = chart(browser)
    # A drag to the right shows earlier rows.
    ActionChains(browser.driver).move_to_element(canvas).click_and_hold().move_by_offset(200, 0).release().perform()
    browser.wait(lambda _: chart(browser)["from"] < zoomed["from"] - 50, message="the drag did not pan")
    browser.driver.find_element(By.ID, "zoom-reset").click()
    browser.wait(lambda _: chart(browser)["from"] == 0, message="reset did not show everything")

    # The cursor reads out the nearest row's values.
    ActionChains(browser.driver).move_to_element(canvas).move_by_offset(50, 0).perform()
    browser.wait(lambda _: browser.driver.find_element(By.ID, "readout").text.startswith("t = "),
                 message="no read-out under the cursor")
    readout = browser.driver.find_element(By.ID, "readout").text
    assert "demo/1/a1_pc_Position_actual_value = " in readout, readout

    download = browser.driver.find_element(By.ID, "download")
    download.click()
    browser.wait(lambda _: download.get_attribute("data-state") == "done", message="the CSV did not download")

    browser.driver.find_element(By.CSS_SELECTOR, f'#loggers tr[data-id="{logger["id"]}"] button.delete').click()
    browser.wait(lambda d: not d.find_elements(By.CSS_SELECTOR, f'#loggers tr[data-id="{logger["id"]}"]'),
                 message="the deleted logger is still listed")
    assert server.get("/api/v1/loggers") == []
    assert browser.js("return document.getElementById('chart-panel').hidden")

    total = sum(f["bytes"] for f in browser.loaded_files())
    assert total < 300 * 1024, total
    browser.check()
    assert not browser.problems, browser.problems


def test_rows_streamed_while_the_csv_is_read_are_not_lost(server, browser):
    """The chart is filled from the CSV while the stream goes on; a logger
    that finishes while the CSV is read must still end with every row (the
    stream's last rows came during that read and no message follows them)."""
    browser.driver.get(server.url + "/loggers")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")
    # Every CSV answer is held back 4 s after it was read: the first fill
    # reads the logger near its start and is seen after the logger's end.
    browser.js(
        """const real = window.fetch;
           window.fetch = async (...args) => {
             const response = await real(...args);
             if (!String(args[0]).endsWith('/data.csv')) return response;
             const text = await response.text();
             await new Promise((resolve) => setTimeout(resolve, 4000));
             return new Response(text, {status: response.status, headers: response.headers});
           };"""
    )
    logger = log_one_position_for_2_s(server, browser)
    browser.wait(lambda _: chart(browser)["rows"] == logger["samples"], timeout=20,
                 message=f"the chart holds {chart(browser)['rows']} of {logger['samples']} rows")
    browser.driver.find_element(By.CSS_SELECTOR, f'#loggers tr[data-id="{logger["id"]}"] button.delete').click()
    browser.wait(lambda d: not d.find_elements(By.CSS_SELECTOR, f'#loggers tr[data-id="{logger["id"]}"]'),
                 message="the deleted logger is still listed")
    browser.check()
    assert not browser.problems, browser.problems


# Before the page's scripts run: a stream that loses the logger's messages
# after its first rows, and whose last message (the logger done) carries no
# rows, the gateway having published them in a message coalesced away.
COALESCING_STREAM = """
const Real = window.WebSocket;
window.WebSocket = class extends Real {
  set onmessage(handler) {
    super.onmessage = (event) => {
      const message = JSON.parse(event.data);
      const data = message.data;
      if (!String(message.topic).startsWith('loggers/') || !data) return handler(event);
      if (data.state === 'running' && data.first > 0) return undefined;
      if (data.state === 'done') {
        data.first = data.samples;
        data.rows = [];
        return handler(new MessageEvent('message', {data: JSON.stringify(message)}));
      }
      return handler(event);
    };
  }
};
"""


def test_a_finished_loggers_last_message_without_rows_still_completes_the_chart(server, browser):
    """The gateway's last message of a logger may carry no rows: the rows
    it publishes every 100 ms went in a message the stream replaced by that
    last one. Its `first` says rows are missing; the page reads the CSV."""
    browser.driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": COALESCING_STREAM})
    browser.driver.get(server.url + "/loggers")
    browser.wait(lambda _: browser.js("return document.getElementById('connection').dataset.state") == "connected",
                 message="the stream did not connect")
    logger = log_one_position_for_2_s(server, browser)
    browser.wait(lambda _: chart(browser)["rows"] == logger["samples"],
                 message=f"the chart holds {chart(browser)['rows']} of {logger['samples']} rows")
    # The rows the CSV filled in have their values (its time_utc column is
    # no channel's): the cursor in the middle, past the stream's first rows.
    ActionChains(browser.driver).move_to_element(browser.driver.find_element(By.ID, "chart")).perform()
    browser.wait(lambda _: browser.driver.find_element(By.ID, "readout").text.startswith("t = "),
                 message="no read-out under the cursor")
    readout = browser.driver.find_element(By.ID, "readout").text
    assert "demo/1/a1_pc_Position_actual_value = " in readout and "= —" not in readout, readout
    browser.check()
    assert not browser.problems, browser.problems
