"""A project can move (docs/reliability.md, "A project can move"): a copy at another path, with the
original gone, runs every verb on its own data, runs and MLflow store; a verb run outside a project
says so in one line; and `make` makes a .venv again that was made in another folder."""

from __future__ import annotations

import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
import yaml

from orchestration.cli import main
from tests.helpers import TINY_BODY, TINY_MMM, TINY_MOTIONDIFFUSE, TINY_VQ_RUN, write_part_tokenizer_configs
from tests.test_sweep import sweep_config

REPOSITORY = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def moved(trained_store: Path, tmp_path_factory) -> Iterator[Path]:
    """The session's trained project copied to a new path, its working directory, while the project
    itself is moved aside (the original gone; put back afterwards for the other tests). Its configs
    name the dataset relative to it, as a clone's configs/ do."""
    root = tmp_path_factory.mktemp("moved") / "project"
    shutil.copytree(trained_store, root)
    for name, config in (
        ("vq", TINY_VQ_RUN),
        ("mmm", TINY_MMM),
        ("motiondiffuse", TINY_MOTIONDIFFUSE),
        ("evaluator", yaml.safe_load((trained_store / "evaluator.yaml").read_text(encoding="utf-8"))),
    ):
        relative = {**config, "data": {**config["data"], "dir": "data"}}
        (root / f"{name}.yaml").write_text(yaml.safe_dump(relative), encoding="utf-8")
    aside = trained_store.with_name(trained_store.name + "-aside")
    os.rename(trained_store, aside)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.chdir(root)
            patch.delenv("MLFLOW_TRACKING_URI", raising=False)
            yield root
    finally:
        torch.set_num_threads(threads)
        if trained_store.exists():  # written into by the copy: the failure the test reports
            shutil.rmtree(trained_store)
        os.rename(aside, trained_store)


def recorded_paths(value) -> list[str]:
    """Every string in a JSON value that looks like a path."""
    if isinstance(value, dict):
        return [path for item in value.values() for path in recorded_paths(item)]
    if isinstance(value, list):
        return [path for item in value for path in recorded_paths(item)]
    return [value] if isinstance(value, str) and "/" in value else []


def test_a_moved_project_runs_every_verb_on_its_own_files(moved, trained_store, capsys):
    before = set(moved.glob("runs/*/*/*/run.json"))
    commands = [
        ["data", "--dataset", "synthetic", "--raw", "raw", "--out", "data", "--samples-per-shard", "4"],
        ["tokenize", "--dataset", "tiny"],
        ["train-diffusion", "--config", "diffusion.yaml"],  # the VQ run's tokens, made before the move
        ["train-mmm", "--config", "mmm.yaml"],
        ["train-motiondiffuse", "--config", "motiondiffuse.yaml"],
        ["train-evaluator", "--config", "evaluator.yaml"],
        ["evaluate", "--dataset", "tiny", "--repeats", "1", "--batch-size", "16"],  # its default test set
        ["testset", "--dataset", "tiny", "--data", "data", "--n", "2", "--seed", "0", "--mirrors", "distinct"],
        ["generate", "a person walks forward and then jumps", "--dataset", "tiny", "--out", "made", "--formats", "npy"],
        ["export", "made/motion.npy", "--out", "made/motion.bvh"],
        ["render", "raw", "--id", "000000", "--out", "clip.gif"],
        ["train-vq", "--config", "vq.yaml"],
    ]
    for argv in commands:
        assert main(argv) == 0, f"m2d2m {' '.join(argv)}: {capsys.readouterr().err}"
    assert "reusing it" in capsys.readouterr().out  # the dataset was built from this project's raw/

    assert not trained_store.exists(), "the copy wrote into the original's place"
    made = set(moved.glob("runs/*/*/*/run.json")) - before
    assert len(made) == 6  # four trainings, the evaluation and a VQ-VAE
    for run_file in made:
        info = json.loads(run_file.read_text(encoding="utf-8"))
        paths = recorded_paths({key: value for key, value in info.items() if key != "config"})
        assert paths and not [path for path in paths if Path(path).is_absolute()], (run_file, paths)
    with sqlite3.connect(moved / "mlflow.db") as store:
        locations = store.execute("SELECT artifact_location FROM experiments UNION SELECT artifact_uri FROM runs")
        elsewhere = [place for (place,) in locations if str(moved / "mlruns") not in place]
    assert not elsewhere, elsewhere


