"""bench/learning_curves.py: what it trains and judges, in which order, its report and figure, and
that its runs never become `latest` (the commands themselves are stood in for: each is a real
`m2d2m` verb tested elsewhere)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from orchestration.runs import mark_latest, new_run_dir, write_run_info

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # bench scripts import `stages` beside them
import stages  # noqa: E402

from bench import learning_curves  # noqa: E402
from bench.learning_curves import ABLATION, CURVES, PAPER, plot, report, schedule_overrides  # noqa: E402


def single_table(fid: float, r_top3: float) -> dict:
    row = {
        "fid": {"mean": fid, "ci": 0.1},
        "r_top3": {"mean": r_top3, "ci": 0.01},
        "mm_dist": {"mean": 2.0, "ci": 0.1},
        "mmodality": {"mean": 1.0, "ci": 0.1},
    }
    return {
        "generated": row,
        "gt_single": {**row, "fid": {"mean": None, "ci": None}, "r_top3": {"mean": 0.8, "ci": 0}},
        "reconstruction": {**row, "fid": {"mean": 0.07, "ci": 0}},
    }


@pytest.fixture
def fake_commands(tmp_path, monkeypatch) -> list[tuple[str, ...]]:
    """Every `m2d2m` verb the bench runs, recorded; trainings leave a finished run (with snapshots
    when asked for) that marks itself latest, evaluations a table whose FID is the call's number."""
    monkeypatch.chdir(tmp_path)
    calls: list[tuple[str, ...]] = []

    def fake(*argv: str) -> None:
        calls.append(argv)
        if argv[0].startswith("train-"):
            stage = "mmm" if argv[0] == "train-mmm" else "motiondiffuse" if "motiondiffuse" in argv[0] else "m2d2m"
            run_dir = new_run_dir("synthetic", stage)
            snapshots = next((a.split("=", 1)[1] for a in argv if a.startswith("trainer.snapshots=")), None)
            if snapshots:
                steps = json.loads(snapshots)
                (run_dir / "snapshots").mkdir()
                (run_dir / "snapshots" / "seconds.json").write_text(json.dumps({str(s): s / 10 for s in steps}))
            write_run_info(run_dir, status="finished")
            mark_latest(run_dir)
        elif argv[0] == "evaluate":
            run_dir = new_run_dir("synthetic", "eval")
            (run_dir / "table.json").write_text(json.dumps({"single": single_table(len(calls), 0.5)}))
            write_run_info(run_dir, status="finished")
            mark_latest(run_dir)

    monkeypatch.setattr(stages, "run", fake)
    return calls


def test_schedule_overrides_stretch_the_demo_schedule():
    assert schedule_overrides(8000, [500, 8000]) == [
        "--set",
        "trainer.max_steps=8000",
        "--set",
        "optim.milestones=[6000]",
        "--set",
        "trainer.val_every_steps=500",
        "--set",
        "trainer.snapshots=[500,8000]",
    ]
    assert schedule_overrides(40) == [
        "--set",
        "trainer.max_steps=40",
        "--set",
        "optim.milestones=[30]",
        "--set",
        "trainer.val_every_steps=40",
    ]


def test_a_curve_trains_once_and_judges_every_snapshot_without_moving_latest(fake_commands, tmp_path):
    before = new_run_dir("synthetic", "m2d2m")
    write_run_info(before, status="finished")
    mark_latest(before)
    progress = stages.Progress(tmp_path / "state.json", {"test": 1}, restart=False)
    points = []
    learning_curves.curve(progress, CURVES["m2d2m"], [500, 1000], 2, lambda key, point: points.append(point))
    trainings = [c for c in fake_commands if c[0] == "train-diffusion"]
    assert len(trainings) == 1 and "trainer.snapshots=[500,1000]" in trainings[0]
    judged = [c for c in fake_commands if c[0] == "evaluate"]
    assert [Path(c[c.index("--checkpoint") + 1]).name for c in judged] == ["model-step500.pt", "model-step1000.pt"]
    assert all({"--no-multi", "--single"} <= set(c) for c in judged)
    assert [(p["step"], p["seconds"]) for p in points] == [(500, 50.0), (1000, 100.0)]
    assert (tmp_path / "runs" / "synthetic" / "m2d2m" / "latest").read_text().strip() == before.name
    # run again: everything is finished, nothing runs
    count = len(fake_commands)
    learning_curves.curve(progress, CURVES["m2d2m"], [500, 1000], 2, lambda key, point: None)
    assert len(fake_commands) == count


