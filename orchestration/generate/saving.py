"""A generation's files written and recorded: into a new run folder whose ``run.json`` says
how it ended, or into the staging folder of :func:`orchestration.generate.outputs.staged`, and
logged to MLflow (one warning line, not a lost result, when the tracking store cannot take it).
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from m2d2m.motion.clip import Motion
from m2d2m.motion.files.formats import FORMATS
from m2d2m.progress import progress
from orchestration.errors import UserError
from orchestration.generate.outputs import Output
from orchestration.runs import new_run_dir, write_run_info
from orchestration.tracking import experiment_name, tracked_run, unreachable

GENERATE_STAGE = "generate"


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (``kill``, a scheduler) stops like Ctrl-C: temporary files are removed and the run
    is marked failed, where the default handler would end the process on the spot."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def save_generation(
    motion: Motion, output: Output, prompts: Sequence[str], dataset: str, track: bool = True
) -> tuple[dict[str, Path], str | None]:
    """Write ``motion``'s files (a progress bar on stderr while animations render) and, with
    ``track``, log them to MLflow; returns format → path and the MLflow run id.

    Without a ``directory`` the files go to a new run folder ``runs/<dataset>/generate/<id>/``
    whose ``run.json`` says ``running`` while they are written, then ``finished`` (with the
    files, the MLflow run id and the quality figures) or ``failed``, like a training run's. With
    a ``staging`` folder they are written (and logged) there; the paths returned are those they
    have in ``directory`` once :func:`~orchestration.generate.outputs.staged` has moved them.
    """
    run_dir = output.directory is None
    directory = new_run_dir(dataset, GENERATE_STAGE) if run_dir else output.directory
    if run_dir:
        write_run_info(
            directory,
            stage=GENERATE_STAGE,
            dataset=dataset,
            status="running",
            prompts=list(prompts),
            actions=motion.actions,
            settings=motion.settings,
        )
    frames = len(motion.joints) * sum(FORMATS[kind].animation for kind in output.formats)
    try:
        with (
            _sigterm_as_interrupt(),
            progress(total=frames, unit="frame", desc="rendering", leave=False, disable=not frames) as bar,
        ):
            written = motion.save(
                output.staging or directory,
                output.name,
                output.formats,
                progress=lambda _: bar.update(),
                delivery=output.delivery,
            )
            run_id = _tracked(motion, prompts, written, dataset, directory) if track else None
    except BaseException as error:
        if run_dir:
            write_run_info(directory, status="failed", error=f"{type(error).__name__}: {error}")
        if isinstance(error, (ValueError, RuntimeError)):  # ffmpeg failed, or a file could not be written
            raise UserError(str(error)) from error
        raise
    files = {kind: directory / path.name for kind, path in written.items()}
    if run_dir:
        write_run_info(
            directory,
            status="finished",
            files={k: str(v) for k, v in files.items()},
            mlflow_run_id=run_id,
            quality=motion.quality,
        )
    return files, run_id


def _tracked(motion: Motion, prompts: Sequence[str], files: dict[str, Path], dataset: str, folder: Path) -> str | None:
    """:func:`log_generation`, or, when the tracking store cannot take it, one warning line naming
    the ``folder`` the files end in and None: the files are written already, and a dead server
    must neither hold them nor lose them."""
    problem = unreachable()
    if problem is None:
        try:
            return log_generation(motion, prompts, files, dataset)
        except Exception as error:  # MLflow's errors have no common base (HTTP, SQL, file store)
            problem = f"MLflow could not record it ({type(error).__name__}: {str(error).splitlines()[0][:200]})"
    print(f"warning: {problem}; the generation is not tracked, its files are in {folder}", file=sys.stderr)
    return None


def log_generation(motion: Motion, prompts: Sequence[str], files: dict[str, Path], dataset: str) -> str:
    """Record one generation in MLflow (experiment ``<dataset>/generate``): prompts, actions,
    settings as params, the quality figures as metrics, each file once as an artifact; returns
    the MLflow run id."""
    params = {
        **{k: str(v) for k, v in motion.settings.items()},
        "prompts": " | ".join(prompts)[:500],
        "actions": " | ".join(motion.actions)[:500],
        "seconds": f"{motion.seconds:.2f}",
    }
    tags = {
        "dataset": dataset,
        "stage": GENERATE_STAGE,
        "model": str(motion.settings.get("model")),
        "method": str(motion.settings.get("method")),
    }
    if "edit_parent_run" in motion.settings:  # an edit of a served generation: nested under it in the MLflow UI
        tags["mlflow.parentRunId"] = str(motion.settings["edit_parent_run"])
    with tracked_run(experiment_name(dataset, GENERATE_STAGE), tags=tags, params=params) as (client, run_id):
        for name, value in motion.quality.items():
            client.log_metric(run_id, name, value)
        for kind, path in files.items():  # each file with those its format wrote beside it (the npy's sidecar, ...)
            stem = path.name.removesuffix(f".{kind}")
            for name in FORMATS[kind].file_names(stem):
                if (path.parent / name).is_file():
                    client.log_artifact(run_id, str(path.parent / name), artifact_path="motion")
    return run_id
