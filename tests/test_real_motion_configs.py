"""The real-motion configs (configs/*/bandai-namco.yaml, `make demo-real`) are the demo's: the same
sizes, steps and semantics on another corpus, so that a table on real motion compares with the
embedded default's (docs/reproduction.md, "On real motion")."""

from __future__ import annotations

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
