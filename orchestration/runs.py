"""Run directories: ``runs/<dataset>/<stage>/<run-id>/`` holds a stage's checkpoints, resolved
config and MLflow run id; ``runs/<dataset>/<stage>/latest`` names the newest successful run, so
the next stage finds its input without arguments."""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from m2d2m.atomic import atomic_path
from m2d2m.layout import VQ_FILE
from m2d2m.locks import Busy, holding
from m2d2m.motion.representation.body_parts import FULL
from orchestration.errors import NotInProject, UserError
from orchestration.tracking import download_model_file

RUNS_ROOT = Path("runs")
RUN_FILE = "run.json"
LATEST = "latest"
# the stages that are no model of the registry: their runs' folders and MLflow experiments, and a file they hold
VQ_STAGE = "vq"
EVALUATOR_STAGE = "evaluator"
EVALUATOR_FILE = "evaluator.pt"
MLFLOW_ID = re.compile(r"^[0-9a-f]{32}$")


def enter_project(project: str, tracking_uri: str, cpus: float) -> None:
    """Make a Ray process (a Tune trial, a Ray Train worker) work like the driver: in the project
    directory, so relative ``runs/`` and ``data/`` mean the same, on the driver's MLflow store, with
    as many torch threads as CPUs it reserved rather than every core of the node."""
    import torch

    os.chdir(project)
    os.environ["MLFLOW_TRACKING_URI"] = tracking_uri
    torch.set_num_threads(max(1, int(cpus)))


@contextmanager
def exclusive(lock_file: Path, busy: str) -> Iterator[None]:
    """:func:`m2d2m.locks.holding` for a command: another command holding it is a one-line error."""
    try:
        with holding(lock_file, busy):
            yield
    except Busy as error:
        raise UserError(str(error)) from None


def run_in_use(run_dir: Path, verb: str) -> contextlib.AbstractContextManager[None]:
    """Hold ``run_dir`` for the command ``m2d2m <verb>`` that writes it (a second one refuses)."""
    return exclusive(run_dir / ".lock", f"{run_dir} is in use by another `m2d2m {verb}`; let it finish first")


def stage_dir(dataset: str, stage: str) -> Path:
    return RUNS_ROOT / dataset / stage


def ensure_stage_dir(dataset: str, stage: str) -> Path:
    """The folder of a stage's runs, made now: a file in its way, or a folder one may not write,
    is one line before any work rather than after it."""
    folder = stage_dir(dataset, stage)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise _unmade(f"{folder}/", folder, error) from error
    return folder


def _unmade(path: str | Path, folder: Path, error: OSError) -> UserError:
    return UserError(
        f"cannot make the run folder {path}: {error.strerror}; "
        f"{folder} and the folders above it must be folders you can write"
    )


def new_run_dir(dataset: str, stage: str) -> Path:
    """A fresh, sortable run directory: ``<UTC time>-<random>``, recording when and by which
    process it was started (so a bench tells its own runs from those of a command run beside it)."""
    folder = ensure_stage_dir(dataset, stage)
    started = time.time()
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(started))
    while True:
        path = folder / f"{stamp}-{secrets.token_hex(2)}"
        try:
            path.mkdir()
            break
        except FileExistsError:  # the same second and the same four hex digits: draw again
            if not path.is_dir():
                raise UserError(f"cannot make the run folder {path}: a file is in the way") from None
        except OSError as error:  # a read-only folder, a full disk
            raise _unmade(path, folder, error) from error
    write_run_info(path, started=started, pid=os.getpid())
    return path


def write_run_info(run_dir: Path, **info: Any) -> dict[str, Any]:
    """Merge ``info`` into the run's ``run.json`` (status, MLflow run id, config, outputs)."""
    path = run_dir / RUN_FILE
    current = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
    current.update(info)
    with atomic_path(path) as partial:
        partial.write_text(json.dumps(current, indent=2, sort_keys=True, default=str) + "\n", encoding="utf-8")
    return current


def read_run_info(run_dir: Path) -> dict[str, Any]:
    path = run_dir / RUN_FILE
    if not path.exists():
        raise UserError(f"{run_dir}: not a run directory (no {RUN_FILE})")
    return json.loads(path.read_text(encoding="utf-8"))


def mark_latest(run_dir: Path) -> None:
    """Point ``latest`` at a finished run; renamed into place, so a kill never leaves it empty."""
    with atomic_path(run_dir.parent / LATEST) as partial:
        partial.write_text(run_dir.name + "\n", encoding="utf-8")


