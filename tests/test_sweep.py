"""`m2d2m sweep` end to end with real Ray Tune and a real MLflow SQLite store: two sampling trials
on a tiny trained model become child runs of one parent with a summary table and plot,
re-running a sweep restores it instead of starting over (unless its config changed: then it is
refused, or replaced with --restart), and a training sweep's keys are checked before Ray starts."""

from __future__ import annotations

import json
from pathlib import Path

import mlflow
import numpy as np
import pytest
import yaml

from orchestration.cli import main
from orchestration.errors import UserError
from orchestration.sweep import SUMMARY_JSON, SUMMARY_MD, summary_plot, sweep, trial_name
from tests.helpers import latest_evaluation, one_line_error

SUMMARY_PNG = summary_plot("ts")
M2D2M_DEMO = Path(__file__).resolve().parents[1] / "configs" / "m2d2m" / "demo.yaml"


def sweep_config(testset: Path, **changes) -> dict:
    return {
        "dataset": "tiny",
        "kind": "sampling",
        "model": "m2d2m",
        "checkpoint": "latest",
        "train_config": "unused",
        "evaluator": "latest",
        "testset": str(testset),
        "method": "tps",
        "repeats": 1,
        "search": "grid",
        "samples": 1,
        "space": {"eta": [0.25], "ts": [2, 4]},
        "resources": {"cpu": 1, "gpu": 0},
        "max_concurrent": 2,
        "max_failures": 1,
        **changes,
    }


def child_runs(trained_project: Path, parent_run_id: str) -> list:
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{trained_project / 'mlflow.db'}")
    parent = client.get_run(parent_run_id)
    runs = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent_run_id}'")
    return sorted(runs, key=lambda run: run.info.run_name)


def test_a_two_trial_sweep_nests_its_trials_under_one_parent_and_resumes(
    trained_project, tiny_testset, monkeypatch, capfd
):
    import m2d2m.progress

    monkeypatch.chdir(trained_project)
    monkeypatch.setattr(m2d2m.progress, "MIN_SECONDS", 0.0)
    (trained_project / "two.yaml").write_text(yaml.safe_dump(sweep_config(tiny_testset)), encoding="utf-8")
    sweep_dir = sweep(str(trained_project / "two.yaml"))
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("sweep two: ")]
    assert lines[-1].startswith("sweep two: 2/2 trial (100 %)") and lines[-1].endswith(" done"), lines

    summary = yaml.safe_load((sweep_dir / SUMMARY_JSON).read_text(encoding="utf-8"))
    assert [(row["eta"], row["ts"]) for row in summary] == [(0.25, 2), (0.25, 4)]
    assert all(row["multi/tps/jerk"] is not None and row["multi/tps/fid"] is not None for row in summary)
    assert (sweep_dir / SUMMARY_PNG).stat().st_size > 0 and "multi/tps/jerk" in (sweep_dir / SUMMARY_MD).read_text()

    parent_run_id = yaml.safe_load((sweep_dir / "sweep.json").read_text(encoding="utf-8"))["parent_run_id"]
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{trained_project / 'mlflow.db'}")
    parent = client.get_run(parent_run_id)
    assert parent.info.status == "FINISHED" and parent.data.tags["stage"] == "sweep"
    artifacts = {Path(a.path).name for a in client.list_artifacts(parent_run_id)}
    assert {SUMMARY_MD, SUMMARY_JSON, SUMMARY_PNG} <= artifacts
    children = child_runs(trained_project, parent_run_id)
    assert [run.info.run_name for run in children] == [
        trial_name({"eta": 0.25, "ts": 2}),
        trial_name({"eta": 0.25, "ts": 4}),
    ]
    for run, ts in zip(children, (2, 4)):
        assert run.data.params["ts"] == str(ts) and run.data.params["eta"] == "0.25"
        assert "multi/tps/jerk" in run.data.metrics and run.data.tags["stage"] == "eval"

    # the driver runs again (as after a crash): Tune restores the experiment, finished trials stay done
    assert sweep(str(trained_project / "two.yaml")) == sweep_dir
    assert len(child_runs(trained_project, parent_run_id)) == 2

    # an edited config is refused: a restored experiment would run the old space
    (trained_project / "two.yaml").write_text(
        yaml.safe_dump(sweep_config(tiny_testset, space={"eta": [0.25], "ts": [3]})), encoding="utf-8"
    )
    with pytest.raises(UserError, match=r"\(space.ts changed\).*--restart"):
        sweep(str(trained_project / "two.yaml"))
    # --restart replaces it: a new parent run over the new space only
    assert sweep(str(trained_project / "two.yaml"), restart=True) == sweep_dir
    assert yaml.safe_load((sweep_dir / "sweep.json").read_text(encoding="utf-8"))["parent_run_id"] != parent_run_id
    assert [row["ts"] for row in yaml.safe_load((sweep_dir / SUMMARY_JSON).read_text(encoding="utf-8"))] == [3]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"kind": "inference"}, "sweep kind must be one of"),
        ({"space": {"eta": []}}, "non-empty list"),
        ({"space": {"width": [1, 2]}}, "unknown: width"),
    ],
)
def test_bad_sweep_configs_are_one_line_errors(trained_project, tiny_testset, capsys, monkeypatch, change, message):
    monkeypatch.chdir(trained_project)
    (trained_project / "bad.yaml").write_text(yaml.safe_dump(sweep_config(tiny_testset, **change)), encoding="utf-8")
    assert message in one_line_error(["sweep", "--config", str(trained_project / "bad.yaml")], capsys)


