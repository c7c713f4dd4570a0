"""The web page in a real headless Chromium against a real uvicorn: one compute request per click, the API's
answer on screen with its files to download, drag and drop, errors that replace the result, a notice for
matches that did not converge, the API docs rendering with nothing fetched from elsewhere and no script refused by
their policy, and, with API keys on, the page asking for one and then matching."""
from __future__ import annotations

import base64
import json
import os
import re
import shutil
import tempfile
import time

import cv2
import httpx2
import numpy as np
import pytest

from reglib.examples import example_pair

CHROMEDRIVER = "/usr/bin/chromedriver"
WAIT_S = 180

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
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # CSP reports land in the console
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    driver.set_script_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def compute_requests(url: str) -> dict[str, float]:
    """POSTs under /v1/ answered so far, by route, from the service's own /metrics."""
    counts: dict[str, float] = {}
    for line in httpx2.get(url + "/metrics", timeout=10).text.splitlines():
        m = re.match(r'reglib_http_requests_total\{method="POST",route="(/v1/[^"]*)",status="[^"]*"\} (\S+)', line)
        if m:
            counts[m.group(1)] = counts.get(m.group(1), 0.0) + float(m.group(2))
    return counts


def state(browser) -> str:
    return browser.find_element("tag name", "body").get_attribute("data-state") or ""


def click_and_wait(browser, before: str | None = None) -> str:
    """Press the page's submit button; wait until the page has answered (done or error)."""
    from selenium.webdriver.support.ui import WebDriverWait

    browser.find_element("css selector", "button[type=submit]").click()
    WebDriverWait(browser, WAIT_S).until(lambda d: state(d) in ("done", "error") and d.find_element(
        "id", "run").is_enabled())
    return state(browser)


def visible_text(browser) -> str:
    return browser.find_element("tag name", "body").text


def downloads(browser) -> dict[str, str]:
    """{download name: href} of the links the page offers."""
    links = browser.find_elements("css selector", "a[download]")
    return {a.get_attribute("download"): a.get_attribute("href") for a in links if a.get_attribute("href")}


def fetch_bytes(browser, href: str) -> bytes:
    """The bytes behind one of the page's (blob:) links, read inside the page."""
    script = """const done = arguments[arguments.length - 1];
      fetch(arguments[0]).then((r) => r.arrayBuffer()).then((buf) => {
        let text = ""; const bytes = new Uint8Array(buf);
        for (let i = 0; i < bytes.length; i++) text += String.fromCharCode(bytes[i]);
        done(btoa(text));
      }).catch((e) => done("ERROR " + e));"""
    out = browser.execute_async_script(script, href)
    assert not out.startswith("ERROR"), out
    return base64.b64decode(out)


def choose(browser, path_a: str, path_b: str) -> None:
    browser.find_element("id", "image_a").send_keys(path_a)
    browser.find_element("id", "image_b").send_keys(path_b)


