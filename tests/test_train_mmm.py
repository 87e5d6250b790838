"""MMM end to end at toy size on the trained project's VQ tokens: `m2d2m train-mmm`, then
`m2d2m generate --model mmm` and `m2d2m evaluate --model mmm` through the registry, and MMM
judged beside M2D2M in one `m2d2m evaluate` run."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import numpy as np
import pytest
import yaml

from orchestration.cli import main
from orchestration.recipe import train
from orchestration.reports import FEET_TITLES
from orchestration.runs import latest_run, read_run_info
from tests.helpers import TINY_MMM, latest_evaluation


@pytest.fixture(scope="module")
def mmm_run(trained_project) -> Path:
    """A tiny MMM trained by `train-mmm`'s code on the trained project's tokens."""
    (trained_project / "mmm.yaml").write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    return train("mmm", str(trained_project / "mmm.yaml"))


def test_mmm_trains_generates_and_is_evaluated_through_the_registry(trained_project, tiny_testset, mmm_run):
    run_dir = mmm_run
    info = read_run_info(run_dir)
    assert info["status"] == "finished" and latest_run("tiny", "mmm", "make train-mmm") == run_dir
    assert (run_dir / "model.pt").exists() and any((run_dir / "previews").glob("*.gif"))
    mlflow.set_tracking_uri(f"sqlite:///{trained_project / 'mlflow.db'}")
    run = mlflow.get_run(info["mlflow_run_id"])
    assert {"train/loss", "val/loss", "val/masked_accuracy"} <= set(run.data.metrics)
    assert run.data.tags["stage"] == "mmm"

    out = trained_project / "mmm-clip"
    assert (
        main(
            [
                "generate",
                "a person walks forward",
                "a person jumps",
                "--model",
                "mmm",
                "--dataset",
                "tiny",
                "--seconds",
                "1.2",
                "1.2",
                "--no-split",
                "--no-track",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert {p.suffix for p in out.iterdir()} >= {".gif", ".bvh", ".npy"}

    assert (
        main(
            [
                "evaluate",
                "--model",
                "mmm",
                "--dataset",
                "tiny",
                "--testset",
                str(tiny_testset),
                "--method",
                "transition,independent",
                "--repeats",
                "1",
                "--batch-size",
                "4",
            ]
        )
        == 0
    )
    table = json.loads((latest_evaluation(trained_project) / "table.json").read_text())
    assert {"transition", "independent", "reconstruction"} <= set(table["multi"])
    assert table["multi"]["transition"]["jerk"]["mean"] is not None
    checkpoint = table["settings"]["candidates"][0]["checkpoint"]
    assert checkpoint == f"runs/tiny/mmm/{run_dir.name}/model.pt"  # relative to the project, which can move


def test_mmm_and_m2d2m_are_judged_in_one_table_and_one_mlflow_run(trained_project, tiny_testset, mmm_run):
    assert (
        main(
            [
                "evaluate",
                "--model",
                "m2d2m,mmm",
                "--dataset",
                "tiny",
                "--testset",
                str(tiny_testset),
                "--method",
                "tps,mmm:transition",
                "--method",
                "independent",
                "--ts",
                "4",
                "--option",
                "mmm.temperature=0.5",
                "--repeats",
                "1",
                "--single",
                "--edit",
                "inbetween",
                "--batch-size",
                "4",
            ]
        )
        == 0
    )
    run_dir = latest_evaluation(trained_project)
    table = json.loads((run_dir / "table.json").read_text())
    rows = ["m2d2m/tps", "m2d2m/independent", "mmm/transition", "mmm/independent"]
    feet = {f"{row}.{variant}" for row in rows for variant in FEET_TITLES}  # issue 40's rows
    assert set(table["multi"]) == {"gt_single", "gt_concat", "reconstruction", *rows, *feet}
    assert all(np.isfinite(table["multi"][row]["fid"]["mean"]) for row in rows)
    # both models decode through the one VQ-VAE: its reconstruction is measured once, for both
    assert table["codecs"] == {"m2d2m": "reconstruction", "mmm": "reconstruction"}
    assert set(table["single"]) == {"gt_single", "reconstruction", "generated/m2d2m", "generated/mmm"}
    edits = [f"{m}/inbetween/{t}" for m in ("m2d2m", "mmm") for t in ("text", "no_text")]
    assert set(table["editing"]) == {"gt_single", "reconstruction", *edits}
    assert all(np.isfinite(table["editing"][row]["r_top1"]["mean"]) for row in edits)
    options = {c["model"]: c["options"] for c in table["settings"]["candidates"]}
    assert options == {"m2d2m": {"ts": 4}, "mmm": {"temperature": 0.5}}  # --ts: the knob only M2D2M has
    markdown = (run_dir / "table.md").read_text()
    titles = [
        line.split(" | ")[0].strip("| ")
        for line in markdown.split("## Single")[0].splitlines()
        if line.startswith("| ") and "(n = 1)" in line  # one repeat: means without an interval
    ]
    methods = ["m2d2m tps", "m2d2m independent", "mmm transition", "mmm independent"]
    assert titles == [
        "Ground truth (single)",
        "Ground truth (concat)",
        "VQ-VAE reconstruction (m2d2m, mmm)",
        *methods,
        *(f"{method}{suffix}" for method in methods for suffix in FEET_TITLES.values()),
    ]
    assert {p.name for p in (run_dir / "results").iterdir()} >= {
        "multi-m2d2m-tps-r0.json",
        "multi-mmm-transition-r0.json",
        "single-mmm-r0.json",
        "edit-mmm-inbetween-no_text-r0.json",
    }
    assert "| mmm In-betweening (w/o text) |" in markdown

    client = mlflow.MlflowClient(f"sqlite:///{trained_project / 'mlflow.db'}")
    parent = client.get_run(read_run_info(run_dir)["mlflow_run_id"])
    assert parent.data.tags["model"] == "m2d2m,mmm" and parent.data.params["mmm.temperature"] == "0.5"
    assert "multi/mmm/transition/jerk" in parent.data.metrics and "single/m2d2m/fid" in parent.data.metrics
    children = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent.info.run_id}'")
    by_model = {run.info.run_name: run for run in children}
    assert set(by_model) == {"m2d2m", "mmm"}
    mmm = by_model["mmm"].data
    assert mmm.metrics["multi/transition/jerk"] == parent.data.metrics["multi/mmm/transition/jerk"]
    assert mmm.metrics["single/fid"] == parent.data.metrics["single/mmm/fid"]
    assert {"gt/jerk_concat", "multi/reconstruction/jerk", "edit/inbetween/no_text/fid"} <= set(mmm.metrics)
    assert "edit/m2d2m/inbetween/text/r_top1" in parent.data.metrics
    assert mmm.params["sampling"].startswith("10 iterations (cosine), temperature 0.5")

    assert main(["evaluate", "--dataset", "tiny", "--resume", run_dir.name]) == 0  # children reused, not doubled
    again = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent.info.run_id}'")
    assert len(again) == 2


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--checkpoint", "model.pt"], "with several models say whose, as MODEL=REF (models: m2d2m, mmm)"),
        (
            ["--method", "mmm:tps"],
            "unknown method 'tps' for mmm; choose from m2d2m: tps, independent, handshake, "
            "slerp; mmm: transition, independent",
        ),
        (["--option", "mmm.ts=3"], "mmm has no sampling option 'ts'"),
        (["--option", "nothing=3"], "m2d2m or mmm has no sampling option 'nothing'"),
    ],
)
def test_bad_multi_model_input_is_one_line_and_exit_2(trained_project, tiny_testset, capsys, arguments, message):
    code = main(
        [
            "evaluate",
            "--model",
            "m2d2m",
            "--model",
            "mmm",
            "--dataset",
            "tiny",
            "--testset",
            str(tiny_testset),
            *arguments,
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1, err


SWEEPS = Path(__file__).resolve().parents[1] / "configs" / "sweep"


def test_the_shipped_mmm_decoding_sweep_runs_through_ray_tune(trained_project, tiny_testset, mmm_run):
    """configs/sweep/mmm-decoding.yaml as shipped, on the tiny project: its knobs reach MMM's sampler."""
    from orchestration.sweep import SUMMARY_JSON, sweep

    config = yaml.safe_load((SWEEPS / "mmm-decoding.yaml").read_text())
    config.update(
        dataset="tiny", testset=str(tiny_testset), space={"schedule": ["cosine", "linear"], "iterations": [4]}
    )
    (trained_project / "mmm-decoding.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    summary = json.loads((sweep(str(trained_project / "mmm-decoding.yaml")) / SUMMARY_JSON).read_text())
    assert sorted((row["schedule"], row["iterations"]) for row in summary) == [("cosine", 4), ("linear", 4)]
    assert all(np.isfinite(row["multi/transition/fid"]) for row in summary)


def test_the_shipped_mmm_alpha_sweep_checks_its_space_against_the_training_config(monkeypatch):
    from orchestration.sweep import _check_training_space

    monkeypatch.chdir(SWEEPS.parents[1])  # where `make sweep` runs: configs/mmm/demo.yaml is found from here
    config = yaml.safe_load((SWEEPS / "mmm-alpha.yaml").read_text())
    _check_training_space(config)  # every α applies to configs/mmm/demo.yaml
    assert config["model"] == "mmm" and config["kind"] == "training" and list(config["space"]) == ["masking.alpha"]
