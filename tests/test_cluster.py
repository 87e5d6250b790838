"""The cluster story as far as one machine goes: `ray start --head`, then `m2d2m data` and a sweep
with `--ray-address auto` run as jobs of that cluster; the test stops the cluster it started."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.helpers import free_port

BIN = Path(sys.executable).parent


@pytest.fixture
def ray_head(tmp_path):
    """A Ray head node on free ports in its own process group, stopped (all of it) afterwards."""
    port = free_port()
    log = (tmp_path / "ray-head.log").open("wb")
    head = subprocess.Popen(
        [
            str(BIN / "ray"),
            "start",
            "--head",
            "--block",
            f"--port={port}",
            "--num-cpus=2",
            "--include-dashboard=false",
            f"--ray-client-server-port={free_port()}",
            f"--dashboard-agent-listen-port={free_port()}",
        ],
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    address = f"127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while subprocess.run([str(BIN / "ray"), "status", f"--address={address}"], capture_output=True).returncode:
        assert head.poll() is None, (tmp_path / "ray-head.log").read_text()
        assert time.monotonic() < deadline, "the head node did not come up within 120 s"
        time.sleep(1)
    try:
        yield address
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        head.wait(timeout=60)
        log.close()


def m2d2m(*arguments: str, cwd: Path, address: str) -> str:
    """Run the command line in its own process, as a user would, joined to the cluster."""
    result = subprocess.run(
        [str(BIN / "m2d2m"), *arguments],
        cwd=cwd,
        capture_output=True,
        text=True,
        env={**os.environ, "RAY_ADDRESS": address},
        timeout=600,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


def test_data_and_a_sweep_run_on_a_cluster_started_with_ray_start(ray_head, trained_project, tiny_testset):
    out = trained_project / "cluster-data"
    printed = m2d2m(
        "data",
        "--dataset",
        "synthetic",
        "--raw",
        str(trained_project / "raw"),
        "--out",
        str(out),
        "--ray-address",
        "auto",
        cwd=trained_project,
        address=ray_head,
    )
    port = ray_head.rsplit(":", 1)[1]
    assert "joined the cluster at " in printed and f":{port} (2 CPUs)" in printed
    assert json.loads((out / "manifest.json").read_text())["splits"]["test"]["originals"] == 8

    config = {
        "dataset": "tiny",
        "kind": "sampling",
        "checkpoint": "latest",
        "train_config": "unused",
        "evaluator": "latest",
        "testset": str(tiny_testset),
        "method": "tps",
        "repeats": 1,
        "search": "grid",
        "samples": 1,
        "space": {"eta": [0.25], "ts": [2, 4]},
        "resources": {"cpu": 1, "gpu": 0},
        "max_concurrent": 2,
        "max_failures": 0,
    }
    (trained_project / "cluster-sweep.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    printed = m2d2m(
        "sweep",
        "--config",
        str(trained_project / "cluster-sweep.yaml"),
        "--ray-address",
        "auto",
        cwd=trained_project,
        address=ray_head,
    )
    assert f":{port} (2 CPUs)" in printed and "multi/tps/jerk" in printed
    summary = json.loads((trained_project / "runs" / "tiny" / "sweep" / "cluster-sweep" / "summary.json").read_text())
    assert [row["ts"] for row in summary] == [2, 4]
