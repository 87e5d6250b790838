"""The tracking store under many writers: N processes create a run each and log to it at once,
against the default SQLite file and against an MLflow tracking server backed by PostgreSQL with
its artifacts proxied by the server (docs/cluster.md, "An MLflow tracking server"). Nothing may
be lost: every metric of every run, every run finished, every artifact listed; and no writer may
fail ("database is locked"). Bounded: 8 writers × 40 steps, each process within 120 s.

PostgreSQL is Debian's ``postgresql``, started by the test in a temporary folder and stopped
after; `.ci/run` installs it when it runs as root with apt; elsewhere that case is skipped with a
one-line reason.
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import mlflow
import pytest

from tests.helpers import free_port

pytestmark = pytest.mark.slow  # eight writer processes, and a PostgreSQL server
ROOT = Path(__file__).resolve().parents[1]
WRITERS, STEPS = 8, 40
WRITER = """
import sys
from pathlib import Path
from orchestration.tracking import finishing, log_batch, start_run
index = int(sys.argv[1])
run_id = start_run("tiny/sweep", run_name=f"writer-{index}", tags={"writer": str(index)}, params={"index": index})
with finishing(run_id) as client:
    for step in range(int(sys.argv[2])):
        client.log_metric(run_id, "loss", 1.0 / (step + 1), step=step)
        log_batch(client, run_id, metrics={"eta": 0.25, "ts": 90.0})
    note = Path(sys.argv[3]) / f"note-{index}.txt"
    note.write_text(f"writer {index}\\n", encoding="utf-8")
    client.log_artifact(run_id, str(note))
print(run_id)
"""


def run_writers(tracking_uri: str, scratch: Path) -> list[str]:
    """WRITERS processes at once, each logging STEPS steps, a batch per step and an artifact."""
    env = {**os.environ, "MLFLOW_TRACKING_URI": tracking_uri, "PYTHONPATH": str(ROOT)}
    subprocess.run(
        [sys.executable, "-c", "from orchestration.tracking import ensure_experiment; ensure_experiment('tiny/sweep')"],
        env=env,
        cwd=scratch,
        check=True,
    )  # the driver creates the experiment before any trial starts, as a sweep does
    writers = [
        subprocess.Popen(
            [sys.executable, "-c", WRITER, str(index), str(STEPS), str(scratch)],
            env=env,
            cwd=scratch,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for index in range(WRITERS)
    ]
    run_ids = []
    for writer in writers:
        out, err = writer.communicate(timeout=120)
        assert writer.returncode == 0 and "locked" not in err, err[-2000:]
        run_ids.append(out.split()[-1])
    return run_ids


def assert_nothing_lost(tracking_uri: str, run_ids: list[str]) -> None:
    client = mlflow.MlflowClient(tracking_uri=tracking_uri)
    for index, run_id in enumerate(run_ids):
        run = client.get_run(run_id)
        assert run.info.status == "FINISHED" and run.data.params["index"] == str(index)
        history = client.get_metric_history(run_id, "loss")
        assert sorted(m.step for m in history) == list(range(STEPS))
        assert run.data.metrics["eta"] == 0.25 and run.data.metrics["ts"] == 90.0
        assert [a.path for a in client.list_artifacts(run_id)] == [f"note-{index}.txt"]
    experiment = client.get_experiment_by_name("tiny/sweep")
    assert len(client.search_runs([experiment.experiment_id], max_results=100)) == WRITERS


def test_many_writers_lose_nothing_in_the_default_sqlite_store(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    assert_nothing_lost(uri, run_writers(uri, tmp_path))


# ----------------------------------------------------------------------- PostgreSQL and a server
def postgres_bin() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    return Path(found[-1]).parent if found else None


def as_postgres_user(command: list[str]) -> list[str]:
    """PostgreSQL refuses to run as root: as root, the command runs as the ``postgres`` user."""
    return ["runuser", "-u", "postgres", "--", *command] if os.geteuid() == 0 else command


@pytest.fixture
def postgres() -> Iterator[str]:
    """A PostgreSQL server on a free loopback port with an empty database ``mlflow``: its URI."""
    binaries = postgres_bin()
    try:
        import psycopg2  # noqa: F401  (MLflow's PostgreSQL driver)
    except ImportError:
        binaries = None
    if binaries is None:
        pytest.skip("no PostgreSQL here (apt-get install postgresql; pip install psycopg2-binary)")
    home = Path(tempfile.mkdtemp(prefix="m2d2m-postgres-"))  # not under pytest's 0700 folders
    os.chmod(home, 0o777)
    if os.geteuid() == 0:
        shutil.chown(home, "postgres")
    data, port = home / "data", free_port()
    run = lambda *command: subprocess.run(as_postgres_user(list(command)), check=True, capture_output=True)  # noqa: E731
    run(str(binaries / "initdb"), "-D", str(data), "-U", "mlflow", "--auth=trust")
    options = f"-p {port} -k {home} -c listen_addresses=127.0.0.1"
    run(str(binaries / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(home / "log"), "-w", "start")
    try:
        run(str(binaries / "createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", "mlflow", "mlflow")
        yield f"postgresql+psycopg2://mlflow@127.0.0.1:{port}/mlflow"
    finally:
        run(str(binaries / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop")
        shutil.rmtree(home, ignore_errors=True)


@pytest.fixture
def tracking_server(postgres: str, tmp_path) -> Iterator[str]:
    """``mlflow server`` on PostgreSQL, proxying artifacts into a folder: its URL (docs/cluster.md)."""
    port = free_port()
    log = (tmp_path / "server.log").open("wb")
    server = subprocess.Popen(
        [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", postgres]
        + ["--artifacts-destination", (tmp_path / "artifacts").as_uri(), "--serve-artifacts"]
        + ["--host", "127.0.0.1", "--port", str(port), "--workers", "2"],
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        import httpx

        while True:
            try:
                if httpx.get(url + "/health", timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert server.poll() is None and time.monotonic() < deadline, (tmp_path / "server.log").read_text()[-3000:]
            time.sleep(0.5)
        yield url
    finally:
        if server.poll() is None:
            os.killpg(server.pid, 15)
        server.wait(timeout=30)


def test_many_writers_lose_nothing_on_a_tracking_server_backed_by_postgresql(tracking_server, tmp_path):
    scratch = tmp_path / "writers"
    scratch.mkdir()
    assert_nothing_lost(tracking_server, run_writers(tracking_server, scratch))
    # the artifacts went through the server into its destination, not beside the writers
    assert len(list((tmp_path / "artifacts").rglob("note-*.txt"))) == WRITERS
