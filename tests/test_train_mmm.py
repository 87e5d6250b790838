"""MMM end to end at toy size on the trained project's VQ tokens: `m2d2m train-mmm`, then
`m2d2m generate --model mmm` and `m2d2m evaluate --model mmm` through the registry."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import yaml

from orchestration.cli import main
from orchestration.runs import latest_run, read_run_info
from orchestration.train import train_model
from tests.helpers import TINY_MMM



def test_mmm_trains_generates_and_is_evaluated_through_the_registry(trained_project, tiny_testset):
    (trained_project / "mmm.yaml").write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    run_dir = train_model("mmm", str(trained_project / "mmm.yaml"))
    info = read_run_info(run_dir)
    assert info["status"] == "finished" and latest_run("tiny", "mmm", "make train-mmm") == run_dir
    assert (run_dir / "model.pt").exists() and any((run_dir / "previews").glob("*.gif"))
    mlflow.set_tracking_uri(f"sqlite:///{trained_project / 'mlflow.db'}")
    run = mlflow.get_run(info["mlflow_run_id"])
    assert {"train/loss", "val/loss", "val/masked_accuracy"} <= set(run.data.metrics)
    assert run.data.tags["stage"] == "mmm"

    out = trained_project / "mmm-clip"
    assert main(["generate", "a person walks forward", "a person jumps", "--model", "mmm", "--dataset", "tiny",
                 "--seconds", "1.2", "1.2", "--no-split", "--no-track", "--out", str(out)]) == 0
    assert {p.suffix for p in out.iterdir()} >= {".gif", ".bvh", ".npy"}

    assert main(["evaluate", "--model", "mmm", "--dataset", "tiny", "--testset", str(tiny_testset),
                 "--method", "transition,independent", "--repeats", "1", "--batch-size", "4"]) == 0
    stage = trained_project / "runs" / "tiny" / "eval"
    table = json.loads((stage / (stage / "latest").read_text().strip() / "table.json").read_text())
    assert {"transition", "independent", "reconstruction"} <= set(table["multi"])
    assert table["multi"]["transition"]["jerk"]["mean"] is not None
    assert Path(table["settings"]["checkpoint"]) == (run_dir / "model.pt").resolve()
