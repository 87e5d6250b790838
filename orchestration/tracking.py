"""MLflow tracking: where the store is, and experiments named ``<dataset>/<stage>``.

Default store: ``sqlite:///<project>/mlflow.db`` with artifacts in ``<project>/mlruns``, where the
project is the working directory the command runs in (the Makefile runs from the repository
root). ``MLFLOW_TRACKING_URI`` points everything at a server instead. Paths are absolute because
Ray workers and Tune trials run in other directories.
"""

from __future__ import annotations

import os
from pathlib import Path


def tracking_uri() -> str:
    uri = os.environ.get("MLFLOW_TRACKING_URI")
    return uri if uri else f"sqlite:///{(Path.cwd() / 'mlflow.db').resolve()}"


def artifact_location(experiment: str) -> str | None:
    """Where a new experiment keeps its artifacts: beside the SQLite store by default; a tracking
    server decides for itself."""
    if os.environ.get("MLFLOW_TRACKING_URI"):
        return None
    return (Path.cwd() / "mlruns" / experiment.replace("/", "-")).resolve().as_uri()


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
    mlflow_client.log_batch(run_id, params=[Param(k, str(v)) for k, v in (params or {}).items()],
                            metrics=[Metric(k, float(v), now, 0) for k, v in (metrics or {}).items()])


def ensure_experiment(name: str) -> str:
    """Create the experiment once (from the driver, before any worker logs to it) and return its id."""
    client_ = client()
    existing = client_.get_experiment_by_name(name)
    if existing is not None:
        return existing.experiment_id
    return client_.create_experiment(name, artifact_location=artifact_location(name))


def ui_command(host: str, port: int) -> list[str]:
    """The MLflow UI on the project's store (``mlflow server`` with the same backend as every run)."""
    import shutil
    import sys

    mlflow = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or "mlflow"
    return [mlflow, "server", "--backend-store-uri", tracking_uri(), "--host", host, "--port", str(port),
            "--workers", "1"]
