"""Two commands on one project at once (docs/reliability.md, "Concurrent commands"): each pair
either both finish correctly or the later one refuses in one line, and ``latest``, the run
records and the token sets are never left inconsistent."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from orchestration.cli import main
from pipelines.tokenize import check_tokens
from tests.helpers import one_line_error
from tests.test_sweep import sweep_config

ROOT = Path(__file__).resolve().parents[1]


def start(argv: list[str], cwd: Path) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "RAY_ADDRESS")}
    return subprocess.Popen(
        [sys.executable, "-m", "orchestration.cli", *argv],
        cwd=cwd,
        env={**env, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(process: subprocess.Popen) -> None:
    err = process.communicate(timeout=600)[1]
    assert process.returncode == 0, err[-3000:]


def held(lock_file: Path) -> bool:
    """Whether a process holds ``lock_file`` now, read from the kernel's table of locks
    (/proc/locks: ``FLOCK … major:minor:inode``) without taking it: a probe that took the lock
    for an instant would make the command it watches, taking it then, refuse as busy."""
    try:
        found = lock_file.stat()
    except FileNotFoundError:
        return False
    where = f"{os.major(found.st_dev):02x}:{os.minor(found.st_dev):02x}:{found.st_ino}"
    return any(
        "FLOCK" in line.split() and where in line.split() for line in Path("/proc/locks").read_text().splitlines()
    )


def wait_until(condition: Callable[[], bool], process: subprocess.Popen, what: str) -> bool:
    """Poll ``condition`` while ``process`` runs; False when it ended first."""
    deadline = time.monotonic() + 300
    while not condition():
        if process.poll() is not None:
            return False
        assert time.monotonic() < deadline, f"never reached: {what}"
        time.sleep(0.02)
    return True


def one_line_refusal(capfd, verb: str, argv: list[str], says: str) -> None:
    line = one_line_error(argv, capfd)
    assert line.startswith(f"m2d2m {verb}: error:") and says in line, line


def finished_runs(project: Path, stage: str) -> set[str]:
    return {
        info.parent.name
        for info in (project / "runs" / "tiny" / stage).glob("*/run.json")
        if json.loads(info.read_text())["status"] == "finished"
    }


def latest(project: Path, stage: str) -> str:
    return (project / "runs" / "tiny" / stage / "latest").read_text().strip()


@pytest.fixture(scope="module")
def two_vq_runs(trained_project) -> list[str]:
    """Two trainings of one stage at once: both finish, ``latest`` names a finished one of them."""
    before = finished_runs(trained_project, "vq")
    first, second = (start(["train-vq", "--config", str(trained_project / "vq.yaml")], trained_project) for _ in "ab")
    finish(first)
    finish(second)
    new = sorted(finished_runs(trained_project, "vq") - before)
    assert len(new) == 2 and latest(trained_project, "vq") in new
    return new


def test_two_trainings_of_one_stage_both_finish(two_vq_runs):
    assert len(set(two_vq_runs)) == 2


def test_generate_and_evaluate_while_a_training_moves_latest_use_a_finished_model_every_time(
    trained_project, tiny_testset
):
    before = latest(trained_project, "m2d2m")
    training = start(["train-diffusion", "--config", str(trained_project / "diffusion.yaml")], trained_project)
    judged = []
    while training.poll() is None or not judged:
        argv = ["generate", "a person walks", "--dataset", "tiny", "--seconds", "1", "--ts", "4", "--no-track"]
        assert main(argv + ["--formats", "npy", "--out", str(trained_project / "while-training"), "--overwrite"]) == 0
        argv = ["evaluate", "--dataset", "tiny", "--testset", str(tiny_testset), "--repeats", "1", "--ts", "4"]
        assert main(argv) == 0
        record = trained_project / "runs" / "tiny" / "eval" / latest(trained_project, "eval") / "run.json"
        (candidate,) = json.loads(record.read_text())["settings"]["candidates"]
        judged.append(Path(candidate["checkpoint"]).parent.name)
    finish(training)
    assert latest(trained_project, "m2d2m") != before
    assert set(judged) | {latest(trained_project, "m2d2m")} <= finished_runs(trained_project, "m2d2m")  # read once


def test_two_testsets_of_one_name_at_once_both_finish_with_one_whole_set(trained_project, tmp_path):
    from pipelines.testset import check_testset

    data = tmp_path / "data"  # the dataset without its test sets
    shutil.copytree(trained_project / "data", data, ignore=shutil.ignore_patterns("testsets", "tokens"))
    argv = ["testset", "--dataset", "tiny", "--data", str(data), "--n", "2", "--seed", "5", "--mirrors", "distinct"]
    first, second = (start(argv, trained_project) for _ in "ab")
    finish(first)
    finish(second)
    (built,) = (data / "testsets").glob("n2-*")
    assert check_testset(built) == [] and not list((data / "testsets").glob(".*.partial"))


def test_tokenize_while_a_training_tokenizes_first(trained_project, two_vq_runs, capfd):
    vq = trained_project / "runs" / "tiny" / "vq" / two_vq_runs[0]  # its tokens are not made yet
    data = Path(yaml.safe_load((trained_project / "vq.yaml").read_text())["data"]["dir"])
    tokens = data / "tokens" / two_vq_runs[0]
    lock = tokens.parent / f".{tokens.name}.lock"
    argv = ["train-diffusion", "--config", str(trained_project / "diffusion.yaml"), "--set", f"vq={vq}"]
    training = start(argv, trained_project)
    if wait_until(lambda: held(lock), training, "the training's tokenizing"):
        one_line_refusal(
            capfd,
            "tokenize",
            ["tokenize", "--dataset", "tiny", "--vq", str(vq)],
            "another command is writing these tokens; let it finish",
        )
    finish(training)
    assert check_tokens(tokens) == []
    assert main(["tokenize", "--dataset", "tiny", "--vq", str(vq)]) == 0  # now reused as it is


def test_a_second_sweep_of_one_name_refuses_while_the_first_runs(trained_project, tiny_testset, capfd):
    config = trained_project / "pair.yaml"
    config.write_text(yaml.safe_dump(sweep_config(tiny_testset, space={"eta": [0.25], "ts": [4]})), encoding="utf-8")
    first = start(["sweep", "--config", str(config)], trained_project)
    lock = trained_project / "runs" / "tiny" / "sweep" / ".pair.lock"
    assert wait_until(lambda: held(lock), first, "the first sweep's lock")
    one_line_refusal(
        capfd, "sweep", ["sweep", "--config", str(config)], "the sweep 'pair' is running in another command"
    )
    finish(first)
    assert (trained_project / "runs" / "tiny" / "sweep" / "pair" / "summary.json").exists()


def test_two_evaluations_finish_and_a_second_resume_of_one_run_refuses(trained_project, tiny_testset, capfd):
    argv = ["evaluate", "--dataset", "tiny", "--testset", str(tiny_testset), "--repeats", "1", "--ts", "4"]
    before = finished_runs(trained_project, "eval")
    first, second = (start(argv, trained_project) for _ in "ab")
    finish(first)
    finish(second)
    new = sorted(finished_runs(trained_project, "eval") - before)
    assert len(new) == 2 and latest(trained_project, "eval") in new
    run_dir = trained_project / "runs" / "tiny" / "eval" / new[0]
    next(iter((run_dir / "results").glob("multi-*.json"))).unlink()
    resuming = start(["evaluate", "--dataset", "tiny", "--resume", new[0]], trained_project)
    if wait_until(lambda: held(run_dir / ".lock"), resuming, "the resumed evaluation's lock"):
        one_line_refusal(
            capfd,
            "evaluate",
            ["evaluate", "--dataset", "tiny", "--resume", new[0]],
            "is in use by another `m2d2m evaluate`",
        )
    finish(resuming)
    assert json.loads((run_dir / "run.json").read_text())["status"] == "finished"


def test_resuming_a_run_another_command_trains_refuses_in_one_line(trained_project, two_vq_runs, capfd):
    before = {p.name for p in (trained_project / "runs" / "tiny" / "vq").iterdir()}
    training = start(["train-vq", "--config", str(trained_project / "vq.yaml")], trained_project)

    def its_run_is_held() -> bool:
        new = [p for p in (trained_project / "runs" / "tiny" / "vq").iterdir() if p.name not in before and p.is_dir()]
        return bool(new) and held(new[0] / ".lock")

    assert wait_until(its_run_is_held, training, "the training's run")
    one_line_refusal(
        capfd,
        "train-vq",
        ["train-vq", "--config", str(trained_project / "vq.yaml"), "--resume"],
        "is being trained by another command; let it finish first",
    )
    finish(training)
    assert latest(trained_project, "vq") in finished_runs(trained_project, "vq")