def test_a_record_is_found_from_the_project_of_the_file_that_made_it(tmp_path, monkeypatch):
    """Relative to the recording file's project (a model file given from elsewhere finds its dataset);
    an absolute record (a file outside the project) as it stands, never guessed at when it is gone."""
    from m2d2m.layout import recorded_path

    monkeypatch.chdir(tmp_path)
    (tmp_path / "data" / "synthetic").mkdir(parents=True)
    (tmp_path / "other" / "data" / "kit").mkdir(parents=True)
    model = Path("runs/synthetic/m2d2m/run/model.pt")
    assert recorded_path("data/synthetic", model) == Path("data/synthetic")
    assert recorded_path("data/kit", tmp_path / "other/runs/kit/m2d2m/run/model.pt") == tmp_path / "other/data/kit"
    assert recorded_path("/gone/project/data/synthetic", model) == Path("/gone/project/data/synthetic")
    assert recorded_path("/datasets/humanml3d", model) == Path("/datasets/humanml3d")  # outside: as it stands


@pytest.mark.slow
def test_a_moved_project_sweeps_serves_and_trains_the_upper_body_editor(moved, trained_store, capsys):
    """The verbs the test above leaves out for time (about a minute more on 2 cores)."""
    from fastapi.testclient import TestClient

    from orchestration.web.app import ServeSettings, create_app

    testset = ["testset", "--dataset", "tiny", "--data", "data", "--n", "2", "--seed", "0", "--mirrors", "distinct"]
    sweep = sweep_config(
        Path("data/testsets/n2-seed0-distinct"), space={"eta": [0.25]}, max_concurrent=1, max_failures=0
    )
    (moved / "sweep.yaml").write_text(yaml.safe_dump(sweep), encoding="utf-8")
    (moved / "body.yaml").write_text(yaml.safe_dump(TINY_BODY), encoding="utf-8")
    parts = [["train-vq", "--config", str(config.relative_to(moved))] for config in write_part_tokenizer_configs(moved)]
    for argv in (testset, ["sweep", "--config", "sweep.yaml"], *parts, ["train-mmm-body", "--config", "body.yaml"]):
        assert main(argv) == 0, f"m2d2m {' '.join(argv)}: {capsys.readouterr().err}"
    with TestClient(create_app(ServeSettings(dataset="tiny", track=True))) as client:
        answer = client.post("/api/generate", json={"actions": [{"text": "a person jumps", "seconds": 1.2}]})
    assert answer.status_code == 200, answer.text
    assert not trained_store.exists(), "the copy wrote into the original's place"


@pytest.mark.parametrize(
    "argv",
    [
        ["generate", "a person walks"],
        ["evaluate"],
        ["tokenize"],
        ["testset"],
        ["train-vq"],
        ["train-diffusion"],
        ["train-evaluator", "--resume"],
        ["sweep"],
        ["ui"],
        ["serve"],
        ["data"],
    ],
    ids=lambda argv: argv[0],
)
def test_a_verb_run_outside_a_project_says_so_in_one_line(argv, tmp_path, monkeypatch, capsys):
    """Not "run `make train-diffusion` first": in a subfolder of a project, the project is named."""
    inside = tmp_path / "project" / "runs" / "synthetic"
    inside.mkdir(parents=True)
    for folder, where in ((tmp_path, "cd to your project"), (inside, f"run it in {tmp_path / 'project'}")):
        monkeypatch.chdir(folder)
        assert main(argv) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and f"{folder} is not an m2d2m project" in lines[0] and where in lines[0], lines
    assert sorted(p.name for p in tmp_path.iterdir()) == ["project"]  # nothing made outside