def test_a_training_sweep_trains_each_trial_then_evaluates_it(trained_project, tiny_testset, monkeypatch):
    monkeypatch.chdir(trained_project)
    config = sweep_config(
        tiny_testset,
        kind="training",
        train_config=str(trained_project / "diffusion.yaml"),
        space={"diffusion.kind": ["uniform", "dynamic"]},
    )
    (trained_project / "ablation.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    sweep_dir = sweep(str(trained_project / "ablation.yaml"))
    summary = yaml.safe_load((sweep_dir / SUMMARY_JSON).read_text(encoding="utf-8"))
    assert [row["diffusion.kind"] for row in summary] == ["dynamic", "uniform"]
    assert all(row["multi/tps/jerk"] is not None for row in summary)
    trained = [
        yaml.safe_load((run / "run.json").read_text())["config"]["diffusion"]["kind"]
        for run in (trained_project / "runs" / "tiny" / "m2d2m").iterdir()
        if (run / "run.json").exists()
    ]
    assert trained.count("uniform") == 1 and trained.count("dynamic") >= 2  # the fixture's run, and the trial's


def test_a_training_trial_can_train_on_two_ray_train_workers(trained_project, tiny_testset, monkeypatch):
    """Ray Train's TorchTrainer, two CPU workers in DDP (gloo), inside a Tune trial: one run
    trained by both ranks, its model evaluated by the trial."""
    monkeypatch.chdir(trained_project)
    config = sweep_config(
        tiny_testset,
        kind="training",
        train_config=str(trained_project / "diffusion.yaml"),
        space={"diffusion.eta": [0.5]},
        resources={"cpu": 0.5, "gpu": 0, "workers": 2},
    )
    (trained_project / "workers.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    before = set((trained_project / "runs" / "tiny" / "m2d2m").iterdir())
    sweep_dir = sweep(str(trained_project / "workers.yaml"))
    summary = yaml.safe_load((sweep_dir / SUMMARY_JSON).read_text(encoding="utf-8"))
    assert len(summary) == 1 and summary[0]["multi/tps/jerk"] is not None
    (new_run,) = set((trained_project / "runs" / "tiny" / "m2d2m").iterdir()) - before
    info = yaml.safe_load((new_run / "run.json").read_text(encoding="utf-8"))
    assert info["status"] == "finished" and info["world_size"] == 2
    assert info["config"]["diffusion"]["eta"] == 0.5 and (new_run / "model.pt").is_file()


def test_workers_are_for_training_sweeps(trained_project, tiny_testset, capsys, monkeypatch):
    monkeypatch.chdir(trained_project)
    config = sweep_config(tiny_testset, resources={"cpu": 1, "gpu": 0, "workers": 2})
    (trained_project / "bad-workers.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    assert main(["sweep", "--config", str(trained_project / "bad-workers.yaml")]) == 2
    assert "training sweeps only" in capsys.readouterr().err


def test_a_model_registered_from_outside_goes_through_evaluate_and_a_sampling_sweep(
    trained_project, tiny_testset, monkeypatch, capsys
):
    """The registry and the generator protocol are all that evaluation and sweeps know of a model:
    a plugin's playback model (tests/fake_model.py) runs through both unchanged."""
    from orchestration.registry import load_plugins, models
    from tests.fake_model import evaluate_playback, playback_of

    monkeypatch.chdir(trained_project)
    monkeypatch.setenv("M2D2M_PLUGINS", "tests.fake_model")
    load_plugins()
    assert "playback" in models()
    model_file, _ = playback_of(tiny_testset, trained_project / "playback.npz")

    assert main(evaluate_playback(model_file, tiny_testset)) == 0
    assert "ground truth played back from frame 0" in capsys.readouterr().out
    table = yaml.safe_load((latest_evaluation(trained_project) / "table.json").read_text())
    (judged,) = table["settings"]["candidates"]
    assert judged["model"] == "playback" and judged["methods"] == ["concat"]
    assert all(np.isfinite(summary["mean"]) for summary in table["multi"]["concat"].values())

    config = sweep_config(
        tiny_testset, model="playback", checkpoint=str(model_file), method="concat", space={"offset": [0, 3]}
    )
    (trained_project / "playback.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    summary = yaml.safe_load((sweep(str(trained_project / "playback.yaml")) / SUMMARY_JSON).read_text())
    assert [row["offset"] for row in summary] == [0, 3]
    assert summary[0]["multi/concat/fid"] == pytest.approx(table["multi"]["concat"]["fid"]["mean"])
    assert summary[0]["multi/concat/fid"] != summary[1]["multi/concat/fid"]  # the knob reached the generator


@pytest.mark.parametrize(
    "space, message",
    [
        ({"diffusion.nope": [1]}, "no key 'nope' in diffusion"),
        ({"diffusion.kind": ["uniform"], "optim.lr": [1e-3, "fast"]}, "optim.lr takes a number, got 'fast'"),
    ],
)
def test_a_training_sweep_key_its_training_config_lacks_is_one_line_before_ray(
    tmp_path, capsys, monkeypatch, space, message
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    config = sweep_config(tmp_path / "testset", kind="training", train_config=str(M2D2M_DEMO), space=space)
    (tmp_path / "ablation.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    assert message in one_line_error(["sweep", "--config", str(tmp_path / "ablation.yaml")], capsys)
    assert not (tmp_path / "runs").exists() and not (tmp_path / "mlflow.db").exists()  # no parent run, no Ray


def test_a_rerun_whose_config_changed_is_refused_before_ray(tmp_path, capsys, monkeypatch):
    """A sweep.json as a first run left it; the config edited since, or given through --set."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    config = {**sweep_config(tmp_path / "testset"), "resources": {"cpu": 1, "gpu": 0, "workers": 0}}
    sweep_dir = tmp_path / "runs" / "tiny" / "sweep" / "grid"
    sweep_dir.mkdir(parents=True)
    (sweep_dir / "sweep.json").write_text(
        json.dumps({"experiment_id": "1", "parent_run_id": "0" * 32, "config": config}), encoding="utf-8"
    )
    (tmp_path / "grid.yaml").write_text(yaml.safe_dump({**config, "repeats": 3}), encoding="utf-8")
    err = one_line_error(["sweep", "--config", str(tmp_path / "grid.yaml")], capsys)
    assert "(repeats changed)" in err and "--name" in err and "--restart" in err
    err = one_line_error(
        ["sweep", "--config", str(tmp_path / "grid.yaml"), "--set", "repeats=1", "--set", "space.eta=[0.5]"], capsys
    )
    assert "(space.eta changed)" in err
    assert "plain folder name" in one_line_error(
        ["sweep", "--config", str(tmp_path / "grid.yaml"), "--name", "../x"], capsys
    )
    assert sorted(p.name for p in sweep_dir.iterdir()) == ["sweep.json"]
