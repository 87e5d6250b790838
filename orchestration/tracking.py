"""MLflow tracking: where the store is, and experiments named ``<dataset>/<stage>``.

Default store: ``sqlite:///<project>/mlflow.db`` with artifacts in ``<project>/mlruns``, where the
project is the working directory the command runs in (the Makefile runs from the repository
root). ``MLFLOW_TRACKING_URI`` points everything at a server instead. Paths are absolute because
Ray workers and Tune trials run in other directories, and MLflow keeps them so in the store; a
copied or moved project's store is pointed at its own ``mlruns`` by :func:`follow_project`.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

from orchestration.errors import UserError

STORE = "mlflow.db"
ARTIFACTS = "mlruns"


def _project_store() -> Path:
    return (Path.cwd() / STORE).resolve()


def _on_project_store() -> bool:
    """Whether the runs go to the project's own SQLite store: no ``MLFLOW_TRACKING_URI``, or the one
    MLflow itself exports once a client named the store (``mlflow.set_tracking_uri``)."""
    uri = os.environ.get("MLFLOW_TRACKING_URI")
    return not uri or uri == f"sqlite:///{_project_store()}"


def tracking_uri() -> str:
    """The store every run goes to: ``MLFLOW_TRACKING_URI``, else the project's own, made to follow
    the project first."""
    if not _on_project_store():
        return os.environ["MLFLOW_TRACKING_URI"]
    follow_project(_project_store())
    return f"sqlite:///{_project_store()}"


def artifact_location(experiment: str) -> str | None:
    """Where a new experiment keeps its artifacts: beside the SQLite store by default; a tracking
    server decides for itself."""
    if not _on_project_store():
        return None
    return (Path.cwd() / ARTIFACTS / experiment.replace("/", "-")).resolve().as_uri()


def _artifact_root(location: str) -> tuple[str, Path] | None:
    """The ``.../mlruns`` an artifact location lies under, as the store spells it (a path or a
    ``file:`` URI) and as a path; None for one elsewhere (an object store, a server's)."""
    end = location.rfind(f"/{ARTIFACTS}/")
    if end < 0:
        return None
    spelled = location[: end + len(ARTIFACTS) + 1]
    if spelled.startswith("file:"):
        return spelled, Path(unquote(urlparse(spelled).path))
    return (spelled, Path(spelled)) if spelled.startswith("/") else None


@functools.cache
def follow_project(store: Path) -> None:
    """Point the artifact locations of a store that was copied with its project, or moved, from the
    old ``mlruns`` to the one beside ``store``: MLflow records them absolute, so new runs of a copy
    would write their artifacts into the original project, and old ones be read from there. Once per
    process and store; nothing is written when nothing moved."""
    if not store.is_file():
        return
    here = store.parent / ARTIFACTS
    with contextlib.closing(sqlite3.connect(store, timeout=60)) as connection:
        try:
            locations = [row[0] for row in connection.execute("SELECT artifact_location FROM experiments")]
        except sqlite3.OperationalError:  # no MLflow tables (yet): nothing recorded
            return
        moved = {}
        for location in locations:
            root = _artifact_root(location or "")
            if root is not None and root[1] != here:
                moved[root[0]] = here.as_uri() if root[0].startswith("file:") else str(here)
        with connection:  # one transaction
            for old, new in moved.items():
                for table, column in (("experiments", "artifact_location"), ("runs", "artifact_uri")):
                    connection.execute(
                        f"UPDATE {table} SET {column} = ? || substr({column}, ?) WHERE substr({column}, 1, ?) = ?",
                        (new, len(old) + 1, len(old) + 1, old + "/"),
                    )


SERVER_TIMEOUT_S = 5.0  # how long a tracking server may take to answer before a result goes unrecorded


def unreachable(timeout_s: float = SERVER_TIMEOUT_S) -> str | None:
    """Why the tracking server does not answer (None when it does, or when the store is not a
    server): MLflow's client retries a dead one for minutes before it gives up, so a command
    whose result is already on disk asks first, briefly."""
    import urllib.error
    import urllib.request

    uri = tracking_uri()
    if urlparse(uri).scheme not in ("http", "https"):
        return None
    try:
        with urllib.request.urlopen(f"{uri.rstrip('/')}/health", timeout=timeout_s):
            return None
    except urllib.error.HTTPError:  # it answered (a proxy in front may not know /health)
        return None
    except (OSError, ValueError) as error:
        reason = getattr(error, "reason", error)
        return f"the MLflow server at {uri} did not answer in {timeout_s:g} s ({reason})"


def experiment_name(dataset: str, stage: str) -> str:
    return f"{dataset}/{stage}"


def client():
    """An MLflow client on the project's store."""
    import mlflow

    return mlflow.MlflowClient(tracking_uri=tracking_uri())


def log_batch(mlflow_client, run_id: str, params: dict | None = None, metrics: dict | None = None) -> None:
    """Params (as strings) and metrics of a run in one request."""
    import time

    from mlflow.entities import Metric, Param

    now = int(time.time() * 1000)
    mlflow_client.log_batch(
        run_id,
        params=[Param(k, str(v)) for k, v in (params or {}).items()],
        metrics=[Metric(k, float(v), now, 0) for k, v in (metrics or {}).items()],
    )


def ensure_experiment(name: str) -> str:
    """Create the experiment once (from the driver, before any worker logs to it) and return its id."""
    client_ = client()
    existing = client_.get_experiment_by_name(name)
    if existing is not None:
        return existing.experiment_id
    return client_.create_experiment(name, artifact_location=artifact_location(name))


def start_run(
    experiment: str,
    run_name: str | None = None,
    tags: dict[str, str] | None = None,
    params: dict[str, Any] | None = None,
    parent: tuple[str, str] | None = None,
) -> str:
    """A new MLflow run in the experiment named ``experiment`` — or, given ``parent`` (experiment
    id, run id), a child run of that run in its experiment — with its tags and params; its id."""
    client_ = client()
    tags = dict(tags or {})
    if parent is None:
        experiment_id = ensure_experiment(experiment)
    else:
        experiment_id, tags["mlflow.parentRunId"] = parent
    run_id = client_.create_run(experiment_id, run_name=run_name, tags=tags).info.run_id
    if params:
        log_batch(client_, run_id, params=params)
    return run_id


@contextlib.contextmanager
def finishing(run_id: str) -> Iterator[Any]:
    """The client, for logging to ``run_id``; the run ends FINISHED when the block completes and
    FAILED when it raises (a Ctrl-C included), never left RUNNING by an error."""
    client_ = client()
    try:
        yield client_
    except BaseException:
        client_.set_terminated(run_id, "FAILED")
        raise
    client_.set_terminated(run_id)


@contextlib.contextmanager
def tracked_run(
    experiment: str,
    run_name: str | None = None,
    tags: dict[str, str] | None = None,
    params: dict[str, Any] | None = None,
) -> Iterator[tuple[Any, str]]:
    """:func:`start_run` and :func:`finishing` in one: the client and the new run's id."""
    run_id = start_run(experiment, run_name, tags, params)
    with finishing(run_id) as client_:
        yield client_, run_id


def download_model_file(run_id: str, name: str) -> Path:
    """The model file ``name`` an MLflow run logged under ``model/``, downloaded from the store,
    or a one-line error."""
    import mlflow

    mlflow.set_tracking_uri(tracking_uri())
    try:
        return Path(mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=f"model/{name}"))
    except Exception as error:  # an unknown id or a run without the file: one line for the user
        raise UserError(f"MLflow run {run_id} has no model/{name} ({type(error).__name__})") from error


# MLflow 3's UI opens on its GenAI view (traces, token cost) unless a page's address asks for the
# model-training one, where runs, params and metrics are (the UI's own workflowType parameter)
RUNS_VIEW = "workflowType=machine_learning"


def ui_runs_page(base: str, experiment_id: str | None = None, run_id: str | None = None) -> str:
    """The MLflow UI's page of the experiments, of one experiment's runs, or of one run, in its
    model-training view."""
    page = "experiments" if experiment_id is None else f"experiments/{experiment_id}"
    page += "" if run_id is None else f"/runs/{run_id}"
    return f"{base.rstrip('/')}/#/{page}?{RUNS_VIEW}"


def ui_command(host: str, port: int) -> list[str]:
    """The MLflow UI on the project's store (``mlflow server`` with the same backend as every run)."""
    import shutil
    import sys

    mlflow = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or "mlflow"
    return [
        mlflow,
        "server",
        "--backend-store-uri",
        tracking_uri(),
        "--host",
        host,
        "--port",
        str(port),
        "--workers",
        "1",
    ]
