"""The device descriptions page (/eds) and the EDS assignment of the node
page, in headless Chromium against `candeck serve` on the demo bus: the
catalog with its built-in files, a file uploaded with its problems shown
(file:line), assigned to a node on the node page and listed as used by it,
then unassigned and deleted."""

import os

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from conftest import ROOT

IPOS = os.path.join(ROOT, "tests", "data", "eds-corpus", "synthetic", "technosoft-ipos-like.eds")
NAME = "technosoft-ipos-like.eds"


def open_eds(browser, server):
    browser.driver.get(f"{server.url}/eds")
    browser.wait(lambda _: browser.js("return document.getElementById('eds-page').dataset.loaded === 'true'"),
                 message="the catalog was not shown")


def row_text(browser, name, cell):
    return browser.js(
        "const row = document.querySelector(`#eds tr[data-name='${arguments[0]}']:not(.problems)`);"
        "return row ? row.querySelector(arguments[1]).innerText.trim() : null",
        name, cell,
    )


def open_node(browser, server, node):
    browser.driver.get(f"{server.url}/nodes/demo/{node}")
    browser.wait(lambda _: browser.js(
        "return document.querySelectorAll('#eds-file option').length > 0 && !!document.getElementById('eds-current').textContent"),
        message="the EDS assignment was not shown")


def test_a_file_is_uploaded_shown_with_its_problems_assigned_and_deleted(browser, server):
    open_eds(browser, server)
    assert browser.js("return document.querySelector(`#eds tr[data-name='umc1bds32.eds']`).dataset.source") == "built_in"
    assert row_text(browser, "io401.eds", ".warnings") == "0"
    # Issue 31 point 6: the catalog names each file's product and vendor
    # ([DeviceInfo]), not only its hex identity.
    identity = row_text(browser, "umc1bds32.eds", "td[data-label='Identity']")
    assert "UMC1BDS32" in identity and "UniSwarm SASU" in identity and "0x000004A2" in identity, identity
    assert "JMC CANopen stepper drive" in row_text(browser, "jmc_stepper.eds", "td[data-label='Identity']")

    # Upload: the name comes from the file; its warning is listed by line.
    browser.driver.find_element(By.ID, "upload-file").send_keys(IPOS)
    assert browser.driver.find_element(By.ID, "upload-name").get_attribute("value") == NAME
    browser.driver.find_element(By.ID, "upload").click()
    browser.wait(lambda _: row_text(browser, NAME, ".warnings") == "1", message="the upload is not listed")
    assert browser.js(f"return document.querySelector(`#eds tr[data-name='{NAME}']`).dataset.source") == "uploaded"
    problems = browser.js(f"return document.querySelector(`#eds tr.problems[data-name='{NAME}']`).innerText")
    assert f"{NAME}:16" in problems and "matches no device by identity" in problems, problems
    assert NAME in browser.driver.find_element(By.ID, "upload-result").text

    # Assigned to node 2 on its page: the node is described by it.
    open_node(browser, server, 2)
    assert browser.js("return document.getElementById('eds-current').dataset.assigned") == "false"
    Select(browser.driver.find_element(By.ID, "eds-file")).select_by_value(NAME)
    # Issue 31 point 6: a file of another device's identity is said so, and
    # Assign asks before assigning it.
    warning = browser.driver.find_element(By.ID, "eds-warning").text
    assert "describes another device (iPOS-like, Technosoft (imitated))" in warning, warning
    # The files offered name their products too.
    offered = browser.js("return [...document.querySelectorAll('#eds-file option')].map((o) => o.textContent)")
    assert "umc1bds32.eds (UMC1BDS32)" in offered, offered
    browser.driver.find_element(By.ID, "eds-assign").click()
    browser.wait(lambda _: browser.js("return document.getElementById('confirm').open"), message="no question asked")
    browser.driver.find_element(By.ID, "confirm-ok").click()
    browser.wait(lambda _: browser.js("return document.getElementById('eds-current').dataset.assigned") == "true",
                 message="the assignment was not shown")
    node = server.get("/api/v1/buses/demo/nodes/2")
    assert (node["eds"], node["eds_assigned"], node["profile"]) == (NAME, True, "cia402")

    # The catalog says who uses it.
    open_eds(browser, server)
    assert row_text(browser, NAME, ".nodes") == "demo 2 (assigned)"

    # Unassigned, then deleted.
    open_node(browser, server, 2)
    browser.driver.find_element(By.ID, "eds-unassign").click()
    browser.wait(lambda _: browser.js("return document.getElementById('eds-current').dataset.assigned") == "false",
                 message="the node was not unassigned")
    assert server.get("/api/v1/buses/demo/nodes/2")["eds"] == "jmc_stepper.eds"
    open_eds(browser, server)
    browser.driver.find_element(By.CSS_SELECTOR, f"#eds tr[data-name='{NAME}'] button.delete").click()
    browser.wait(lambda _: row_text(browser, NAME, ".name") is None, message="the file was not deleted")
    assert all(f["name"] != NAME for f in server.get("/api/v1/eds")["files"])
