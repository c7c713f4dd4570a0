"""The web page in a real headless Chromium against a real uvicorn: the inlier count shown is the API's."""
from __future__ import annotations

import os
import shutil
import tempfile

import httpx2
import pytest

CHROMEDRIVER = "/usr/bin/chromedriver"

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def chromium_binary() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found and os.path.exists(CHROMEDRIVER):
        return found
    message = "Debian's chromium and chromium-driver are not installed"
    if os.environ.get("REGLIB_REQUIRE_BROWSER") == "1":
        pytest.fail(message + " (REGLIB_REQUIRE_BROWSER=1: the browser test is required here)")
    pytest.skip(message)


@pytest.fixture
def browser():
    binary = chromium_binary()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="reglib-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--no-first-run", f"--user-data-dir={profile}", "--window-size=1200,1600"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def test_page_shows_the_apis_inlier_count(browser, live_server, png_pair, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    paths = []
    for name, data in zip("ab", png_pair, strict=True):
        path = tmp_path / f"{name}.png"
        path.write_bytes(data)
        paths.append(str(path))
    browser.get(live_server.url + "/")
    browser.find_element(By.ID, "image_a").send_keys(paths[0])
    browser.find_element(By.ID, "image_b").send_keys(paths[1])
    browser.find_element(By.ID, "run").click()
    WebDriverWait(browser, 180).until(lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-state"))
    state = browser.find_element(By.TAG_NAME, "body").get_attribute("data-state")
    assert state == "done", browser.find_element(By.ID, "status").text
    shown = int(browser.find_element(By.ID, "n-inliers").text)

    files = {"image_a": ("a.png", png_pair[0], "image/png"), "image_b": ("b.png", png_pair[1], "image/png")}
    data = {"features": "sift", "method": "l2e", "dense": "false", "seed": "0"}
    api = httpx2.post(live_server.url + "/v1/match", files=files, data=data, timeout=120).json()
    assert shown == api["n_inliers"] > 0
    assert int(browser.find_element(By.ID, "n-matches").text) == api["n_matches"]
    # the warped overlay and the flow picture arrived and decoded
    a_width = 320  # the test images are 320 x 256; warp and flow are in a's frame
    for image_id in ("overlay-b", "flow"):
        script = f"return document.getElementById('{image_id}').naturalWidth"
        WebDriverWait(browser, 30).until(lambda d, script=script: d.execute_script(script) > 0)
        width = browser.execute_script(script)
        assert width == a_width, image_id
