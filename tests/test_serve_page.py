"""`m2d2m serve`'s page in a real Chromium (Debian's chromium and chromium-driver, driven by
Selenium): three actions generated with the tiny model, a figure drawn, the timeline's three
labels, scrubbing moving the figure, two methods compared in sync, and the BVH downloaded and parsed.

`.ci/run` installs Chromium when it runs as root with apt, so CI always runs this test; elsewhere
it is skipped with a one-line reason. ``M2D2M_SCREENSHOT=<file.png>`` keeps a picture of the page;
``M2D2M_SERVE_PROJECT=<dir>`` serves that project's synthetic models instead (the README's picture
is of the demo's: ``M2D2M_SERVE_PROJECT=. M2D2M_SCREENSHOT=docs/serve-page.png``).
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from orchestration.web.app import ServeSettings
from tests.live_server import live_server
from tests.test_export import parse_bvh

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(
    not (CHROMIUM and DRIVER), reason="no chromium and chromedriver here (apt-get install chromium chromium-driver)"
)
# read at import, while the working directory is still the one the command was started in
SERVE_PROJECT = Path(os.environ["M2D2M_SERVE_PROJECT"]).resolve() if os.environ.get("M2D2M_SERVE_PROJECT") else None
ACTIONS = [("a person walks forward", "1.6"), ("a person jumps", "1.2"), ("a person waves their right hand", "2")]

# Pixels of the player's canvas that differ from its corner's colour (the background), and a
# digest of them: a figure is drawn when there are many, and a new frame changes the digest.
CANVAS_PIXELS = """
const canvas = arguments[0];
const data = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
let drawn = 0, digest = 0;
for (let i = 0; i < data.length; i += 4) {
  if (data[i] !== data[0] || data[i + 1] !== data[1] || data[i + 2] !== data[2]) {
    drawn += 1;
    digest = (digest * 31 + i + data[i]) % 1000000007;
  }
}
return [drawn, digest];
"""


@pytest.fixture
def browser(tmp_path) -> Iterator:
    yield from _chromium(tmp_path)


@pytest.fixture
def offline_browser(tmp_path) -> Iterator:
    """A Chromium that resolves no host but the loopback one: a machine without internet."""
    yield from _chromium(tmp_path, "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1")


def _chromium(tmp_path: Path, *arguments: str) -> Iterator:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1400,900",
        *arguments,
    ):
        options.add_argument(argument)
    options.add_experimental_option(
        "prefs", {"download.default_directory": str(tmp_path), "download.prompt_for_download": False}
    )
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(DRIVER))
    driver.downloads = tmp_path
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def dataset(trained_project, monkeypatch) -> str:
    """The dataset whose models the page serves: the tiny project's, or another project's demo models."""
    if SERVE_PROJECT is not None:
        monkeypatch.chdir(SERVE_PROJECT)
        return "synthetic"
    return "tiny"


def wait_for(condition: Callable[[], object], seconds: float = 120, what: str = "") -> object:
    deadline = time.monotonic() + seconds
    while not (value := condition()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)
    return value


def test_a_newcomer_generates_three_actions_scrubs_compares_and_downloads_the_bvh(dataset, browser):
    from selenium.webdriver.common.by import By

    find = browser.find_element
    find_all = browser.find_elements
    with live_server(ServeSettings(dataset=dataset)) as (base, _):
        browser.get(base + "/")
        wait_for(lambda: find_all(By.CSS_SELECTOR, "#lanes .lane [data-knob]"), 60, "the model's knobs")
        find(By.ID, "add-action").click()
        for row, (text, seconds) in zip(find_all(By.CSS_SELECTOR, "#actions .action"), ACTIONS, strict=True):
            for selector, value in ((".action-text", text), (".action-seconds", seconds)):
                field = row.find_element(By.CSS_SELECTOR, selector)
                field.clear()
                field.send_keys(value)
        find(By.ID, "generate").click()
        player = wait_for(lambda: find_all(By.CSS_SELECTOR, "#players .player"), what="the player")[0]
        labels = [segment.text for segment in player.find_elements(By.CSS_SELECTOR, ".timeline .segment")]
        assert labels == [text for text, _ in ACTIONS]
        frames = int(player.get_attribute("data-frames"))
        assert frames == (8 + 6 + 10) * 4  # each action's seconds in 4-frame tokens at 20 fps
        canvas = player.find_element(By.TAG_NAME, "canvas")
        drawn, _ = browser.execute_script(CANVAS_PIXELS, canvas)
        assert drawn > 200, "the canvas shows no figure"

        scrub = find(By.ID, "scrub")
        seen = []
        for fraction in (0.05, 0.8):
            browser.execute_script(
                "const s = arguments[0]; s.value = String(Number(s.max) * arguments[1]);"
                "s.dispatchEvent(new Event('input', {bubbles: true}));",
                scrub,
                fraction,
            )
            time.sleep(0.3)
            seen.append((int(player.get_attribute("data-frame")), browser.execute_script(CANVAS_PIXELS, canvas)[1]))
        (first_frame, first_digest), (later_frame, later_digest) = seen
        assert later_frame > first_frame and later_digest != first_digest
        active = player.find_element(By.CSS_SELECTOR, ".timeline .segment.active").text
        assert active == ACTIONS[2][0]  # 80 % of the way is in the third action

        find(By.ID, "compare").click()
        lanes = find_all(By.CSS_SELECTOR, "#lanes .lane")
        assert [lane.find_element(By.CSS_SELECTOR, ".lane-method").get_attribute("value") for lane in lanes] == [
            "tps",
            "independent",
        ]
        find(By.ID, "generate").click()
        players = wait_for(lambda: len(found := find_all(By.CSS_SELECTOR, "#players .player")) == 2 and found)
        titles = [p.find_element(By.CSS_SELECTOR, ".player-title").text for p in players]
        assert "tps" in titles[0] and "independent" in titles[1]
        for each in players:
            assert browser.execute_script(CANVAS_PIXELS, each.find_element(By.TAG_NAME, "canvas"))[0] > 200
        if find(By.ID, "play").text.strip() == "Play":
            find(By.ID, "play").click()
        wait_for(lambda: int(players[0].get_attribute("data-frame")) > 0, 20, "playback")
        find(By.ID, "play").click()  # pause: both players stop on the same frame
        time.sleep(0.3)
        assert players[0].get_attribute("data-frame") == players[1].get_attribute("data-frame")

        if os.environ.get("M2D2M_SCREENSHOT"):  # with the actions in view
            browser.execute_script("for (const e of document.querySelectorAll('*')) e.scrollTop = 0;")
            browser.save_screenshot(os.environ["M2D2M_SCREENSHOT"])
        players[0].find_element(By.CSS_SELECTOR, ".downloads a[data-format='bvh']").click()
        bvh: Path = wait_for(lambda: next(iter(browser.downloads.glob("*.bvh")), None), 30, "the BVH download")
        assert len(parse_bvh(bvh).motion) == frames
        errors = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
        assert not errors, errors


# every resource the page asked for
LOADED = "return performance.getEntriesByType('resource').map(entry => entry.name);"


@pytest.mark.parametrize(
    "path, rendered",
    [("/docs", ".swagger-ui .info .title"), ("/redoc", "h1")],
    ids=["swagger", "redoc"],
)
def test_the_api_documentation_renders_without_internet(tmp_path, monkeypatch, offline_browser, path, rendered):
    """Issue 38, item 3: Swagger UI and ReDoc came from a CDN, so /docs and /redoc were blank offline."""
    from selenium.webdriver.common.by import By

    monkeypatch.chdir(tmp_path)  # no model needed to document the API
    with live_server(ServeSettings(dataset="tiny", track=False)) as (base, _):
        offline_browser.get(base + path)
        title = wait_for(
            lambda: [e.text for e in offline_browser.find_elements(By.CSS_SELECTOR, rendered) if e.text], 60, path
        )
        assert title[0].startswith("m2d2m")
        # anything asked of another host was refused by the page's own policy, never sent
        blocked = " ".join(
            entry["message"] for entry in offline_browser.get_log("browser") if "blocked" in entry["message"]
        )
        elsewhere = [url for url in offline_browser.execute_script(LOADED) if not url.startswith(base)]
        assert all(url in blocked for url in elsewhere), (elsewhere, blocked)
        if path == "/docs":  # the operations are listed, each with its summary
            operations = offline_browser.find_elements(By.CSS_SELECTOR, ".opblock-summary-path")
            assert {"/api/generate", "/api/models"} <= {o.get_attribute("data-path") for o in operations}
