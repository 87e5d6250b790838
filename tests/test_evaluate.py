"""`m2d2m testset` and `m2d2m evaluate` end to end on a tiny trained VQ-VAE, denoiser and evaluator:
the tables, Fig. 5, MLflow, resuming without recomputing, and one-line errors with exit status 2."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import mlflow
import numpy as np
import pytest

import tests.test_testset as handmade
from m2d2m.generators.m2d2m.generator import M2D2MGenerator
from orchestration.cli import main
from orchestration.reports import FEET_TITLES, MULTI_COLUMNS, SINGLE_COLUMNS, table_metrics
from pipelines.testset import build_testset
from tests.helpers import latest_evaluation, one_line_error

METHODS = ("tps", "slerp")


@pytest.fixture(scope="module")
def evaluated(trained_project, tiny_testset) -> Path:
    """The run directory of `m2d2m evaluate` with two methods, two repeats and the single table."""
    arguments = [
        "evaluate",
        "--dataset",
        "tiny",
        "--testset",
        str(tiny_testset),
        "--method",
        "tps",
        "--method",
        "slerp",
        "--repeats",
        "2",
        "--ts",
        "4",
        "--single",
        "--batch-size",
        "4",
    ]
    assert main(arguments) == 0
    return latest_evaluation(trained_project)


def mlflow_client(trained_project: Path) -> mlflow.MlflowClient:
    return mlflow.MlflowClient(tracking_uri=f"sqlite:///{trained_project / 'mlflow.db'}")


def test_the_testset_command_builds_and_logs_the_counts(trained_project, capsys):
    code = main(
        [
            "testset",
            "--dataset",
            "tiny",
            "--data",
            str(trained_project / "data"),
            "--n",
            "2",
            "--seed",
            "1",
            "--mirrors",
            "distinct",
        ]
    )
    printed = capsys.readouterr().out
    assert code == 0 and "8 instances of 2 actions" in printed
    run = mlflow_client(trained_project).get_run(printed.split("logged to MLflow run ")[1].split()[0])
    assert run.data.metrics == {"pool_captions": 16.0, "pool_motions": 16.0, "instances": 8.0}
    assert run.data.params["n"] == "2" and run.data.params["mirrors"] == "distinct" and run.data.params["seed"] == "1"
    assert run.data.tags["stage"] == "testset"
    files = {Path(a.path).name for a in mlflow_client(trained_project).list_artifacts(run.info.run_id, "testset")}
    assert files == {"manifest.json", "instances.jsonl", "motions.npz"}


def test_every_multi_row_has_its_feet_rows_and_the_skating_column(evaluated):
    """Issue 40 §3: GMD's skating ratio on the ground truth, each method's raw output, the same
    with its feet planted."""
    table = json.loads((evaluated / "table.json").read_text(encoding="utf-8"))
    for row in ("gt_single", "gt_concat", *METHODS, *(f"{m}.{v}" for m in METHODS for v in FEET_TITLES)):
        assert 0.0 <= table["multi"][row]["skating"]["mean"] <= 1.0, row
    for method in METHODS:
        assert table["multi"][f"{method}.planted"]["skating"]["mean"] <= table["multi"][method]["skating"]["mean"]
        assert np.isfinite(table["multi"][f"{method}.planted"]["fid"]["mean"])
        assert table["titles"][f"{method}.planted"].endswith(", feet planted")
    assert "| Skating ↓ |" in (evaluated / "table.md").read_text(encoding="utf-8")


def test_evaluate_writes_both_tables_and_fig5(evaluated):
    table = json.loads((evaluated / "table.json").read_text(encoding="utf-8"))
    assert table["testset"]["instances"] == 8 and table["testset"]["items"] == 16
    assert table["r_precision_batch"] == 16 and any("groups of 16" in note for note in table["notes"])
    for method in METHODS:
        for metric, _ in MULTI_COLUMNS:
            summary = table["multi"][method][metric]
            assert np.isfinite(summary["mean"]) and summary["ci"] >= 0, (method, metric)
    assert table["multi"]["tps"]["jerk"] != table["multi"]["slerp"]["jerk"]  # each method really ran
    assert set(table["multi"]["gt_single"]) >= {"r_top3", "mm_dist", "diversity", "transition_diversity", "jerk"}
    for metric in ("jerk", "peak_jerk", "auj"):  # deterministic: no repeat changes them
        assert (
            np.isfinite(table["multi"]["gt_concat"][metric]["mean"]) and table["multi"]["gt_concat"][metric]["ci"] == 0
        )
    assert any(note.startswith("PJ, AUJ: FlowMDM's") and "c = " in note for note in table["notes"])
    for metric, _ in MULTI_COLUMNS:  # the codec's ceiling, measured like a method
        summary = table["multi"]["reconstruction"][metric]
        assert np.isfinite(summary["mean"]) and summary["ci"] >= 0, metric
    assert all(np.isfinite(table["single"]["reconstruction"][m]["mean"]) for m, _ in SINGLE_COLUMNS if m != "mmodality")
    for row in ("gt_single", "generated"):
        columns = [m for m, _ in SINGLE_COLUMNS if row == "generated" or m not in ("fid", "mmodality")]
        assert all(np.isfinite(table["single"][row][metric]["mean"]) for metric in columns), row
    markdown = (evaluated / "table.md").read_text(encoding="utf-8")
    assert "Ground truth (concat)" in markdown and "| tps |" in markdown and "Single-motion" in markdown
    assert markdown.count("| VQ-VAE reconstruction |") == 2
    assert (evaluated / "fig5.png").read_bytes()[:4] == b"\x89PNG"
    assert len(list((evaluated / "results").glob("multi-*.json"))) == 4
    assert len(list((evaluated / "results").glob("single-*.json"))) == 2


def test_evaluate_logs_every_metric_and_knob_to_mlflow(trained_project, evaluated):
    client = mlflow_client(trained_project)
    run = client.get_run(json.loads((evaluated / "run.json").read_text())["mlflow_run_id"])
    metrics, params = run.data.metrics, run.data.params
    for method in METHODS:
        for metric, _ in MULTI_COLUMNS:
            assert f"multi/{method}/{metric}" in metrics and f"multi/{method}/{metric}_ci" in metrics
    for name in (
        "gt/jerk_single",
        "gt/jerk_concat",
        "gt/r_top3_single",
        "single/r_top1",
        "single/fid",
        "single/mmodality_ci",
        "multi/reconstruction/jerk",
        "single/reconstruction/fid",
    ):
        assert name in metrics, name
    assert params["methods"] == "tps,slerp" and params["repeats"] == "2" and params["ts"] == "4"
    assert params["sampling"] == "T_s = 4 of T = 8, η = 0.25, s = 2" and params["model"] == "m2d2m"
    assert params["single_sampling"] == "η = 0.5, s = 4" and params["testset"].endswith("n2-seed0-distinct")
    assert params["evaluator"].endswith("evaluator.pt") and params["checkpoint"].endswith("model.pt")
    assert run.data.tags["stage"] == "eval" and run.data.tags["methods"] == "tps,slerp"
    assert run.info.status == "FINISHED"
    assert {"table.md", "table.json", "fig5.png"} <= {a.path for a in client.list_artifacts(run.info.run_id)}


def test_resume_recomputes_only_missing_results(trained_project, evaluated, monkeypatch):
    calls = []
    original = M2D2MGenerator.generate

    def counting(self, actions, *args, **kwargs):
        calls.append(len(actions))
        return original(self, actions, *args, **kwargs)

    monkeypatch.setattr(M2D2MGenerator, "generate", counting)
    results = sorted((evaluated / "results").glob("*.json"))
    before = {path: path.stat().st_mtime_ns for path in results}
    assert main(["evaluate", "--dataset", "tiny", "--resume", evaluated.name]) == 0
    assert calls == [] and {path: path.stat().st_mtime_ns for path in results} == before

    missing = evaluated / "results" / "multi-slerp-r1.json"
    kept = json.loads(missing.read_text(encoding="utf-8"))
    missing.unlink()
    assert main(["evaluate", "--dataset", "tiny", "--resume", evaluated.name]) == 0
    assert calls == [8]  # the 8 instances of one (method, repeat), in one batch of the default 32
    again = json.loads(missing.read_text(encoding="utf-8"))
    assert again["metrics"] == pytest.approx(kept["metrics"], rel=1e-4)  # same seeds, same tokens (float32 batches)


def test_a_job_stopped_midway_resumes_from_its_last_finished_batch(trained_project, evaluated, monkeypatch):
    calls = []
    original = M2D2MGenerator.generate

    def stopped_at_the_third_batch(self, actions, *args, **kwargs):
        calls.append(len(actions))
        if len(calls) == 3:
            raise KeyboardInterrupt("killed")
        return original(self, actions, *args, **kwargs)

    missing = evaluated / "results" / "multi-slerp-r1.json"
    kept = json.loads(missing.read_text(encoding="utf-8"))
    missing.unlink()
    monkeypatch.setattr(M2D2MGenerator, "generate", stopped_at_the_third_batch)
    resume = ["evaluate", "--dataset", "tiny", "--resume", evaluated.name, "--batch-size", "3"]
    assert main(resume) == 130 and calls == [3, 3, 2]
    folder = evaluated / "batches" / "multi-slerp-r1"
    assert sorted(path.name for path in folder.iterdir()) == ["multi-0-3.npz", "multi-3-3.npz"]
    calls.clear()
    assert main(resume) == 0
    assert calls == [2]  # the two finished batches were read back, only the third generated
    again = json.loads(missing.read_text(encoding="utf-8"))
    assert again["metrics"] == pytest.approx(kept["metrics"], rel=1e-4)
    assert not folder.exists()


def test_single_motion_alone_with_fewer_steps_and_the_no_multi_switch(trained_project, tiny_testset):
    """--no-multi --single: the single-motion table alone (a learning curve's points), sampled with
    the steps option; the multi table keeps only its reference rows."""
    arguments = [
        "evaluate",
        "--dataset",
        "tiny",
        "--testset",
        str(tiny_testset),
        "--no-multi",
        "--single",
        "--repeats",
        "1",
        "--option",
        "steps=3",
        "--batch-size",
        "8",
    ]
    assert main(arguments) == 0
    run_dir = latest_evaluation(trained_project)
    table = json.loads((run_dir / "table.json").read_text(encoding="utf-8"))
    assert set(table["multi"]) == {"gt_single", "gt_concat", "reconstruction"}
    assert np.isfinite(table["single"]["generated"]["fid"]["mean"]) and table["settings"]["multi"] is False
    assert [p.name for p in (run_dir / "results").iterdir()] == ["single-r0.json"]
    assert "3 of 8 steps" in " ".join(table["notes"])
    # one repeat has no interval: no "± 0.000" (which read as certainty), no _ci metric in MLflow
    assert table["single"]["generated"]["fid"]["ci"] is None
    markdown = (run_dir / "table.md").read_text(encoding="utf-8")
    assert "(n = 1)" in markdown and "±" not in markdown
    assert "single/fid" in table_metrics(table) and "single/fid_ci" not in table_metrics(table)


@pytest.fixture(scope="module")
def other_dim_testset(tmp_path_factory) -> Path:
    """A test set of 251-d features (a KIT-ML-shaped dataset), for the dimension check."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(handmade, "DIM", 251)
        data = handmade.write_dataset(tmp_path_factory.mktemp("kit-shaped"))
    return Path(build_testset(data, n=2)["path"])


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--method", "tps,blend"], "unknown method 'blend' for m2d2m; choose from tps, independent, handshake, slerp"),
        (["--repeats", "0"], "--repeats must be at least 1"),
        (["--testset", "nowhere"], "no test set there; build one with `m2d2m testset`"),
        (["--testset", "{other}"], "holds 251-d features but the model works on 263-d ones"),
        (["--evaluator", "no-such-run"], "no evaluator run 'no-such-run'"),
        (["--checkpoint", "no-such-run"], "no m2d2m run 'no-such-run'"),
        (["--ts", "9"], "T_s must lie in 0..T = 8"),
        (["--glove", "glove"], "--glove and --meta go with --guo-evaluator"),
        (["--guo-evaluator", "guo"], "--guo-evaluator needs --glove DIR"),
        (["--resume", "some-run", "--repeats", "3"], "with its own settings; drop --repeats"),
        (["--resume", "no-such-run"], "no eval run 'no-such-run'"),
        (["--no-multi"], "--no-multi leaves nothing to evaluate: add --single, --edit TASK or --regenerate K"),
        (["--option", "steps=9", "--single"], "steps must lie in 1..T = 8"),
        (["--regenerate", "0"], "argument --regenerate: must be a positive integer, got 0"),
        (["--regenerate", "3"], "'s instances have 2 actions"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(trained_project, tiny_testset, other_dim_testset, capsys, arguments, message):
    arguments = [a.replace("{other}", str(other_dim_testset)) for a in arguments]
    given = [] if {"--testset", "--resume"} & set(arguments) else ["--testset", str(tiny_testset)]
    line = one_line_error(["evaluate", "--dataset", "tiny", *given, *arguments], capsys)
    assert message in line, line


def test_a_missing_evaluator_says_what_to_run(trained_project, tmp_path, monkeypatch, capsys):
    (tmp_path / "runs").mkdir()  # a project with no runs yet (outside a project, a verb says that instead)
    monkeypatch.chdir(tmp_path)
    model = next((trained_project / "runs" / "tiny" / "m2d2m").glob("*/model.pt"))
    assert main(["evaluate", "--dataset", "tiny", "--checkpoint", str(model)]) == 2
    assert "run `make train-evaluator` first" in capsys.readouterr().err


def test_a_metric_registered_from_outside_is_a_column_of_the_table_and_in_mlflow(
    trained_project, tiny_testset, monkeypatch
):
    """tests/fake_metric.py's root travel, measured on the playback model (tests/fake_model.py),
    whose sequences are known: each row's value is the hand-computed mean over its sequences."""
    import m2d2m.evaluation.sequence_metrics as sequence_metrics
    from m2d2m.motion.representation.features import features_to_joints
    from m2d2m.motion.representation.skeleton import SKELETONS
    from orchestration.registry import load_plugins
    from pipelines.testset import load_testset

    # the plugin is imported afresh by the registry, and its metric leaves with this test
    monkeypatch.setattr(sequence_metrics, "_REGISTERED", {})
    monkeypatch.delitem(sys.modules, "tests.fake_metric", raising=False)
    monkeypatch.setattr("m2d2m.plugins._imported", [])
    monkeypatch.chdir(trained_project)
    monkeypatch.setenv("M2D2M_PLUGINS", "tests.fake_model,tests.fake_metric")
    load_plugins()
    assert [metric.name for metric in sequence_metrics.sequence_metrics()] == ["root_travel"]
    from tests.fake_metric import root_travel
    from tests.fake_model import evaluate_playback, playback_of

    model_file, clips = playback_of(tiny_testset, trained_project / "playback-metric.npz")
    testset = load_testset(tiny_testset)
    expected = []  # what playback lays end to end for each instance, measured by hand
    for instance in testset:
        pieces = []
        for p, item in enumerate(instance.items):
            stored, frames = clips[item.action], len(testset.features(instance.index, p))
            pieces.append(stored[np.minimum(np.arange(frames), len(stored) - 1)])
        expected.append(root_travel(features_to_joints(np.concatenate(pieces), SKELETONS["t2m"]), [], None))

    assert main(evaluate_playback(model_file, tiny_testset)) == 0
    run_dir = latest_evaluation(trained_project)
    table = json.loads((run_dir / "table.json").read_text(encoding="utf-8"))
    assert table["multi"]["concat"]["root_travel"]["mean"] == pytest.approx(np.mean(expected), rel=1e-5)
    assert table["multi"]["gt_concat"]["root_travel"]["mean"] > 0  # the ground truth joined, measured alike
    header = next(
        line for line in (run_dir / "table.md").read_text(encoding="utf-8").splitlines() if line.startswith("| Method")
    )
    assert header.endswith("| Root travel (m) |")
    run_id = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))["mlflow_run_id"]
    logged = mlflow_client(trained_project).get_run(run_id).data.metrics
    assert logged["multi/concat/root_travel"] == pytest.approx(np.mean(expected), rel=1e-5)
