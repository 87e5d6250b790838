"""MMM's upper-body editing end to end at toy size: both part tokenizers by `m2d2m train-vq`, the
editor by `m2d2m train-mmm-body`, an edit by `m2d2m generate --edit ... --keep-body lower`."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import yaml

from m2d2m.motion.representation.body_parts import LOWER, UPPER, part_dims
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.networks.vqvae import load_vq
from orchestration.cli import main
from orchestration.runs import latest_run, read_run_info
from tests.helpers import TINY_BODY, TINY_MMM, latest_evaluation, pose_clip, write_part_tokenizer_configs
from training.data.tokens import BodyTokenDataModule, TokenDataModule


@pytest.fixture(scope="module")
def body_project(trained_project):
    """The trained project with both part tokenizers and an editor trained on its corpus."""
    for config in write_part_tokenizer_configs(trained_project):
        assert main(["train-vq", "--config", str(config)]) == 0
    (trained_project / "body.yaml").write_text(yaml.safe_dump(TINY_BODY), encoding="utf-8")
    assert main(["train-mmm-body", "--config", str(trained_project / "body.yaml")]) == 0
    return trained_project


def test_part_tokenizers_have_their_own_runs(body_project):
    whole = latest_run("tiny", "vq", "make train-vq")
    for part in (UPPER, LOWER):
        run = latest_run("tiny", f"vq-{part}", "train-vq")
        model, _, meta = load_vq(run / "vq.pt")
        assert meta["part"] == part and run != whole
        assert model.decoder[-2].out_channels == len(part_dims(T2M, part))  # it writes its part's dimensions
    assert load_vq(whole / "vq.pt")[2]["part"] == "full"  # the whole-body tokenizer stays the vq stage's latest


def test_the_editor_reads_each_clip_s_two_token_sets_as_pairs(body_project, capsys):
    info = read_run_info(latest_run("tiny", "mmm-body", "make train-mmm-body"))
    paired = next(iter(BodyTokenDataModule(info["tokens"], info["lower_tokens"], num_workers=0).val_dataloader()))
    for column, tokens_dir in enumerate((info["tokens"], info["lower_tokens"])):
        alone = next(iter(TokenDataModule(tokens_dir, num_workers=0).val_dataloader()))
        assert torch.equal(paired["tokens"][..., column], alone["tokens"]) and paired["keys"] == alone["keys"]
    # a whole-body model refuses a part tokenizer, and the editor a whole-body one
    upper = latest_run("tiny", "vq-upper", "train-vq") / "vq.pt"
    (body_project / "mmm.yaml").write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    assert main(["train-mmm", "--config", str(body_project / "mmm.yaml"), "--set", f"vq={upper}"]) == 2
    assert "tokenizes the upper body, not the full body" in capsys.readouterr().err
    whole = latest_run("tiny", "vq", "make train-vq") / "vq.pt"
    assert main(["train-mmm-body", "--config", str(body_project / "body.yaml"), "--set", f"vq.lower={whole}"]) == 2
    assert "tokenizes the full body, not the lower body" in capsys.readouterr().err


def test_the_editor_trains_and_edits_through_the_command_line(body_project, tiny_testset, capsys):
    run_dir = latest_run("tiny", "mmm-body", "make train-mmm-body")
    info = read_run_info(run_dir)
    assert info["status"] == "finished" and (run_dir / "model.pt").exists()
    assert "lower_vq" in info and "lower_tokens" in info  # the run says which tokenizers it paired

    joints = pose_clip(T2M, 41, seed=3)  # joints: the command line makes the 40 frames of features
    np.save(body_project / "source.npy", joints)
    out = body_project / "edited"
    assert (
        main(
            [
                "generate",
                "a man waves his right hand",
                "--model",
                "mmm-body",
                "--dataset",
                "tiny",
                "--edit",
                str(body_project / "source.npy"),
                "--keep-body",
                "lower",
                "--option",
                "lower_mask=0.5",
                "--no-split",
                "--no-track",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert {p.name for p in out.iterdir()} >= {"motion.npy", "motion.features.npy", "motion.bvh", "motion.gif"}
    edited = np.load(out / "motion.features.npy")
    assert edited.shape == (40, 263)

    for argv, message in (
        (["--keep-body", "lower"], "--keep-body PART goes with --edit SOURCE"),
        (["--edit", str(body_project / "missing.npy"), "--keep-body", "lower"], "no such file"),
        (["--edit", str(body_project / "source.npy"), "--keep-body", "upper"], "lower body to keep on every frame"),
        (["--edit", str(body_project / "source.npy"), "--keep-body", "arms"], "unknown body part 'arms'"),
        ([], "lower body to keep on every frame"),  # the editor cannot make a motion from text alone
    ):
        capsys.readouterr()
        assert (
            main(
                [
                    "generate",
                    "a man claps",
                    "--model",
                    "mmm-body",
                    "--dataset",
                    "tiny",
                    "--no-track",
                    "--out",
                    str(body_project / "refused"),
                    *argv,
                ]
            )
            == 2
        )
        error = capsys.readouterr().err
        assert message in error and len(error.strip().splitlines()) == 1
    # the multi-motion table asks for motions from text alone, which an editor cannot make
    assert (
        main(["evaluate", "--model", "mmm-body", "--dataset", "tiny", "--testset", str(tiny_testset), "--repeats", "1"])
        == 2
    )
    assert "cannot generate from text alone" in capsys.readouterr().err


def test_the_editor_is_judged_in_the_editing_table_beside_a_text_to_motion_model(body_project, tiny_testset, capsys):
    for argv, message in (
        (
            ["--model", "mmm-body", "--edit", "upper", "--method", "mmm-body:independent"],
            "mmm-body edits motions and has no multi-action",
        ),
        (
            ["--model", "m2d2m", "--edit", "upper"],
            "no model given can do the editing task 'upper'; mmm-body, motiondiffuse can",
        ),
    ):
        assert main(["evaluate", "--dataset", "tiny", "--testset", str(tiny_testset), *argv]) == 2
        assert message in capsys.readouterr().err
    assert (
        main(
            [
                "evaluate",
                "--model",
                "m2d2m,mmm-body",
                "--dataset",
                "tiny",
                "--testset",
                str(tiny_testset),
                "--method",
                "tps",
                "--edit",
                "inbetween,upper",
                "--single",
                "--repeats",
                "1",
                "--batch-size",
                "8",
            ]
        )
        == 0
    )
    table = json.loads((latest_evaluation(body_project) / "table.json").read_text())
    assert set(table["multi"]) >= {"m2d2m/tps"} and not any(row.startswith("mmm-body") for row in table["multi"])
    assert "generated/mmm-body" not in table["single"]  # an editor has no single-motion row
    edits = {"m2d2m/inbetween/text", "m2d2m/inbetween/no_text", "mmm-body/upper/text", "mmm-body/upper/no_text"}
    assert edits <= set(table["editing"])
    assert all(np.isfinite(table["editing"][row]["fid"]["mean"]) for row in edits)
    candidates = {c["model"]: c for c in table["settings"]["candidates"]}
    assert candidates["mmm-body"]["methods"] == [] and candidates["mmm-body"]["edits"] == ["upper"]
    assert candidates["m2d2m"]["edits"] == ["inbetween"]
