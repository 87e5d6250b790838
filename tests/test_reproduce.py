"""`make reproduce`'s report: readable midway, complete at the end (bench/reproduce.py)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest

from orchestration.runs import new_run_dir, newest_run, read_run_info, write_run_info

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # bench scripts import `stages` beside them
import stages  # noqa: E402

from bench.reproduce import Scale, _plain, plot, report  # noqa: E402

SCALE = Scale(vq_steps=10, diffusion_steps=10, repeats=2, ts=(0, 90, 100))


def metrics(jerk: float) -> dict:
    names = ("jerk", "fid", "transition_fid", "peak_jerk", "auj", "r_top3")
    return {name: {"mean": jerk + i, "ci": 0.01} for i, name in enumerate(names)}


def test_a_report_written_midway_marks_what_is_missing(tmp_path):
    results = {"uniform": {}, "dynamic": {100: {"tps": metrics(0.5), "gt_single": metrics(1.0)}}}
    text = report(results, {}, SCALE)
    assert "| ground truth (single) | 2.000 ± 0.010 |" in text  # from whichever evaluation finished
    assert "| β(t, d) (dynamic), T_s = 100 | 1.500 ± 0.010 | 2.500 ± 0.010 | 0.500 ± 0.010 |" in text
    assert "| β_t (uniform), T_s = 90 | – | – | – | – | – | – |" in text
    plot(tmp_path / "curve.png", results)
    assert (tmp_path / "curve.png").stat().st_size > 0


def test_a_complete_report_has_both_tables_and_every_point_of_the_curve():
    results = {kind: {ts: {"tps": metrics(ts / 100)} for ts in SCALE.ts} for kind in ("uniform", "dynamic")}
    baselines = {
        "handshake": metrics(0.7),
        "slerp": metrics(1.5),
        "gt_single": metrics(1.0),
        "gt_concat": metrics(1.2),
        "reconstruction": metrics(1.0),
    }
    text = report(results, baselines, SCALE)
    for heading in ("## Table 5", "## Table 6", "## Ground truth", "## Jerk and FID against T_s"):
        assert heading in text
    assert "| slerp | 2.500 ± 0.010 | 3.500 ± 0.010 | 1.500 ± 0.010 |" in text
    assert text.count("T_s = 0 |") == 2 and "| – |" not in text.split("## Ground truth")[0]


def test_a_stopped_reproduction_continues_where_it_stopped(tmp_path, monkeypatch):
    """A stage killed midway is resumed (not started again); finished stages are not run again."""
    monkeypatch.chdir(tmp_path)
    calls: list[tuple[str, ...]] = []

    def killed_once(*argv: str) -> None:
        calls.append(argv)
        if argv[0] == "train-vq" and "--resume" not in argv:
            new_run_dir("synthetic", "vq")  # the kill comes after the run folder exists
            raise SystemExit("killed")
        run_dir = newest_run("synthetic", "vq") if "--resume" in argv else new_run_dir("synthetic", "vq")
        write_run_info(run_dir, status="finished")

    monkeypatch.setattr(stages, "run", killed_once)
    state = tmp_path / "state.json"
    vq = ("train-vq", "--config", "demo")
    with pytest.raises(SystemExit):
        stages.Progress(state, _plain(SCALE), restart=False).stage("vq", "vq", str, *vq, resume=(*vq, "--resume"))
    progress = stages.Progress(state, _plain(SCALE), restart=False)
    first = progress.stage("vq", "vq", str, *vq, resume=(*vq, "--resume"))
    assert calls == [vq, (*vq, "--resume")]
    assert first == str(newest_run("synthetic", "vq"))
    assert progress.stage("vq", "vq", str, *vq, resume=(*vq, "--resume")) == first and len(calls) == 2

    with pytest.raises(SystemExit, match="other settings"):
        stages.Progress(state, _plain(Scale(1, 1, 1, (90, 100))), restart=False)
    assert stages.Progress(state, _plain(Scale(1, 1, 1, (90, 100))), restart=True).state["finished"] == {}


def test_a_run_another_command_starts_beside_a_bench_is_not_taken_for_the_benchs(tmp_path, monkeypatch):
    """An evaluation run by hand while a bench evaluates lands in the same stage folder, later: the
    bench must still record the run its own command made."""
    monkeypatch.chdir(tmp_path)
    made: list[Path] = []

    def evaluate_beside_another(*argv: str) -> None:
        made.append(new_run_dir("synthetic", "eval"))
        write_run_info(made[-1], status="finished")
        beside = new_run_dir("synthetic", "eval")  # started later, by another process
        write_run_info(beside, status="finished", pid=-1, started=read_run_info(made[-1])["started"] + 1)

    monkeypatch.setattr(stages, "run", evaluate_beside_another)
    progress = stages.Progress(tmp_path / "state.json", _plain(SCALE), restart=False)
    assert progress.stage("judge", "eval", str, "evaluate", resume=("evaluate", "--resume", "{run}")) == str(made[0])


def test_a_key_recorded_before_runs_named_their_process_keeps_its_own_run(tmp_path, monkeypatch):
    """A state written before run folders recorded their process: its key still finds the run of
    its time, not a newer one that a command started since (which names its process)."""
    monkeypatch.chdir(tmp_path)
    progress = stages.Progress(tmp_path / "state.json", _plain(SCALE), restart=False)
    progress.state["started"]["vq"] = time.time()
    own = new_run_dir("synthetic", "vq")
    info = {key: value for key, value in read_run_info(own).items() if key != "pid"}
    (own / "run.json").write_text(json.dumps({**info, "status": "finished"}), encoding="utf-8")
    write_run_info(new_run_dir("synthetic", "vq"), status="finished")  # a later run, by this process
    monkeypatch.setattr(stages, "run", lambda *argv: pytest.fail("a finished key's run was started again"))
    assert progress.stage("vq", "vq", str, "train-vq", resume=("train-vq", "--resume")) == str(own)