def latest_run(dataset: str, stage: str, made_by: str) -> Path:
    """The newest successful run of a stage, or a one-line error naming ``made_by``, the command
    that makes one."""
    marker = stage_dir(dataset, stage) / LATEST
    if marker.exists():
        return marker.parent / marker.read_text(encoding="utf-8").strip()
    raise NotInProject(f"no finished {stage} run for dataset {dataset!r} yet; run `{made_by}` first")


def never_trained(info: dict[str, Any]) -> bool:
    """A run that failed before its training began (its data could not be made, say): it has no
    MLflow run and nothing to continue."""
    return info.get("status") == "failed" and "mlflow_run_id" not in info


def newest_run(dataset: str, stage: str) -> Path:
    """The most recently started run of a stage, finished or not (what ``--resume`` continues);
    runs that failed before training began are passed over."""
    runs = (
        [p for p in stage_dir(dataset, stage).iterdir() if (p / RUN_FILE).exists()]
        if stage_dir(dataset, stage).exists()
        else []
    )
    infos = {run: read_run_info(run) for run in runs}
    runs = [run for run in runs if not never_trained(infos[run])]
    if not runs:
        raise NotInProject(
            f"nothing to resume: no {stage} run for dataset {dataset!r} under {stage_dir(dataset, stage)} "
            "that began training"
        )
    return max(runs, key=lambda p: infos[p].get("started", 0.0))


def find_run(reference: str, dataset: str, stage: str) -> Path:
    """A run given as a directory, a run-id folder name, or an MLflow run id (looked up in the
    stage's folder)."""
    as_path = Path(reference)
    if (as_path / RUN_FILE).exists():
        return as_path
    candidate = stage_dir(dataset, stage) / reference
    if (candidate / RUN_FILE).exists():
        return candidate
    for run_file in stage_dir(dataset, stage).glob(f"*/{RUN_FILE}"):
        if json.loads(run_file.read_text(encoding="utf-8")).get("mlflow_run_id") == reference:
            return run_file.parent
    raise NotInProject(
        f"no {stage} run {reference!r} for dataset {dataset!r} (a run directory, its name, or its MLflow run id)"
    )


def run_file(reference: str | Path, dataset: str, stage: str, name: str, made_by: str) -> Path:
    """The file ``name`` of a run given as that file itself, ``latest``, a run directory, its name
    or its MLflow run id — downloaded from the tracking store (every stage logs its model files
    under ``model/``) when no local run has that id; a run without the file did not finish,
    which is said in one line. ``made_by`` is the command that makes such a run: a make target
    (``make train-vq``) or an ``m2d2m`` command line."""
    path = Path(reference)
    if path.is_file():
        return path
    if (path / name).is_file():  # a run directory, or a copy of one without run.json
        return path / name
    try:
        run_dir = (
            latest_run(dataset, stage, made_by)
            if str(reference) == "latest"
            else find_run(str(reference), dataset, stage)
        )
    except UserError:
        if not MLFLOW_ID.match(str(reference)):
            raise
        return download_model_file(str(reference), name)
    if not (run_dir / name).is_file():
        resume = f"m2d2m {made_by.split()[-1]}" if made_by.startswith("make ") else made_by
        raise UserError(f"{run_dir} has no {name}: the run did not finish (`{resume} --resume` continues it)")
    return run_dir / name


def vq_stage(part: str) -> str:
    """The stage (run folder, MLflow experiment) of a tokenizer of ``part``: ``vq`` for the whole
    body, ``vq-upper`` / ``vq-lower`` for MMM's part tokenizers, so that each has its own ``latest``
    and a part tokenizer never becomes the one the whole-body models take."""
    return VQ_STAGE if part == FULL else f"{VQ_STAGE}-{part}"


def vq_file(reference: str | Path, dataset: str, part: str = FULL) -> Path:
    """A VQ model file from ``latest``, a ``vq.pt`` path, a Lightning checkpoint of a VQ run, or a
    VQ run directory, name or MLflow run id (the one resolver of every stage that reads a VQ-VAE);
    ``part`` says whose runs ``latest`` and names are looked up in (:func:`vq_stage`)."""
    path = Path(reference)
    if path.suffix == ".ckpt" and path.is_file():
        reference = path.resolve().parent.parent  # <run>/checkpoints/<name>.ckpt
    made_by = (
        "make train-vq"
        if part == FULL
        else f"m2d2m train-vq --config mmm-{part}-{'demo' if dataset == 'synthetic' else dataset}"
    )
    return run_file(reference, dataset, vq_stage(part), VQ_FILE, made_by)