def test_the_ablation_trains_each_change_once_and_samples_the_paper_model_for_sampling_rows(fake_commands, tmp_path):
    progress = stages.Progress(tmp_path / "state.json", {"test": 2}, restart=False)
    rows = {}
    learning_curves.ablation(progress, 2000, 1, lambda key, table: rows.__setitem__(key, table))
    assert set(rows) == {variant.key for variant in ABLATION}
    trainings = [c for c in fake_commands if c[0].startswith("train-")]
    assert len(trainings) == sum(variant.trained_as is None for variant in ABLATION)
    assert ("--set", "denoiser.positions=action") == tuple(trainings[2][3:5])  # the paper's config, one change
    sampling_only = [c for c in fake_commands if c[0] == "evaluate" and "truncation=0.86" in c]
    paper_run = json.loads((tmp_path / "state.json").read_text())["finished"][f"ablation/{PAPER}/train"]
    assert len(sampling_only) == 1 and sampling_only[0][sampling_only[0].index("--checkpoint") + 1] == str(
        Path(paper_run) / "model.pt"
    )


def test_report_and_figure_from_partial_results(tmp_path):
    results = {
        "curves": {
            "m2d2m": [
                {"step": 500, "seconds": 60.0, "table": single_table(20.0, 0.6)},
                {"step": 1000, "seconds": 120.0, "table": single_table(5.0, 0.7)},
            ],
            "mmm": [{"step": 500, "seconds": 50.0, "table": single_table(1.0, 0.8)}],
        },
        "ablation": {PAPER: single_table(24.0, 0.68), "aux-1": single_table(4.0, 0.78)},
    }
    text = report(results, {"repeats": 2, "ablation_steps": 2000})
    assert "| 1000 | 120 | 5.000 ± 0.100 | 0.700 ± 0.010 |" in text
    assert (
        "| + auxiliary weight λ = 1 (paper 5e-4) | 4.000 ± 0.100 | 0.780 ± 0.010 | 2.000 ± 0.100 | "
        "1.000 ± 0.100 | -20.000 | +0.100 |" in text
    )
    assert "VQ-VAE reconstruction (the token models' ceiling) | 0.070 ± 0.000" in text
    assert "+ importance sampling" not in text  # rows not measured yet are left out
    plot(tmp_path / "curves.png", results)
    assert (tmp_path / "curves.png").read_bytes()[:4] == b"\x89PNG"


def test_the_summary_run_holds_the_curves_by_step(tmp_path, monkeypatch):
    import mlflow

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.setattr(learning_curves, "OUT", tmp_path)
    results = {
        "curves": {"mmm": [{"step": s, "seconds": s / 10, "table": single_table(10.0 / s, 0.7)} for s in (500, 1000)]},
        "ablation": {PAPER: single_table(24.0, 0.68)},
    }
    (tmp_path / "report.md").write_text(report(results, {"repeats": 1, "ablation_steps": 2000}))
    plot(tmp_path / "curves.png", results)
    run_id = learning_curves.track(results, {"repeats": 1})
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    history = client.get_metric_history(run_id, "curve/mmm/fid")
    assert [(m.step, m.value) for m in history] == [(500, 0.02), (1000, 0.01)]
    assert client.get_run(run_id).data.metrics["ablation/paper/r_top3"] == pytest.approx(0.68)
    assert {a.path for a in client.list_artifacts(run_id)} == {"report.md", "curves.png"}
