"""`m2d2m ui` serves the project's MLflow store: its front page and the runs API over loopback."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import mlflow

from tests.helpers import free_port


def fetch(url: str, body: dict | None = None) -> tuple[int, bytes]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return response.status, response.read()


def test_the_ui_serves_the_project_store(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    experiment = client.create_experiment("tiny/eval")
    run = client.create_run(experiment, run_name="a-run", tags={"stage": "eval"})
    client.log_metric(run.info.run_id, "multi/tps/jerk", 1.25)

    port = free_port()
    log = (tmp_path / "ui.log").open("wb")
    server = subprocess.Popen([sys.executable, "-m", "orchestration.cli", "ui", "--port", str(port)], cwd=tmp_path,
                              stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
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
        status, body = fetch(base + "/api/2.0/mlflow/runs/search", {"experiment_ids": [experiment]})
        runs = json.loads(body)["runs"]
        assert status == 200 and [r["info"]["run_name"] for r in runs] == ["a-run"]
        assert runs[0]["data"]["metrics"][0] == {**runs[0]["data"]["metrics"][0], "key": "multi/tps/jerk", "value": 1.25}
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
        log.close()
    assert f"http://127.0.0.1:{port}" in (tmp_path / "ui.log").read_text().splitlines()[0]
