"""What an evaluation computes, cut into jobs (a candidate's row of one table in one repeat),
and the result file each finished job leaves under the run's ``results/``: the jobs without one
are what a resumed run still has to do; within a job, the batches it finished (:class:`KeptBatches`)."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from m2d2m.motion.clip import Motion, load_motions, save_motions
from orchestration.evaluate.settings import Candidate, EvalSettings
from orchestration.reports import GENERATED

RESULTS = "results"
BATCHES = "batches"  # the generated batches of jobs in progress, kept until each job's result is written


@dataclass(frozen=True)
class Job:
    """One result file's worth of work: a candidate's row of one table in one repeat."""

    candidate: Candidate
    table: str  # "multi", "single", "editing" or "regenerate"
    row: str  # the table's row (the candidate's only one in the single-motion table)
    repeat: int
    method: str | None = None  # multi: the method
    task: str | None = None  # editing: the task and whether with text
    text: bool = True

    @property
    def batches(self) -> str:
        """Which batch count of :func:`evaluate`'s progress bar a job advances by."""
        return {"multi": "multi", "editing": "items", "regenerate": "regenerate"}.get(self.table, "single")


def jobs(settings: EvalSettings) -> list[Job]:
    jobs = [
        Job(c, "multi", settings.row(c, m), r, method=m)
        for c, m in settings.rows()
        for r in range(settings.repeats)
        if settings.multi
    ]
    if settings.single:
        jobs += [
            Job(c, "single", settings.single_row(c), r)
            for c in settings.candidates
            if c.methods
            for r in range(settings.repeats)
        ]
    if settings.regenerate is not None:
        jobs += [
            Job(c, "regenerate", settings.regenerate_row(c), r, method=c.methods[0])
            for c in settings.candidates
            if c.methods
            for r in range(settings.repeats)
        ]
    return jobs + [
        Job(c, "editing", row, r, task=task, text=text)
        for c in settings.candidates
        for task, text, row in settings.edit_rows(c)
        for r in range(settings.repeats)
    ]


def result_file(run_dir: Path, job: Job) -> Path:
    """results/multi-<row>-r<repeat>.json, single-[<model>-]r<repeat>.json, edit-<row>-r<repeat>.json,
    timeline-<row>-r<repeat>.json."""
    if job.table == "single":
        owner = "" if job.row == GENERATED else f"{job.candidate.model}-"
        return run_dir / RESULTS / f"single-{owner}r{job.repeat}.json"
    prefix = {"editing": "edit", "regenerate": "timeline"}.get(job.table, "multi")
    return run_dir / RESULTS / f"{prefix}-{job.row.replace('/', '-')}-r{job.repeat}.json"


def read_result(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


class KeptBatches:
    """A job's finished batches on disk (``<run>/batches/<result file's stem>/<part>-<start>-<size>.npz``),
    each written whole as it is generated, so that an evaluation stopped midway costs at most the
    batch in progress when it is resumed; removed once the job's result is written."""

    def __init__(self, run_dir: Path, job: Job) -> None:
        self.folder = run_dir / BATCHES / result_file(run_dir, job).stem

    def _path(self, part: str, start: int, size: int) -> Path:
        return self.folder / f"{part}-{start}-{size}.npz"

    def load(self, part: str, start: int, size: int) -> list[Motion] | None:
        path = self._path(part, start, size)
        return load_motions(path) if path.exists() else None

    def save(self, part: str, start: int, size: int, motions: list[Motion]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        save_motions(self._path(part, start, size), motions)

    def discard(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
