"""Issue 32 on the tuning page (/nodes/{bus}/{node}/axes/{axis}/tune) in
headless Chromium against `candeck serve`'s demo: the step chart scales to
each response (a step of 3000 and one of 100 both fill the plot's height,
the peak inside it, the time axis the run's duration, the units shown),
and the run list keeps the gains each run used, after a reload too, so
that runs with P and 4 × P compare side by side."""

import os

from selenium.webdriver.common.by import By

from conftest import SHOTS

UMC = "/api/v1/buses/demo/nodes/1"
TUNE = "/nodes/demo/1/axes/1/tune"
# The latest run's colour on the chart (stepchart.js LATEST_COLOUR).
LATEST_RGB = (0x1D, 0x35, 0x57)


def wait_identified(server):
    server.wait_for("/api/v1/buses/demo/nodes",
                    lambda nodes: any(n["id"] == 1 and n["profile"] == "umc" for n in nodes),
                    "the UMC was not identified", timeout=15)


def open_page(browser, server):
    browser.driver.get(server.url + TUNE)
    browser.wait(lambda _: browser.js("return document.getElementById('tune-page').dataset.loaded === 'true'"),
                 message="the tuning page did not load")


def rows(browser):
    """The run list, newest first: each row's data attributes."""
    return browser.js("return [...document.querySelectorAll('#step-runs tbody tr')].map((tr) => ({...tr.dataset}))")


def run_step(browser, frm, to, hold_ms):
    before = len(rows(browser))
    for field, value in (("step-from", frm), ("step-to", to), ("step-hold", hold_ms)):
        element = browser.driver.find_element(By.ID, field)
        element.clear()
        element.send_keys(str(value))
    browser.driver.find_element(By.ID, "step-run").click()
    browser.wait(lambda _: len(rows(browser)) == before + 1 or
                 browser.js("return document.getElementById('step-metrics').dataset.state") == "failed",
                 timeout=30, message="the step test did not finish")
    state = browser.js("return document.getElementById('step-metrics').dataset.state")
    assert state == "done", browser.driver.find_element(By.ID, "step-metrics").text


def write_p(browser, p):
    field = browser.driver.find_element(By.ID, "gain-1")
    field.clear()
    field.send_keys(repr(p))
    browser.js("const w = document.getElementById('gains-written'); if (w) w.remove();")
    browser.driver.find_element(By.ID, "gains-write").click()
    browser.wait(lambda _: browser.js("return !!document.getElementById('gains-written')"), message="gains not written")


CHART = """
const c = document.getElementById('step-chart');
const [left, top, right, bottom] = c.dataset.plot.split(',').map(Number);
const [r0, g0, b0] = arguments[0];
const width = right - left;
const pixels = c.getContext('2d').getImageData(left, top, width, bottom - top).data;
// The rows of the plot where the latest run's line is drawn.
let first = null;
let last = null;
for (let y = 0; y < bottom - top; y += 1) {
  for (let x = 0; x < width; x += 1) {
    const i = (y * width + x) * 4;
    if (pixels[i + 3] > 200 && Math.abs(pixels[i] - r0) + Math.abs(pixels[i + 1] - g0) + Math.abs(pixels[i + 2] - b0) < 40) {
      if (first === null) first = y;
      last = y;
      break;
    }
  }
}
const runs = JSON.parse(localStorage.getItem(Object.keys(localStorage).find((k) => k.startsWith('candeck.tune.runs:'))));
return {
  yMin: Number(c.dataset.yMin), yMax: Number(c.dataset.yMax),
  tMin: Number(c.dataset.tMin), tMax: Number(c.dataset.tMax),
  unit: c.dataset.unit, drawn: Number(c.dataset.runs),
  height: bottom - top, first, last,
  runs,
};
"""


