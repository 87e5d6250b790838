"""Every training verb, every generator and the evaluation under bf16 mixed precision, on the CPU.

A GPU trains with ``precision: auto`` = ``bf16-mixed``, where autocast hands some operations back
in bfloat16 while the rest of the code expects float32; the VQ-VAE's validation once crashed on
exactly that, on every GPU, while every test ran in float32 on the CPU. Lightning's
``bf16-mixed`` and ``torch.autocast("cpu", dtype=torch.bfloat16)`` take the same paths on a CPU,
so these tests catch that class of bug without a GPU: each verb trains its tiny config through
validation, previews, snapshots, EMA and its model file (saved in float32), and each generator
samples under autocast.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import yaml
from torch.utils._python_dispatch import TorchDispatchMode

from m2d2m.generators.edits import Timeline, layer_part
from m2d2m.generators.protocol import keep_part
from m2d2m.motion.representation.body_parts import part_mask
from m2d2m.motion.representation.features import joints_to_features
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from orchestration.generate import load_generator
from orchestration.runs import latest_run, read_run_info
from tests.helpers import (
    TINY_BODY,
    TINY_MMM,
    TINY_MOTIONDIFFUSE,
    latest_evaluation,
    pose_clip,
    write_part_tokenizer_configs,
)

BF16 = ["--set", "trainer.precision=bf16-mixed"]
# the trainer's extras that run code of their own at a step or validation: EMA and a snapshot
EXTRAS = ["--set", "trainer.ema=0.9", "--set", "trainer.snapshots=[1]"]
# two steps, one validation at the second: the shortest run that passes every stage of a training
SHORT = ["--set", "trainer.max_steps=2", "--set", "trainer.val_every_steps=2"]


def _floating_dtypes(payload) -> set[torch.dtype]:
    """The dtypes of every floating tensor in a model file's payload, however nested."""
    if torch.is_tensor(payload):
        return {payload.dtype} if payload.is_floating_point() else set()
    if isinstance(payload, dict):
        return set().union(*(_floating_dtypes(value) for value in payload.values()))
    if isinstance(payload, list | tuple):
        return set().union(*(_floating_dtypes(value) for value in payload))
    return set()


@pytest.fixture(scope="module")
def bf16_project(trained_project):
    """The trained project with every training verb run again in bf16-mixed; the stages they ran."""
    project = trained_project
    configs = {
        "mmm.yaml": TINY_MMM,
        "body.yaml": TINY_BODY,
        "motiondiffuse.yaml": {
            **TINY_MOTIONDIFFUSE,
            "data": {**TINY_MOTIONDIFFUSE["data"], "dir": str(project / "data")},
        },
    }
    for name, config in configs.items():
        (project / name).write_text(yaml.safe_dump(config), encoding="utf-8")
    upper, lower = write_part_tokenizer_configs(project)
    verbs = {
        "vq": ["train-vq", "--config", "vq.yaml"],
        "vq-upper": ["train-vq", "--config", str(upper)],
        "vq-lower": ["train-vq", "--config", str(lower)],
        "m2d2m": ["train-diffusion", "--config", "diffusion.yaml"],
        "mmm": ["train-mmm", "--config", "mmm.yaml"],
        "mmm-body": ["train-mmm-body", "--config", "body.yaml"],
        "motiondiffuse": ["train-motiondiffuse", "--config", "motiondiffuse.yaml"],
        "evaluator": ["train-evaluator", "--config", "evaluator.yaml"],
    }
    for stage, arguments in verbs.items():
        assert main([*arguments, *BF16, *SHORT, *EXTRAS]) == 0, stage
    return project, list(verbs)


def test_every_training_verb_trains_validates_and_saves_in_bf16(bf16_project):
    project, stages = bf16_project
    for stage in stages:
        run_dir = latest_run("tiny", stage, "train")
        info = read_run_info(run_dir)
        assert info["status"] == "finished" and info["config"]["trainer"]["precision"] == "bf16-mixed", stage
        assert info["final_validation"], f"{stage}: no validation metric recorded"
        model_file = next(run_dir.glob("*.pt"))
        assert _floating_dtypes(torch.load(model_file, map_location="cpu", weights_only=True)) <= {
            torch.float32,
            torch.float64,
        }, f"{stage}: {model_file.name} holds reduced-precision tensors"
        assert (run_dir / "snapshots" / "step-1.ckpt").exists(), f"{stage}: no snapshot at step 1"


