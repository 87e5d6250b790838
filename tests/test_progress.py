"""Progress in a log: plain lines at a steady pace when stderr is not a terminal (training,
generation, evaluation, the corpus), never a bar's carriage returns or escape codes; tqdm's bar
on a terminal."""

from __future__ import annotations

import io

import pytest

import m2d2m.progress as progress_module
from m2d2m.progress import ProgressLines, duration, progress
from orchestration.recipes.vq import train_vq


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def run(total: float, steps: int, seconds_per_step: float, **kwargs) -> list[str]:
    clock, out = Clock(), io.StringIO()
    with ProgressLines(total=total, desc="job", unit="step", file=out, clock=clock, **kwargs) as lines:
        for _ in range(steps):
            clock.now += seconds_per_step
            lines.update()
    return out.getvalue().splitlines()


def test_a_long_job_prints_a_line_at_each_tenth_with_rate_and_time_left():
    lines = run(100, 100, 1.0)
    assert len(lines) == 10
    assert lines[0] == "job: 10/100 step (10 %), 1 step/s, 1 min 30 s left"
    assert lines[4] == "job: 50/100 step (50 %), 1 step/s, 50 s left"
    assert lines[-1] == "job: 100/100 step (100 %), 1 step/s, 0 s left"
    assert run(100, 10, 10.0)[0] == "job: 3/100 step (3 %), 10 s/step, 16 min 10 s left"  # 30 s passed first


def test_a_short_job_prints_nothing_and_a_slow_one_at_least_every_30_seconds():
    assert run(100, 100, 0.01) == []  # a second in all: no line at all
    lines = run(10_000, 40, 10.0)  # never reaches a tenth: a line every 30 s and the last
    assert len(lines) == 14 and lines[0] == "job: 3/10000 step (0 %), 10 s/step, 27 h 46 min left"
    assert lines[-1].startswith("job: 40/10000")
    ticks = run(100, 50, 1.0, initial=50)  # resumed at half: counts on from 50, its rate from now
    assert ticks[0] == "job: 60/100 step (60 %), 1 step/s, 40 s left" and len(ticks) == 5


def test_lines_are_plain_and_a_terminal_gets_tqdm():
    for line in run(100, 100, 1.0):
        assert "\r" not in line and "\x1b" not in line
    assert isinstance(progress(total=3, file=io.StringIO()), ProgressLines)

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    from tqdm import tqdm

    assert isinstance(progress(total=3, file=Terminal()), tqdm)
    assert list(progress(range(3), file=io.StringIO())) == [0, 1, 2]
    assert duration(42) == "42 s" and duration(185) == "3 min 5 s" and duration(7800) == "2 h 10 min"


def test_training_in_a_log_prints_steps_and_loss_in_plain_lines(project, capfd, monkeypatch):
    monkeypatch.setattr(progress_module, "MIN_SECONDS", 0.0)
    train_vq(str(project / "tiny.yaml"))
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("training: ")]
    assert len(lines) >= 2 and "step (" in lines[-1] and "loss " in lines[-1], err[-2000:]
    assert "\r" not in err and "\x1b[" not in err


@pytest.mark.parametrize("unit, shown", [("%", "job: 50 %"), ("frame", "job: 50/100 frame (50 %)")])
def test_percent_counters_say_only_the_percentage(unit, shown):
    clock, out = Clock(), io.StringIO()
    lines = ProgressLines(total=100, desc="job", unit=unit, file=out, clock=clock)
    clock.now = 10.0
    lines.update(50)
    assert out.getvalue().startswith(shown)


def test_a_generation_reports_its_sampling_in_percent_lines(monkeypatch, capsys):
    from orchestration.generate.sampling import _progress

    monkeypatch.setattr(progress_module, "MIN_SECONDS", 0.0)
    with _progress("sampling 2 action(s)") as advance:
        for done in (0.25, 0.5, 1.0):
            advance(done)
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("sampling 2 action(s): 25 %, ") and err[-1].startswith("sampling 2 action(s): 100 %")


def _slow_square(task: dict) -> dict:
    return {"square": task["n"] ** 2}


def test_ray_data_jobs_in_a_log_print_plain_lines(ray_local, capfd, monkeypatch):
    from pipelines.features import run_json_tasks

    monkeypatch.setattr(progress_module, "MIN_SECONDS", 0.0)
    capfd.readouterr()
    assert run_json_tasks(_slow_square, [{"n": n} for n in range(4)], workers=2) == [
        {"square": n * n} for n in range(4)
    ]
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("slow square: ")]
    assert lines and lines[-1].startswith("slow square: 4/4 task (100 %)"), lines


def test_an_evaluation_in_a_log_prints_its_batches_in_plain_lines(trained_project, tiny_testset, capfd, monkeypatch):
    from orchestration.cli import main

    monkeypatch.setattr(progress_module, "MIN_SECONDS", 0.0)
    capfd.readouterr()
    argv = ["evaluate", "--dataset", "tiny", "--testset", str(tiny_testset), "--repeats", "1", "--ts", "4"]
    assert main(argv + ["--batch-size", "3"]) == 0
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if " batch (" in line]
    assert lines and lines[-1].startswith("tps r0: 3/3 batch (100 %)"), err[-2000:]
    assert "\r" not in err and "\x1b[" not in err


def test_a_restored_sweep_counts_the_trials_it_had_finished(capsys, monkeypatch):
    """Tune pickles the sweep's callback with the experiment and hands it back on restore: the
    driver that restores it counts the trials finished before it, and prints in its own log."""
    import pickle
    from types import SimpleNamespace

    from ray.tune.experiment import Trial

    from orchestration.sweep_lines import TrialLines

    monkeypatch.setattr(progress_module, "MIN_SECONDS", 0.0)
    trials = [
        SimpleNamespace(status=status, TERMINATED=Trial.TERMINATED, config={"eta": 0.25, "ts": ts})
        for status, ts in ((Trial.TERMINATED, 2), (Trial.PENDING, 4), (Trial.PENDING, 8))
    ]
    restored = pickle.loads(pickle.dumps(TrialLines("demo", ["eta", "ts"], total=3)))
    restored.setup()
    restored.on_step_begin(0, trials)
    restored.on_trial_complete(1, trials, trials[1])
    restored.on_trial_error(2, trials, trials[2])
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("sweep demo: 2/3 trial (67 %)") and lines[0].endswith("eta=0.25 ts=4 done")
    assert lines[1].startswith("sweep demo: 3/3 trial (100 %)") and lines[1].endswith("eta=0.25 ts=8 failed")
