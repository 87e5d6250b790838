"""The real-motion configs (configs/*/bandai-namco.yaml, `make demo-real`) are the demo's: the same
sizes, steps and semantics on another corpus, so that a table on real motion compares with the
embedded default's (docs/reproduction.md, "On real motion")."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from orchestration.config import flatten, load_config

STAGES = ("vq", "m2d2m", "mmm", "motiondiffuse", "evaluator")
# what a real-motion config may change: its corpus, what its previews ask for, and the VQ-VAE's
# window (most of the corpus's raise-up takes are shorter than the demo's 64 frames)
DIFFERENT = {"dataset", "data.dir", "preview.prompts", "data.window"}
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("stage", STAGES)
def test_a_real_motion_config_is_the_demos_on_the_bandai_namco_corpus(stage, monkeypatch):
    monkeypatch.chdir(ROOT)
    real = flatten(load_config(stage, "bandai-namco"))
    demo = flatten(load_config(stage, "demo"))
    assert real.keys() == demo.keys()
    changed = {key for key in real if real[key] != demo[key]}
    assert changed <= DIFFERENT
    assert real["dataset"] == "bandai-namco"
    assert real.get("data.dir", "data/bandai-namco") == "data/bandai-namco"


def test_the_makefile_trains_every_stage_from_its_real_motion_config():
    recipe = (ROOT / "Makefile").read_text(encoding="utf-8").split("\ndemo-real:", 1)[1].split("\n\n", 1)[0]
    for verb in ("train-vq", "train-diffusion", "train-mmm", "train-motiondiffuse", "train-evaluator"):
        assert f"$(M2D2M) {verb} --config bandai-namco" in recipe
    assert "--dataset bandai-namco --raw $(REAL_RAW)" in recipe
    assert yaml.safe_load((ROOT / "configs/vq/bandai-namco.yaml").read_text(encoding="utf-8"))["data"]["window"] == 32


@pytest.fixture
def makefile_project(tmp_path: Path) -> Path:
    """The Makefile in a folder whose .venv is made and up to date, so that a verb runs its recipe."""
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / ".installed").write_text(f"{tmp_path}\n", encoding="utf-8")
    os.utime(tmp_path / "pyproject.toml", (0, 0))
    return tmp_path


@pytest.mark.skipif(shutil.which("make") is None, reason="needs GNU make")
def test_make_demo_on_the_bandai_namco_corpus_is_demo_real_and_on_another_one_line(makefile_project):
    """`make demo DATASET=bandai-namco RAW=<clone>` (the issue's words) runs demo-real on that clone;
    another DATASET is refused in one line instead of running the synthetic flow unasked."""
    plan = subprocess.run(
        ["make", "-n", "demo", "DATASET=bandai-namco", "RAW=../clone"],
        cwd=makefile_project,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "m2d2m data --dataset bandai-namco --raw ../clone" in plan and "synthesize" not in plan
    refused = subprocess.run(["make", "demo", "DATASET=kit"], cwd=makefile_project, capture_output=True, text=True)
    assert refused.returncode == 2
    assert refused.stderr.splitlines()[0].startswith(
        "make demo: the flow of the embedded corpus or, with DATASET=bandai"
    )
