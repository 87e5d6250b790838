"""The page in a real Chromium (Debian's chromium and chromium-driver, driven by Selenium): the
``browser`` fixtures (a pytest plugin of tests/conftest.py), the mark that skips a page test where
there is no Chromium, and waiting for what the page shows.

`.ci/run` installs Chromium when it runs as root with apt, so CI always runs the page tests;
elsewhere they are skipped with a one-line reason. ``M2D2M_SERVE_PROJECT=<dir>`` serves that
project's synthetic models instead of the tiny trained project's (``dataset``)."""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
NEEDS_CHROMIUM = pytest.mark.skipif(
    not (CHROMIUM and DRIVER), reason="no chromium and chromedriver here (apt-get install chromium chromium-driver)"
)
# read at import, while the working directory is still the one the command was started in
SERVE_PROJECT = Path(os.environ["M2D2M_SERVE_PROJECT"]).resolve() if os.environ.get("M2D2M_SERVE_PROJECT") else None


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
def served_dataset(trained_project, monkeypatch) -> str:
    """The dataset whose models the page serves: the tiny project's, or another project's demo models."""
    if SERVE_PROJECT is not None:
        monkeypatch.chdir(SERVE_PROJECT)
        return "synthetic"
    return "tiny"


def wait_for(condition: Callable[[], object], seconds: float = 120, what: str = "") -> object:
    """What ``condition`` gives once it is truthy, polled every 0.1 s for ``seconds`` at most."""
    deadline = time.monotonic() + seconds
    while not (value := condition()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.1)
    return value


def find_all_css(browser, selector: str) -> list:
    """Every element of the page that ``selector`` matches."""
    return browser.find_elements("css selector", selector)


# whether the page has its first lane's run details (GET /api/models/{model}/runs/{run})
RUN_DETAILS_LOADED = "return performance.getEntriesByType('resource').some((e) => e.name.includes('/runs/'));"


def open_page(browser, base: str) -> None:
    """The page, once its first lane has its run's details (its knobs, limits and actions)."""
    browser.get(base + "/")
    wait_for(lambda: browser.execute_script(RUN_DETAILS_LOADED), 60, "the run's details")
    time.sleep(0.3)  # for the page to show them