def make_plan(project: Path, owner: str | None) -> str:
    """What ``make setup`` would run in ``project`` with the stamp naming ``owner`` (None: an older
    Makefile's empty stamp)."""
    (project / ".venv" / ".installed").write_text("" if owner is None else owner + "\n", encoding="utf-8")
    os.utime(project / "pyproject.toml", (0, 0))  # the stamp is newer: only its owner can be wrong
    return subprocess.run(["make", "-n", "setup"], cwd=project, capture_output=True, text=True, check=True).stdout


@pytest.mark.skipif(shutil.which("make") is None, reason="needs GNU make")
def test_make_makes_a_venv_of_another_folder_again(tmp_path):
    project = tmp_path / "copy"
    (project / ".venv" / "bin").mkdir(parents=True)
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(REPOSITORY / name, project / name)
    assert "venv --clear" not in make_plan(project, str(project))
    assert "venv --clear" in make_plan(project, str(tmp_path / "original"))
    venv_python = project / ".venv" / "bin" / "python"
    for owner, remade in ((project, False), (tmp_path / "original", True)):
        venv_python.write_text(f"#!/bin/sh\necho {owner}\n", encoding="utf-8")  # where its m2d2m is
        venv_python.chmod(0o755)
        assert ("venv --clear" in make_plan(project, None)) == remade


def fake_python(path: Path, version: str, usable: bool = True) -> Path:
    """A stand-in for Python ``version`` (``3.12``) that the Makefile's probe finds usable or, like
    a Python outside 3.11-3.14, not (the probe exits 1; ``-V`` still says what it is)."""
    probe = f"echo {version}" if usable else "exit 1"
    path.write_text(f'#!/bin/sh\nif [ "$1" = -V ]; then echo Python {version}; else {probe}; fi\n', encoding="utf-8")
    path.chmod(0o755)
    return path


@pytest.mark.skipif(shutil.which("make") is None, reason="needs GNU make")
def test_make_takes_the_python_it_is_named_and_refuses_one_it_cannot_use(tmp_path):
    """README, "Python versions": ``make PYTHON=...`` makes .venv with that interpreter, again when
    .venv runs another version; a Python outside 3.11-3.14 is one line (then make's own) and exit 2,
    with nothing made."""
    project = tmp_path / "copy"
    (project / ".venv" / "bin").mkdir(parents=True)
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(REPOSITORY / name, project / name)
    (project / ".venv" / ".installed").write_text(f"{project}\n", encoding="utf-8")
    os.utime(project / "pyproject.toml", (0, 0))
    this = f"{sys.version_info.major}.{sys.version_info.minor}"
    other = "3.12" if this != "3.12" else "3.13"

    def plan(python: str) -> str:
        return subprocess.run(
            ["make", "-n", "setup", f"PYTHON={python}"], cwd=project, capture_output=True, text=True, check=True
        ).stdout

    fake_python(project / ".venv" / "bin" / "python", this)
    assert "venv --clear" not in plan(sys.executable)  # .venv already runs this version: kept
    fake_python(project / ".venv" / "bin" / "python", other)
    assert f"{sys.executable} -m venv --clear .venv" in plan(sys.executable)  # made again with the one named

    old = fake_python(tmp_path / "python3.10", "3.10.12", usable=False)
    refused = subprocess.run(["make", "setup", f"PYTHON={old}"], cwd=project, capture_output=True, text=True)
    message, *made = refused.stderr.strip().splitlines()
    assert refused.returncode == 2 and all(re.match(r"make(\[\d+\])?: \*\*\*", line) for line in made), refused.stderr
    assert f"PYTHON={old} is not a Python 3.11-3.14" in message and "Python 3.10.12" in message
    assert sorted(p.name for p in (project / ".venv").iterdir()) == [".installed", "bin"]  # nothing made
