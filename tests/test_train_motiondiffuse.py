"""MotionDiffuse end to end at toy size on the trained project's features: `m2d2m train-motiondiffuse`
through the registry (MLflow loss per step bucket, previews, the model file), `m2d2m generate` for a
multi-action and a body-part request, and the three models — M2D2M, MMM, MotionDiffuse — judged in one
`m2d2m evaluate` run, what `make compare` runs on the embedded default."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import numpy as np
import pytest
import yaml

from m2d2m.motion.representation.body_parts import part_mask
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from orchestration.recipe import train
from orchestration.reports import FEET_TITLES
from orchestration.runs import latest_run, read_run_info
from tests.helpers import TINY_MMM, TINY_MOTIONDIFFUSE, latest_evaluation


@pytest.fixture(scope="module")
def motiondiffuse_run(trained_project) -> Path:
    config = {**TINY_MOTIONDIFFUSE, "data": {**TINY_MOTIONDIFFUSE["data"], "dir": str(trained_project / "data")}}
    (trained_project / "motiondiffuse.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    return train("motiondiffuse", str(trained_project / "motiondiffuse.yaml"))


def test_motiondiffuse_trains_through_the_registry_and_tracks_the_loss_per_step_bucket(
    trained_project, motiondiffuse_run
):
    info = read_run_info(motiondiffuse_run)
    assert info["status"] == "finished"
    assert latest_run("tiny", "motiondiffuse", "make train-motiondiffuse") == motiondiffuse_run
    assert (motiondiffuse_run / "model.pt").exists() and any((motiondiffuse_run / "previews").glob("*.gif"))
    mlflow.set_tracking_uri(f"sqlite:///{trained_project / 'mlflow.db'}")
    run = mlflow.get_run(info["mlflow_run_id"])
    assert {"train/loss", "val/loss"} <= set(run.data.metrics)
    assert any(name.startswith("val/loss_t") for name in run.data.metrics)
    assert run.data.params["diffusion.steps"] == "50" and run.data.tags["stage"] == "motiondiffuse"


def test_generate_writes_a_multi_action_and_a_body_part_request(trained_project, motiondiffuse_run):
    out = trained_project / "md-multi"
    assert (
        main(
            [
                "generate",
                "a person walks forward",
                "a person jumps",
                "--model",
                "motiondiffuse",
                "--dataset",
                "tiny",
                "--seconds",
                "1.5",
                "1.5",
                "--no-split",
                "--no-track",
                "--out",
                str(out),
                "--option",
                "steps=10",
            ]
        )
        == 0
    )
    assert {p.suffix for p in out.iterdir()} >= {".gif", ".bvh", ".npy"}
    parts = trained_project / "md-parts"
    assert (
        main(
            [
                "generate",
                "a person walks forward",
                "--part",
                "upper=a person waves their right hand",
                "--model",
                "motiondiffuse",
                "--dataset",
                "tiny",
                "--seconds",
                "2",
                "--no-track",
                "--out",
                str(parts),
                "--option",
                "steps=10",
            ]
        )
        == 0
    )
    sidecar = json.loads((parts / "motion.json").read_text())
    assert [segment["text"] for segment in sidecar["segments"]] == [
        "upper: a person waves their right hand | lower: a person walks forward"
    ]
    assert sidecar["num_frames"] == 40  # 2 s at 20 fps
    assert {p.suffix for p in parts.iterdir()} >= {".gif", ".bvh", ".npy"}


def test_an_upper_body_action_is_laid_over_a_span_of_the_multi_action_result(trained_project, motiondiffuse_run):
    """Issue 41's body-part track: "waves" over 1–2.5 s of the walk-then-jump result; the lower
    body's features are the source's on every frame, the upper body's outside the span and its
    0.4-s margins; m2d2m, which keeps whole frames, refuses the layer in one line."""
    source = trained_project / "md-multi" / "motion.npy"
    out = trained_project / "md-layer"
    argv = ["generate", "--edit", str(source), "--layer", "upper=a person waves", "--span", "1:2.5"]
    quick = ["--dataset", "tiny", "--no-track", "--formats", "npy", "--option", "steps=10"]
    assert main([*argv, "--model", "motiondiffuse", *quick, "--out", str(out)]) == 0
    before, after = (np.load(folder / "motion.features.npy") for folder in (source.parent, out))
    upper = part_mask(T2M, "upper")
    np.testing.assert_array_equal(after[:, ~upper], before[:, ~upper])
    np.testing.assert_array_equal(after[:12], before[:12])  # 1 s - 0.4 s at 20 fps
    np.testing.assert_array_equal(after[58:], before[58:])  # 2.5 s + 0.4 s
    assert not np.array_equal(after[20:50], before[20:50])
    texts = [s["text"] for s in json.loads((out / "motion.json").read_text())["segments"]]
    assert texts == ["a person walks forward", "a person waves", "a person jumps"]
    assert main([*argv, "--model", "m2d2m", *quick[:-2], "--out", str(out.with_name("m2d2m-layer"))]) == 2


@pytest.mark.parametrize(
    "arguments, message",
    [
        (
            ["a person runs", "--part", "upper=a person waves"],
            "m2d2m has no body-part control; use --model motiondiffuse",
        ),
        (["--part", "upper=a person waves"], "give a prompt for the parts not named (lower)"),
        (["a person runs", "--part", "arms=a person waves"], "unknown body part 'arms'"),
    ],
)
def test_bad_body_part_requests_are_one_line_and_exit_2(trained_project, motiondiffuse_run, capsys, arguments, message):
    code = main(["generate", *arguments, "--dataset", "tiny", "--no-track", "--out", str(trained_project / "x")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1, err


def test_the_three_models_are_judged_in_one_evaluate_run(trained_project, tiny_testset, motiondiffuse_run):
    (trained_project / "mmm.yaml").write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    train("mmm", str(trained_project / "mmm.yaml"))
    assert (
        main(
            [
                "evaluate",
                "--model",
                "m2d2m,mmm,motiondiffuse",
                "--dataset",
                "tiny",
                "--testset",
                str(tiny_testset),
                "--method",
                "m2d2m:tps,m2d2m:independent,mmm:transition,motiondiffuse:time-varied",
                "--ts",
                "4",
                "--repeats",
                "1",
                "--single",
                "--edit",
                "upper",
                "--regenerate",
                "2",
                "--batch-size",
                "4",
            ]
        )
        == 0
    )
    run_dir = latest_evaluation(trained_project)
    table = json.loads((run_dir / "table.json").read_text())
    rows = ["m2d2m/tps", "m2d2m/independent", "mmm/transition", "motiondiffuse/time-varied"]
    feet = {f"{row}.{variant}" for row in rows for variant in FEET_TITLES}  # issue 40's rows
    assert set(table["multi"]) == {"gt_single", "gt_concat", "reconstruction", *rows, *feet}
    assert all(np.isfinite(table["multi"][row]["fid"]["mean"]) for row in rows)
    assert table["multi"]["motiondiffuse/time-varied"]["jerk"]["mean"] is not None
    # MotionDiffuse has no codec: the one reconstruction row is the shared VQ-VAE's
    assert table["codecs"] == {"m2d2m": "reconstruction", "mmm": "reconstruction"}
    assert set(table["single"]) >= {"generated/m2d2m", "generated/mmm", "generated/motiondiffuse"}
    assert {"motiondiffuse/upper/text", "motiondiffuse/upper/no_text"} <= set(table["editing"])
    # issue 41's table: the second action sampled again by an edit, against the whole sequence again
    regenerated = {
        f"{name}/regenerate2/{version}" for name in ("m2d2m", "mmm", "motiondiffuse") for version in ("edit", "whole")
    }
    assert set(table["regenerate"]) == regenerated
    assert all(
        np.isfinite(table["regenerate"][row][metric]["mean"])
        for row in regenerated
        for metric in ("r_top3", "fid", "transition_fid", "jerk")
    )
    assert "## Editing on the timeline: action 2 of 2 sampled again" in (run_dir / "table.md").read_text()
    client = mlflow.MlflowClient(f"sqlite:///{trained_project / 'mlflow.db'}")
    parent = client.get_run(read_run_info(run_dir)["mlflow_run_id"])
    assert "regenerate/mmm/regenerate2/edit/fid" in parent.data.metrics
    children = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent.info.run_id}'")
    assert {run.info.run_name for run in children} == {"m2d2m", "mmm", "motiondiffuse"}
    assert (run_dir / "fig5.png").exists()


SWEEPS = Path(__file__).resolve().parents[1] / "configs" / "sweep"


def test_the_shipped_sampling_sweep_runs_through_ray_tune(trained_project, tiny_testset, motiondiffuse_run):
    """configs/sweep/motiondiffuse-sampling.yaml as shipped, on the tiny project: its knobs reach the sampler."""
    from orchestration.sweep import SUMMARY_JSON, sweep

    config = yaml.safe_load((SWEEPS / "motiondiffuse-sampling.yaml").read_text())
    config.update(dataset="tiny", testset=str(tiny_testset), space={"sampler": ["ddpm", "ddim"], "steps": [5]})
    (trained_project / "md-sampling.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    summary = json.loads((sweep(str(trained_project / "md-sampling.yaml")) / SUMMARY_JSON).read_text())
    assert sorted((row["sampler"], row["steps"]) for row in summary) == [("ddim", 5), ("ddpm", 5)]
    assert all(np.isfinite(row["multi/time-varied/fid"]) for row in summary)
