"""The operator page and the API docs in a real browser (Debian's headless chromium).

A uvicorn server runs the service on 127.0.0.1 with a free port in a thread; selenium drives
the system's chromium through the system's chromedriver (nothing is downloaded). Skipped,
with the reason, when chromium, chromedriver or selenium is missing
(``apt-get install -y chromium chromium-driver``; ``pip install selenium``).
Set ``ORANGE_PLAN_SCREENSHOT=FILE.png`` to keep a screenshot of the page.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser",
                                                         "google-chrome")) if p), None)
CHROMEDRIVER = shutil.which("chromedriver")
if CHROMIUM is None or CHROMEDRIVER is None:
    pytest.skip("no chromium/chromedriver on this machine: apt-get install -y chromium "
                "chromium-driver to run the browser tests", allow_module_level=True)
webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
uvicorn = pytest.importorskip("uvicorn")

from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

from orange_plan.service.app import create_app  # noqa: E402

HOME = (1.0, 1.0)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(db, token=None):
    """The service on http://127.0.0.1:PORT in a thread; returns (base URL, stop)."""
    app = create_app(db, token=token, token_from_env=False)
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.time() + 30
    while not srv.started:
        if time.time() > deadline or not thread.is_alive():
            pytest.fail("uvicorn did not start")
        time.sleep(0.05)

    def stop():
        srv.should_exit = True
        thread.join(timeout=10)

    return f"http://127.0.0.1:{port}", stop


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    url, stop = start_server(tmp_path_factory.mktemp("page") / "m.sqlite")
    yield url
    stop()


@pytest.fixture(scope="module")
def browser():
    profile = tempfile.mkdtemp(prefix="orange-plan-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                 "--window-size=1280,800", f"--user-data-dir={profile}"):
        opts.add_argument(flag)
    opts.set_capability("goog:loggingPrefs", {"performance": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def post(url: str, body: dict, token: str | None = None) -> dict:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=120) as r:
            return json.loads(r.read())
    except urllib.error.HTTPError as exc:
        pytest.fail(f"POST {url}: {exc.code} {exc.read().decode()}")


def requested_urls(driver) -> list[str]:
    """Every URL the browser requested since the last call (DevTools performance log)."""
    urls = []
    for entry in driver.get_log("performance"):
        msg = json.loads(entry["message"])["message"]
        if msg.get("method") == "Network.requestWillBeSent":
            urls.append(msg["params"]["request"]["url"])
    return urls


def is_external(url: str, server: str) -> bool:
    """A network request to anywhere but the service (the browser's own chrome:// pages,
    data: and blob: URLs are not network requests)."""
    return url.split(":", 1)[0] in ("http", "https", "ws", "wss", "ftp") and \
        not url.startswith(server + "/")


def robot_xy(driver) -> tuple[float, float]:
    robot = driver.find_element(By.ID, "robot")
    return float(robot.get_attribute("cx")), float(robot.get_attribute("cy"))


def test_operator_page_draws_the_plan_and_follows_the_robot(server, browser):
    mission = post(f"{server}/missions", {"scenario": "rusti_v1_box", "n_vertices": 300})
    mid = mission["mission_id"]
    browser.get_log("performance")
    browser.get(f"{server}/?mission={mid}")
    wait = WebDriverWait(browser, 30, poll_frequency=0.2)
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#tour line")) > 5)
    wait.until(lambda d: "J" in d.find_element(By.ID, "margin").text)
    assert browser.find_elements(By.CSS_SELECTOR, "#boundary path")
    assert len(browser.find_elements(By.CSS_SELECTOR, "#obstacles path")) == 2
    assert browser.find_element(By.ID, "action").text.lower() == "continue"
    # the tour is coloured by speed (this small plan drives at one speed) with a legend
    strokes = {e.get_attribute("stroke") for e in browser.find_elements(By.CSS_SELECTOR,
                                                                         "#tour line")}
    assert all(s.startswith("rgb(") for s in strokes)
    assert "m/s" in browser.find_element(By.ID, "legend").text
    # one speed: said in words, no colour ramp from a value to itself
    assert "throughout" in browser.find_element(By.ID, "legend").text
    assert not browser.find_elements(By.CSS_SELECTOR, "#legend .ramp")
    wait.until(lambda d: d.find_element(By.ID, "robot").get_attribute("visibility") == "visible")
    assert robot_xy(browser) == pytest.approx(HOME)

    samples = [{"t_s": float(t), "power_W": 9.0, "x_m": HOME[0] + 0.2 * t, "y_m": HOME[1] + 0.05 * t}
               for t in range(1, 11)]
    decision = post(f"{server}/missions/{mid}/telemetry", {"samples": samples})
    assert decision["position_xy_m"] == pytest.approx([3.0, 1.5])
    wait.until(lambda d: robot_xy(d) == pytest.approx((3.0, 1.5)))
    wait.until(lambda d: d.find_element(By.ID, "samples").text.startswith("10 "))
    points = browser.find_element(By.ID, "trail").get_attribute("points").split()
    assert len(points) == 11
    assert browser.find_elements(By.CSS_SELECTOR, "#covered path")
    assert "%" in browser.find_element(By.ID, "probability").text

    # a map update shows up as a new obstacle
    post(f"{server}/missions/{mid}/map", {"obstacles": [{"type": "Polygon", "coordinates": [
        [[6.2, 2.2], [7, 2.2], [7, 3], [6.2, 3], [6.2, 2.2]]]}], "replan": True})
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#obstacles path.update")) == 1)

    shot = Path(os.environ.get("ORANGE_PLAN_SCREENSHOT") or
                Path(tempfile.gettempdir()) / "orange-plan-operator.png")
    browser.save_screenshot(str(shot))
    assert shot.stat().st_size > 1000
    external = [u for u in requested_urls(browser) if is_external(u, server)]
    assert not external, external


def test_docs_page_loads_with_no_external_requests(server, browser):
    browser.get_log("performance")
    browser.get(f"{server}/docs")
    wait = WebDriverWait(browser, 30, poll_frequency=0.2)
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, ".swagger-ui .info .title"))
    assert "orange-plan" in browser.find_element(By.CSS_SELECTOR, ".info .title").text
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, ".opblock")) >= 6)
    urls = requested_urls(browser)
    assert any(u.endswith("/openapi.json") for u in urls)
    assert any(u.endswith("/docs-assets/swagger-ui-bundle.js") for u in urls)
    external = [u for u in urls if is_external(u, server)]
    assert not external, external