class MatrixProducts(TorchDispatchMode):
    """The dtypes the matrix products of a block return: proof that autocast was on."""

    PRODUCTS = {"aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm", "aten::_efficient_attention_forward"}

    def __init__(self) -> None:
        super().__init__()
        self.dtypes: set[torch.dtype] = set()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        if func._schema.name in self.PRODUCTS and torch.is_tensor(out):
            self.dtypes.add(out.dtype)
        return out


def _sampled_in_bf16(call) -> list:
    """``call()``'s motions, checked to have been sampled with bf16 matrix products into finite
    float32 features."""
    with MatrixProducts() as products:
        motions = call()
    assert torch.bfloat16 in products.dtypes, products.dtypes
    for motion in motions:
        assert motion.features.dtype == np.float32 and np.isfinite(motion.features).all()
    return motions


def test_every_generator_samples_under_bf16_autocast(bf16_project):
    project, _ = bf16_project
    for name in ("m2d2m", "mmm", "motiondiffuse"):
        generator = load_generator(name, "latest", "tiny", device="cpu").use_precision("bf16")
        assert generator.precision == "bf16"
        options = generator.options()
        actions, frames = [["a person walks forward", "a person jumps"]], [[40, 32]]
        (motion,) = _sampled_in_bf16(lambda: generator.generate(actions, frames, options, [0]))
        assert len(motion.features) == sum(generator.round_frames(n) for n in frames[0])
    motiondiffuse = load_generator("motiondiffuse", "latest", "tiny", device="cpu").use_precision("bf16")
    parts = [{"upper": "a person waves", "lower": "a person walks forward"}]
    _sampled_in_bf16(lambda: motiondiffuse.generate_parts(parts, [40], motiondiffuse.options(), [0]))
    editor = load_generator("mmm-body", "latest", "tiny", device="cpu").use_precision("bf16")
    source = joints_to_features(pose_clip(T2M, 41, seed=3), T2M)
    keep = keep_part(source, T2M, "lower")
    _sampled_in_bf16(lambda: editor.generate([["a person claps"]], [[40]], editor.options(), [0], [keep]))
    # an edit's keep frame by frame (a body part over a span: m2d2m.generators.edits.layer_part)
    layered = layer_part(Timeline(source[:40], ["a person walks"], [0]), (8, 32), part_mask(T2M, "upper"), "waves", 4)
    (edited,) = _sampled_in_bf16(
        lambda: motiondiffuse.generate(
            [layered.actions], [layered.frames], motiondiffuse.options(), [0], [layered.keep]
        )
    )
    lower = ~part_mask(T2M, "upper")
    assert np.abs(edited.features[:, lower] - source[:40, lower]).max() < 1e-3  # the rest of the body replaced
    # a token model's reconstruction row: encoded and decoded by the codec, in float32
    m2d2m = load_generator("m2d2m", "latest", "tiny", device="cpu").use_precision("bf16")
    (reconstruction,) = m2d2m.reconstruct([[source[:32], source[8:40]]])
    assert reconstruction.features.dtype == np.float32


def test_precision_follows_the_environment_and_refuses_a_bad_value(bf16_project, monkeypatch, capsys):
    monkeypatch.setenv("M2D2M_PRECISION", "bf16")
    assert load_generator("m2d2m", "latest", "tiny", device="cpu").precision == "bf16"
    monkeypatch.delenv("M2D2M_PRECISION")
    assert load_generator("m2d2m", "latest", "tiny", device="cpu").precision == "fp32"  # auto, on a CPU
    monkeypatch.setenv("M2D2M_PRECISION", "half")
    assert main(["generate", "a person walks", "--dataset", "tiny", "--no-track", "--out", "refused"]) == 2
    error = capsys.readouterr().err
    assert "M2D2M_PRECISION" in error and len(error.strip().splitlines()) == 1


def test_an_evaluation_of_bf16_samples_measures_in_float32(bf16_project, tiny_testset, monkeypatch):
    arguments = ["evaluate", "--dataset", "tiny", "--testset", str(tiny_testset), "--repeats", "1"]
    tables = {}
    for precision in ("bf16", "fp32"):
        monkeypatch.setenv("M2D2M_PRECISION", precision)
        assert main([*arguments, "--model", "m2d2m,mmm", "--method", "tps,mmm:transition", "--regenerate", "2"]) == 0
        tables[precision] = json.loads((latest_evaluation(bf16_project[0]) / "table.json").read_text())
    for row, metrics in {**tables["bf16"]["multi"], **tables["bf16"]["regenerate"]}.items():
        assert all(np.isfinite(summary["mean"]) for summary in metrics.values()), row
    # the evaluator measures in float32 whatever the samples were made in: the ground truth scores alike
    assert tables["bf16"]["multi"]["gt_concat"] == tables["fp32"]["multi"]["gt_concat"]
