"""`m2d2m ui` serves the project's MLflow store (its front page and the runs API over loopback),
and stopping it stops every process it started; a port it cannot use is a one-line error."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import mlflow
import psutil
import pytest

from orchestration.cli import main
from orchestration.serving import serve
from tests.helpers import free_port, one_line_error


def fetch(url: str, body: dict | None = None) -> tuple[int, bytes]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return response.status, response.read()


CHROMIUM = shutil.which("chromium") and shutil.which("chromedriver")


def page_text(url: str, expected: str) -> str:
    """The visible text of ``url`` in headless Chromium once it shows ``expected`` (60 s at most)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium")
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(argument)
    driver = webdriver.Chrome(options=options, service=Service(shutil.which("chromedriver")))
    try:
        driver.get(url)
        deadline = time.monotonic() + 60
        while expected not in (text := driver.find_element("tag name", "body").text):
            assert time.monotonic() < deadline, text[:500]
            time.sleep(0.5)
        return text
    finally:
        driver.quit()


def alive(processes: list[psutil.Process]) -> list[psutil.Process]:
    return [p for p in processes if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


SLEEPERS = "from orchestration.serving import serve; print(serve(['sh', '-c', 'setsid sleep 300 & sleep 300 & wait']))"


def serving_sleepers() -> tuple[subprocess.Popen, list[psutil.Process]]:
    """serve() in a child Python (signal handlers belong to a main thread) running a shell that
    starts two sleepers, one in a session of its own; the child, and everything it started."""
    runner = subprocess.Popen(
        [sys.executable, "-c", SLEEPERS],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    deadline = time.monotonic() + 30
    while True:
        started = psutil.Process(runner.pid).children(recursive=True)
        if sum(p.name() in ("sh", "sleep") for p in started) == 3:  # beside them, serve()'s watcher
            return runner, started
        assert runner.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)


@pytest.mark.slow
def test_the_ui_serves_the_project_store_and_sigterm_stops_all_of_it(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    experiment = client.create_experiment("tiny/eval")
    run = client.create_run(experiment, run_name="a-run", tags={"stage": "eval"})
    client.log_metric(run.info.run_id, "multi/tps/jerk", 1.25)

    port = free_port()
    log = (tmp_path / "ui.log").open("wb")
    server = subprocess.Popen(
        [sys.executable, "-m", "orchestration.cli", "ui", "--port", str(port)],
        cwd=tmp_path,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 90
        while True:
            try:
                status, page = fetch(base + "/")
                break
            except OSError:
                assert server.poll() is None, (tmp_path / "ui.log").read_text()
                assert time.monotonic() < deadline, "the UI did not come up within 90 s"
                time.sleep(0.5)
        assert status == 200 and b"<html" in page.lower()
        address = f"{base}/#/experiments?workflowType=machine_learning"
        assert (tmp_path / "ui.log").read_text().splitlines()[0].split(": ", 1)[1].startswith(address)
        if CHROMIUM:  # the address opens on the runs, not on MLflow 3's GenAI view (traces, token cost)
            shown = page_text(f"{base}/#/experiments/{experiment}?workflowType=machine_learning", "a-run")
            assert "Runs" in shown and "Token Usage" not in shown
        status, body = fetch(base + "/api/2.0/mlflow/runs/search", {"experiment_ids": [experiment]})
        runs = json.loads(body)["runs"]
        assert status == 200 and [r["info"]["run_name"] for r in runs] == ["a-run"]
        assert runs[0]["data"]["metrics"][0] == {
            **runs[0]["data"]["metrics"][0],
            "key": "multi/tps/jerk",
            "value": 1.25,
        }
        started = psutil.Process(server.pid).children(recursive=True)
        assert started  # mlflow server and its uvicorn worker(s), in the session m2d2m ui started
        server.send_signal(signal.SIGTERM)  # to `m2d2m ui` alone, as a service manager or `kill` does
        assert server.wait(timeout=60) == 0
        assert alive(started) == []
        with pytest.raises(OSError):
            fetch(base + "/")
    finally:
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait(timeout=30)
        log.close()
    assert f"http://127.0.0.1:{port}" in (tmp_path / "ui.log").read_text().splitlines()[0]


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGHUP])
def test_a_stop_signal_ends_the_whole_process_tree_it_served(stop):
    runner, started = serving_sleepers()
    runner.send_signal(stop)
    assert runner.communicate(timeout=30)[0].strip() == "None" and runner.returncode == 0
    assert alive(started) == []


@pytest.mark.slow
def test_a_sigkill_of_the_serving_process_still_ends_the_whole_tree():
    """A SIGKILL runs nothing in the process that served (`kill -9` of `m2d2m ui`): its watcher,
    told by the kernel, stops the tree, so the port is free for the re-run."""
    runner, started = serving_sleepers()
    runner.kill()
    runner.wait(timeout=30)
    deadline = time.monotonic() + 30
    while alive(started):
        assert time.monotonic() < deadline, alive(started)
        time.sleep(0.1)


def test_serve_returns_the_status_of_a_command_that_ends_by_itself():
    assert serve(["sh", "-c", "exit 3"]) == 3


def test_a_port_that_is_taken_or_out_of_range_is_one_line(capsys):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        assert main(["ui", "--port", str(taken.getsockname()[1])]) == 2
    err = capsys.readouterr().err
    assert "cannot listen on 127.0.0.1:" in err and len(err.strip().splitlines()) == 1
    assert "from 1 to 65535" in one_line_error(["ui", "--port", "99999"], capsys)