def check_scaled(browser, frm, to):
    """The chart of the latest run (frm → to), drawn with the earlier runs
    of the same step, fills the plot's height with their response, clips
    nothing, and spans their duration."""
    chart = browser.js(CHART, list(LATEST_RGB))
    # The runs as the gateway answered them (the page stores them so); the
    # last four of this step are drawn.
    drawn = [r for r in chart["runs"] if r["loop"] == "velocity" and r["from"] == frm and r["to"] == to][-4:]
    assert drawn and chart["runs"][-1] == drawn[-1], "the latest run is not this step"
    samples = [s for r in drawn for s in r["samples"]]
    assert samples, "the stored runs have no samples"
    assert chart["drawn"] == len(drawn), chart["drawn"]
    low = min([frm, to] + [min(s[1], s[2]) for s in samples])
    high = max([frm, to] + [max(s[1], s[2]) for s in samples])
    span = chart["yMax"] - chart["yMin"]
    # Nothing outside the axis: the peak (an overshoot) and the trough.
    assert chart["yMin"] < low and high < chart["yMax"], (chart["yMin"], low, high, chart["yMax"])
    # The step itself fills most of the height, a small one as a large one.
    assert abs(to - frm) / span > 0.75, f"a step of {abs(to - frm)} is drawn on an axis of {span}"
    # The time axis is the runs' duration.
    assert chart["tMin"] == min(s[0] for s in samples) and chart["tMax"] == max(s[0] for s in samples), chart
    assert chart["unit"] == "vl units", chart["unit"]
    # As drawn: the latest run's line covers most of the plot's height and
    # stays off its top and bottom edges.
    assert chart["first"] is not None, "the latest run's line is not drawn"
    covered = (chart["last"] - chart["first"]) / chart["height"]
    assert covered > 0.7, f"the response spans {covered:.0%} of the plot's height"
    assert chart["first"] > 1 and chart["last"] < chart["height"] - 2, chart
    return chart


def test_the_chart_scales_to_each_step_and_the_runs_keep_their_gains(browser, server):
    wait_identified(server)
    # The demo's UMC clips VL's target to 0x6046.2 (1000): raised, so that
    # a step of 3000 is one.
    server.request("PUT", f"{UMC}/od/0x6046/2", {"value": 3000})
    server.post(f"{UMC}/axes/1/state", {"target": "operation_enabled"})
    open_page(browser, server)
    # The velocity loop's factory P (0x4041.1, Q15.16), and four times it.
    p = server.get(f"{UMC}/od/0x4041/1")["value"] / 65536
    assert p > 0, p
    browser.wait(lambda _: browser.js("return document.getElementById('step-unit').textContent") == "vl units",
                 message="the step's unit is not shown")

    # A large step with P, then a small one with 4 × P: the small one is
    # not flattened by the large one before it (which is not drawn with
    # it: another step).
    run_step(browser, 0, 3000, 600)
    check_scaled(browser, 0, 3000)
    write_p(browser, 4 * p)
    run_step(browser, 0, 100, 300)
    check_scaled(browser, 0, 100)
    assert browser.js("return document.getElementById('step-chart').dataset.runs") == "1"

    # The large step again with 4 × P: drawn over the run with P.
    run_step(browser, 0, 3000, 600)
    check_scaled(browser, 0, 3000)
    assert browser.js("return document.getElementById('step-chart').dataset.runs") == "2"

    def listed():
        return [(r["loop"], int(r["from"]), int(r["to"]), round(float(r["p"]) / p, 2), r["drawn"]) for r in rows(browser)]

    expected = [
        ("velocity", 0, 3000, 4.0, "true"),
        ("velocity", 0, 100, 4.0, "false"),
        ("velocity", 0, 3000, 1.0, "true"),
    ]
    assert listed() == expected
    # The rows show the gains as text too, side by side.
    cells = browser.js("return [...document.querySelectorAll('#step-runs tbody tr')].map((tr) => tr.cells[4].textContent)")
    assert [round(float(c) / p, 1) for c in cells] == [4.0, 4.0, 1.0], cells

    # A reload keeps the runs, their gains and the chart.
    open_page(browser, server)
    browser.wait(lambda _: len(rows(browser)) == 3, message="the runs were not kept")
    assert listed() == expected
    assert browser.js("return document.getElementById('step-chart').dataset.runs") == "2"
    check_scaled(browser, 0, 3000)
    # A picture of the chart and the list, for a person to look at.
    os.makedirs(SHOTS, exist_ok=True)
    browser.driver.find_element(By.ID, "step-chart").screenshot(os.path.join(SHOTS, "tuning-runs-chart.png"))
    browser.driver.find_element(By.ID, "step-runs").screenshot(os.path.join(SHOTS, "tuning-runs-list.png"))

    # Clear runs empties the list and the chart, for good.
    browser.driver.find_element(By.ID, "runs-clear").click()
    assert rows(browser) == []
    assert browser.js("return document.getElementById('step-chart').dataset.runs") == "0"
    open_page(browser, server)
    assert rows(browser) == []