def test_operator_page_with_a_token(tmp_path, browser):
    url, stop = start_server(tmp_path / "m.sqlite", token="page-secret")
    try:
        post(f"{url}/missions", {"scenario": "rusti_v1_box", "n_vertices": 300}, "page-secret")
        wait = WebDriverWait(browser, 30, poll_frequency=0.2)
        browser.get(f"{url}/")  # no token yet: the page asks for it
        wait.until(lambda d: d.find_element(By.ID, "token-form").is_displayed())
        assert "token" in browser.find_element(By.ID, "connection").text
        browser.find_element(By.ID, "token").send_keys("page-secret")
        browser.find_element(By.CSS_SELECTOR, "#token-form button").click()
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#tour line")) > 5)
        assert not browser.find_element(By.ID, "token-form").is_displayed()
        # or from the address's fragment (never sent to the server), kept for the tab
        browser.execute_script("sessionStorage.clear()")
        browser.get("about:blank")
        browser.get(f"{url}/#token=page-secret")
        wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#tour line")) > 5)
        assert "token" not in browser.current_url
    finally:
        stop()


def hatch_pixel_share(browser, shot: Path) -> float:
    """Share of the pixels inside the first no-go zone (its on-screen box, less a margin that
    leaves its outline out) drawn in the hatching's dark red."""
    import numpy as np
    from PIL import Image

    box = browser.execute_script(
        "const r = document.querySelector('#nogo path').getBoundingClientRect();"
        "return [r.left, r.top, r.right, r.bottom, window.devicePixelRatio];")
    left, top, right, bottom, ratio = box
    margin = 4
    image = Image.open(shot).convert("RGB")
    inner = image.crop((int((left + margin) * ratio), int((top + margin) * ratio),
                        int((right - margin) * ratio), int((bottom - margin) * ratio)))
    r, g, b = np.asarray(inner, dtype=int).reshape(-1, 3).T
    return float(np.mean((r > 120) & (g < 110) & (b < 110))) if r.size else 0.0


def square(x0: float, y0: float, side: float) -> dict:
    return {"type": "Polygon", "coordinates": [[[x0, y0], [x0 + side, y0],
                                                 [x0 + side, y0 + side], [x0, y0 + side],
                                                 [x0, y0]]]}


@pytest.mark.parametrize("scenario, zone", [
    ("rusti_v1_box", square(5.8, 0.4, 1.6)),        # an 8 m x 6 m lab floor
    ("ar_drone_wind", square(250.0, 40.0, 100.0)),  # a 400 m x 300 m field
])
def test_no_go_hatching_shows_at_every_map_size(server, browser, tmp_path, scenario, zone):
    mission = post(f"{server}/missions", {"scenario": scenario, "n_vertices": 200})
    mid = mission["mission_id"]
    post(f"{server}/missions/{mid}/map", {"no_go": [zone], "replan": False})
    browser.get(f"{server}/?mission={mid}")
    wait = WebDriverWait(browser, 30, poll_frequency=0.2)
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#nogo path"))
    time.sleep(0.5)
    shot = tmp_path / f"{scenario}.png"
    browser.save_screenshot(str(shot))
    if os.environ.get("ORANGE_PLAN_SCREENSHOT"):
        shutil.copy(shot, Path(os.environ["ORANGE_PLAN_SCREENSHOT"]).with_suffix(
            f".{scenario}.png"))
    share = hatch_pixel_share(browser, shot)
    # a stripe 1.5 px wide every 8 px covers about a sixth of the zone (0.16 on either map)
    assert 0.08 < share < 0.35, share
