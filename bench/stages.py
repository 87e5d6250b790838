"""What the long benches that drive the `m2d2m` command line share (bench/reproduce.py,
bench/learning_curves.py): running a verb in this process, and a record of the stages started and
finished (``state.json``), so that a stopped bench continues instead of training and evaluating
everything again."""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from m2d2m.atomic import atomic_path
from orchestration.cli import main as m2d2m
from orchestration.runs import mark_latest, read_run_info, stage_dir

DATASET = "synthetic"
RUNS = Path("runs") / DATASET


def run(*argv: str) -> None:
    """One `m2d2m` verb, in this process; any failure stops the bench."""
    print("$ m2d2m " + " ".join(argv), flush=True)
    code = m2d2m(list(argv))
    if code:
        raise SystemExit(f"m2d2m {argv[0]} failed (exit {code}); the runs so far are kept, run again to continue")


def latest(stage: str) -> Path:
    return RUNS / stage / (RUNS / stage / "latest").read_text(encoding="utf-8").strip()


@contextmanager
def keeping_latest(stage: str) -> Iterator[None]:
    """Leave ``stage``'s ``latest`` as it was: the bench's runs must not become what `make generate`
    or `make eval` pick up."""
    marker = RUNS / stage / "latest"
    before = marker.read_text(encoding="utf-8").strip() if marker.exists() else None
    try:
        yield
    finally:
        if before is not None:
            mark_latest(RUNS / stage / before)


class Progress:
    """What a bench has started and finished (``state.json``) under the ``settings`` it was
    started with; other settings are refused unless ``restart``."""

    def __init__(self, path: Path, settings: dict[str, Any], restart: bool) -> None:
        self.path = path
        recorded = json.loads(path.read_text(encoding="utf-8")) if path.exists() and not restart else None
        if recorded is not None and recorded["scale"] != settings:
            raise SystemExit(
                f"{path} records a run at other settings ({recorded['scale']}); "
                "run it with the same arguments to continue, or add --restart to start over"
            )
        self.state = recorded or {"scale": settings, "started": {}, "finished": {}}
        self._write()

    def record(self, name: str, value: Any) -> None:
        """Keep ``value`` in the state under ``name`` (a bench's results so far)."""
        self.state[name] = value
        self._write()

    def stage(self, key: str, stage: str, finish: Callable[[Path], Any], *argv: str, resume: Sequence[str]) -> Any:
        """Run ``argv`` for ``key`` unless it finished; a run of ``stage`` that this key started
        and that did not finish is continued with ``resume`` + its folder (``{run}``) instead.
        ``finish(run_dir)`` gives what the finished key records."""
        if key in self.state["finished"]:
            return self.state["finished"][key]
        earlier = self._run_started_by(key, stage)
        if earlier is None:  # never started, or stopped before its run folder existed
            self.state["started"][key] = time.time()
            self.state.setdefault("process", {})[key] = os.getpid()
            self._write()
            run(*argv)
        elif read_run_info(earlier).get("status") != "finished":
            run(*[arg.replace("{run}", str(earlier)) for arg in resume])
        self.state["finished"][key] = finish(self._run_started_by(key, stage) or latest(stage))
        self._write()
        return self.state["finished"][key]

    def _run_started_by(self, key: str, stage: str) -> Path | None:
        """The newest run of ``stage`` that the process which started ``key`` began after it, if
        any: a run another command started meanwhile in the same stage is not this key's. (A key
        recorded before processes were, and its runs, have none: they match each other only.)"""
        since, process = self.state["started"].get(key), self.state.get("process", {}).get(key)
        folder = stage_dir(DATASET, stage)
        if since is None or not folder.exists():
            return None
        infos = [(read_run_info(p), p) for p in folder.iterdir() if (p / "run.json").exists()]
        runs = [
            (info.get("started", 0.0), p)
            for info, p in infos
            if info.get("started", 0.0) >= since and info.get("pid") == process
        ]
        return max(runs)[1] if runs else None

    def _write(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.path) as temporary:
            temporary.write_text(json.dumps(self.state, indent=2), encoding="utf-8")