def test_one_click_is_one_request_and_shows_the_apis_answer(browser, live_server):
    path_a, path_b = (str(p) for p in example_pair())
    browser.get(live_server.url + "/")
    choose(browser, path_a, path_b)
    seed = browser.find_element("id", "seed")
    seed.clear()
    seed.send_keys("1e3")
    assert browser.find_element("id", "dense").is_selected()  # the library's default
    before = compute_requests(live_server.url)
    assert click_and_wait(browser) == "done", browser.find_element("id", "error").text
    after = compute_requests(live_server.url)
    new = {route: after[route] - before.get(route, 0.0) for route in after if after[route] != before.get(route, 0.0)}
    assert new == {"/v1/match/bundle": 1.0}

    # what the page shows and offers is the API's answer for the same form (seed 1e3 is 1000, not 1)
    form = {"features": "sift", "method": "l2e", "dense": "true", "seed": "1000"}
    files = {name: (path.name, path.read_bytes(), "image/jpeg") for name, path in zip(("image_a", "image_b"),
                                                                                      example_pair(), strict=True)}
    api = httpx2.post(live_server.url + "/v1/match", files=files, data=form, timeout=120).json()
    assert api["seed"] == 1000 and api["converged"] is True
    assert int(browser.find_element("id", "n-inliers").text) == api["n_inliers"] > 50
    assert not browser.find_element("id", "unreliable").is_displayed()
    assert int(browser.find_element("id", "n-matches").text) == api["n_matches"]
    assert "seed 1000" in browser.find_element("id", "timing").text
    offered = downloads(browser)
    assert set(offered) == {"match.json", "transform.json", "warped.png", "overlay.png", "flow.flo", "flow.png",
                            "confidence.png"}
    shown = json.loads(fetch_bytes(browser, offered["match.json"]))
    shown_timings = shown.pop("timings_ms")
    assert shown_timings.keys() == api.pop("timings_ms").keys()
    assert shown == api
    assert json.loads(fetch_bytes(browser, offered["transform.json"])) == api["transform"]
    flo = httpx2.post(live_server.url + "/v1/flow", files=files, data={**form, "format": "flo"}, timeout=120)
    assert fetch_bytes(browser, offered["flow.flo"]) == flo.content

    # the pictures arrived, decoded, in a's frame, and are kept within the window
    width = cv2.imread(path_a).shape[1]
    for image_id in ("overlay-b", "flow", "confidence"):
        assert browser.execute_script(f"return document.getElementById('{image_id}').naturalWidth") == width
    for selector in ("#overlay-b", "#flow", "#confidence", "#matches", ".preview"):
        assert browser.execute_script(
            f"return getComputedStyle(document.querySelector('{selector}')).maxWidth") == "100%", selector
    assert browser.find_element("id", "notice").is_displayed() is False

    # the views: the time is the computation's total (not the sum of its stages and the total), the slider sits
    # with the overlay it blends, the flow's wheel and scale, and the checkerboard of a and warped b
    shown_ms = re.search(r"computed in (\d+) ms", browser.find_element("id", "timing").text)
    assert shown_ms and int(shown_ms.group(1)) == round(shown_timings["total"])
    assert browser.execute_script("return document.getElementById('dense-results')"
                                  ".contains(document.getElementById('alpha'))")
    flo_bytes = fetch_bytes(browser, offered["flow.flo"])
    w, h = np.frombuffer(flo_bytes, "<i4", count=2, offset=4)
    flow = np.frombuffer(flo_bytes, "<f4", offset=12).reshape(h, w, 2)
    largest = float(np.hypot(flow[..., 0], flow[..., 1]).max())
    assert f"full colour: {largest:.1f} px" in browser.find_element("id", "flow-scale").text
    assert browser.execute_script("return document.getElementById('flow-wheel').naturalWidth") == 96
    assert not browser.find_element("id", "checker").is_displayed()
    browser.find_element("id", "view-checker").click()
    assert browser.find_element("id", "checker").is_displayed()
    assert not browser.find_element("id", "overlay").is_displayed()
    assert browser.execute_script("return document.getElementById('checker').width") == width
    assert not browser.find_element("id", "alpha").is_displayed()
    # its tiles alternate: the top-left tile is a's pixels, the one beside it warped b's
    a_rgb = cv2.cvtColor(cv2.imread(path_a), cv2.COLOR_BGR2RGB).astype(int)
    warped = cv2.cvtColor(cv2.imdecode(np.frombuffer(fetch_bytes(browser, offered["warped.png"]), np.uint8),
                                       cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB).astype(int)
    tile = max(16, round(max(a_rgb.shape[:2]) / 8))
    pixels = browser.execute_script(
        "const c = document.getElementById('checker').getContext('2d');"
        "return [Array.from(c.getImageData(5, 5, 1, 1).data), "
        "Array.from(c.getImageData(arguments[0], 5, 1, 1).data)];",
        tile + 5)
    assert np.abs(np.array(pixels[0][:3]) - a_rgb[5, 5]).max() <= 3
    assert np.abs(np.array(pixels[1][:3]) - warped[5, tile + 5]).max() <= 3
    browser.find_element("id", "view-blend").click()
    assert browser.find_element("id", "overlay").is_displayed() and browser.find_element("id", "alpha").is_displayed()


def test_the_favicon_and_a_text_file_named_png(browser, live_server, tmp_path):
    assert httpx2.get(live_server.url + "/favicon.ico", timeout=10).headers["content-type"] == "image/svg+xml"
    fake = tmp_path / "notes.png"
    fake.write_text("these are my notes, not a picture\n")
    browser.get(live_server.url + "/")
    browser.find_element("id", "image_a").send_keys(str(fake))
    for _ in range(100):
        if "not an image" in browser.find_element("id", "note-image_a").text:
            break
        time.sleep(0.1)
    assert "the service can still read it" not in browser.find_element("id", "note-image_a").text


def test_a_failed_request_replaces_the_result(browser, live_server, png_pair, tmp_path):
    paths = []
    for name, data in zip("ab", png_pair, strict=True):
        path = tmp_path / f"{name}.png"
        path.write_bytes(data)
        paths.append(str(path))
    text = tmp_path / "notes.txt"
    text.write_text("this is not an image\n")
    browser.get(live_server.url + "/")
    choose(browser, *paths)
    assert click_and_wait(browser) == "done"
    assert re.search(r"\d+ inliers", visible_text(browser))
    assert downloads(browser)

    browser.find_element("id", "image_b").send_keys(str(text))
    assert click_and_wait(browser) == "error"
    page = visible_text(browser)
    assert not re.search(r"\d+ inliers", page), page
    assert not browser.find_element("id", "result").is_displayed()
    assert not downloads(browser)
    error = browser.find_element("id", "error")
    assert error.is_displayed()
    assert "400" in error.text and "image_b" in error.text  # the service's own message
    assert "Choose image files" in browser.find_element("id", "error-advice").text  # and what to do


def test_a_seed_that_is_not_a_whole_number_is_refused_before_sending(browser, live_server):
    browser.get(live_server.url + "/")
    choose(browser, *(str(p) for p in example_pair()))
    seed = browser.find_element("id", "seed")
    seed.clear()
    seed.send_keys("1.5")
    before = compute_requests(live_server.url)
    assert click_and_wait(browser) == "error"
    assert compute_requests(live_server.url) == before
    assert "whole number" in browser.find_element("id", "error").text


def test_a_match_that_did_not_converge_says_so_and_draws_no_warp(browser, live_server, png_pair, image_pair,
                                                                  tmp_path):
    a = tmp_path / "a.png"
    a.write_bytes(png_pair[0])
    grey = tmp_path / "grey.png"
    assert cv2.imwrite(str(grey), np.full_like(image_pair[1], 128))  # no keypoints: too few matches
    browser.get(live_server.url + "/")
    choose(browser, str(a), str(grey))
    assert click_and_wait(browser) == "done"
    notice = browser.find_element("id", "notice")
    assert notice.is_displayed()
    assert "too few putative matches" in notice.text
    # headlined as no answer, not as "0 inliers of 0"
    assert browser.find_element("id", "headline").text == "No reliable match"
    assert not browser.find_element("id", "dense-results").is_displayed()
    assert browser.execute_script("return document.getElementById('overlay-b').getAttribute('src')") is None
    assert set(downloads(browser)) == {"match.json", "transform.json"}


DROP = """const [zone, names, done] = [arguments[0], arguments[1], arguments[arguments.length - 1]];
  (async () => {
    const list = new DataTransfer();
    for (const name of names) {
      const blob = await (await fetch("/examples/" + name)).blob();
      list.items.add(new File([blob], "dropped-" + name, { type: blob.type }));
    }
    document.getElementById(zone).dispatchEvent(new DragEvent("drop", { dataTransfer: list, bubbles: true,
                                                                        cancelable: true }));
    done(true);
  })().catch((e) => done(String(e)));"""


def test_drag_and_drop_and_the_examples_button_choose_the_files(browser, live_server):
    from selenium.webdriver.support.ui import WebDriverWait

    (name_a, size_a), (name_b, size_b) = ((p.name, p.stat().st_size) for p in example_pair())
    browser.get(live_server.url + "/")

    def chosen(input_id):
        return browser.execute_script(
            f"const f = document.getElementById('{input_id}').files[0]; return f ? [f.name, f.size] : null")

    def preview_width(input_id):
        return browser.execute_script(f"return document.getElementById('preview-{input_id}').naturalWidth")

    assert browser.execute_async_script(DROP, "drop-image_b", [name_b]) is True
    assert chosen("image_b") == [f"dropped-{name_b}", size_b] and chosen("image_a") is None
    WebDriverWait(browser, 30).until(lambda d: preview_width("image_b") > 0)
    # two files dropped on one box fill a and b
    assert browser.execute_async_script(DROP, "drop-image_a", [name_b, name_a]) is True
    assert chosen("image_a") == [f"dropped-{name_b}", size_b] and chosen("image_b") == [f"dropped-{name_a}", size_a]

    browser.find_element("id", "examples").click()
    WebDriverWait(browser, 30).until(lambda d: chosen("image_a") == [name_a, size_a])
    WebDriverWait(browser, 30).until(lambda d: chosen("image_b") == [name_b, size_b])
    for input_id, name in (("image_a", name_a), ("image_b", name_b)):
        assert name in browser.find_element("id", f"note-{input_id}").text
        WebDriverWait(browser, 30).until(lambda d, i=input_id: preview_width(i) > 0)


@pytest.mark.parametrize(("page", "rendered"), [("/docs", ".swagger-ui .info .title"), ("/redoc", "h1")])
def test_the_api_docs_render_with_nothing_from_elsewhere(browser, live_server, page, rendered):
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get(live_server.url + page)
    WebDriverWait(browser, 60).until(
        lambda d: "reglib" in " ".join(e.text for e in d.find_elements("css selector", rendered)))
    fetched = browser.execute_script("return performance.getEntriesByType('resource').map((e) => e.name)")
    assert any(url.startswith(live_server.url + "/docs/assets/") for url in fetched), fetched
    # ReDoc's script asks for its maker's logo from a CDN: the page's policy must have stopped that request
    violations = [entry["message"] for entry in browser.get_log("browser") if entry.get("source") == "security"]
    blocked = {url for message in violations
               for url in re.findall(r"'(\S+)' violates the following Content Security Policy", message)}
    outside = {url for url in fetched if not url.startswith(live_server.url + "/")}
    assert outside <= blocked, (outside, blocked)
    if page == "/docs":  # Swagger UI's inline start-up script runs by its hash: nothing refused
        assert violations == []


KEY = "5e1f0c2a-page-test-key"


@pytest.fixture(scope="module")
def keyed_server(start_live_server, tmp_path_factory):
    keys = tmp_path_factory.mktemp("page-keys") / "keys.txt"
    keys.write_text(f"# the page test's key\n{KEY}\n")
    return start_live_server(workers=2, env={"REGLIB_API_KEYS_FILE": str(keys), "REGLIB_QUEUE_SIZE": "2"})


def bundle_answers(url: str) -> dict[str, float]:
    """POST /v1/match/bundle answers so far, by status (from /metrics, open on a loopback address)."""
    counts: dict[str, float] = {}
    for line in httpx2.get(url + "/metrics", timeout=10).text.splitlines():
        m = re.match(r'reglib_http_requests_total\{method="POST",route="/v1/match/bundle",status="(\d+)"\} (\S+)', line)
        if m:
            counts[m.group(1)] = float(m.group(2))
    return counts


def test_with_keys_the_page_asks_for_one_and_then_matches(browser, keyed_server):
    from selenium.webdriver.support.ui import WebDriverWait

    def answered_with_key_prompt(reason_text: str) -> None:
        WebDriverWait(browser, WAIT_S).until(lambda d: state(d) == "key" and reason_text in d.find_element(
            "id", "key-reason").text and d.find_element("id", "run").is_enabled())

    url = keyed_server.url
    browser.get(url + "/")
    choose(browser, *(str(p) for p in example_pair()))
    assert not browser.find_element("id", "key-box").is_displayed()
    browser.find_element("css selector", "button[type=submit]").click()
    answered_with_key_prompt("needs an API key")  # the service's own words
    assert browser.find_element("id", "key-box").is_displayed()
    assert not browser.find_element("id", "error").is_displayed()
    assert bundle_answers(url) == {"401": 1.0}

    browser.find_element("id", "api-key").send_keys("not-the-key")
    browser.find_element("id", "key-send").click()
    answered_with_key_prompt("refused")
    assert bundle_answers(url) == {"401": 2.0}
    assert browser.execute_script("return sessionStorage.getItem('reglib-api-key')") is None  # a refused key is dropped

    browser.find_element("id", "api-key").send_keys(KEY)
    browser.find_element("id", "key-send").click()  # the same request, sent again with the key
    WebDriverWait(browser, WAIT_S).until(lambda d: state(d) in ("done", "error") and d.find_element(
        "id", "run").is_enabled())
    assert state(browser) == "done", browser.find_element("id", "error").text
    assert int(browser.find_element("id", "n-inliers").text) > 50
    assert not browser.find_element("id", "key-box").is_displayed()
    assert bundle_answers(url) == {"401": 2.0, "200": 1.0}
    assert browser.execute_script("return sessionStorage.getItem('reglib-api-key')") == KEY  # this tab only
    assert browser.execute_script("return localStorage.length") == 0

    # the next click sends the kept key at once
    assert click_and_wait(browser) == "done"
    assert bundle_answers(url) == {"401": 2.0, "200": 2.0}
    violations = [entry["message"] for entry in browser.get_log("browser") if entry.get("source") == "security"]
    assert violations == []  # the page runs under its policy (no inline script, own styles only)
