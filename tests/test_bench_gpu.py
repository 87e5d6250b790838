"""bench/gpu.py --quick, the CPU mode of `make bench-gpu` that CI runs: every model trains, samples
and makes the long sequence through the real modules, generators and recipes, and the tables are
written; what it measures, not how fast."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # bench scripts import `timing` beside them
import bench.gpu  # noqa: E402
from bench.gpu import BF16_PEAKS, MODELS, machine, main, parse, training_batches  # noqa: E402
from tests.helpers import lacking  # noqa: E402


@pytest.mark.slow
def test_quick_measures_every_model_and_writes_the_tables(tmp_path, one_torch_thread):
    lightning = logging.getLogger("lightning.pytorch")
    level = lightning.level
    result = main(["--quick", "--out", str(tmp_path)])
    assert lightning.level == level  # its quiet logging ends with it, for what runs next in the process
    assert [row["model"] for row in result["training"]] == list(MODELS)
    for row in result["training"]:
        assert row["size"] == "demo" and row["batch"] == 2 and row["precision"] == "32-true"
        assert not row["compiled"] and row["warmup_s"] > 0  # a CPU trains eagerly unless asked
        assert row["steps_per_s"] > 0 and row["gflop_per_step"] > 0 and row["parameters"] > 0
        assert row["gpu_utilisation"] is None and row["peak_memory_gib"] is None  # a CPU has neither
    sampled = {(row["model"], row["batch"]) for row in result["sampling"]}
    assert sampled == {(name, batch) for name in MODELS if name != "vq" for batch in (1, 2)}
    assert all(row["aits"] == row["seconds"] / row["batch"] for row in result["sampling"])
    for row in result["sampling"]:  # MotionDiffuse sampled at 2 of its 1000 steps: the time at all, by proportion
        assert row["aits_at_all_steps"] == (row["aits"] * 500 if row["model"] == "motiondiffuse" else row["aits"])
    assert {row["model"]: row["method"] for row in result["long"]} == {
        "m2d2m": "tps",
        "mmm": "transition",
        "motiondiffuse": "time-varied",
    }
    motiondiffuse = next(row for row in result["long"] if row["model"] == "motiondiffuse")
    assert motiondiffuse["seconds_at_all_steps"] > motiondiffuse["seconds"]  # extrapolated to its 1000 steps
    assert result["serving"] == {"skipped": "--quick"} and result["failures"] == []
    assert json.loads((tmp_path / "gpu.json").read_text(encoding="utf-8")) == result
    assert sorted(path.name for path in tmp_path.iterdir()) == ["gpu.json", "gpu.md"]  # the model files went
    markdown = (tmp_path / "gpu.md").read_text(encoding="utf-8")
    assert markdown.count("| demo |") == 4 + 6 and "Serving: skipped" in markdown


def test_the_card_s_peak_is_known_by_its_name(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "NVIDIA H100 80GB HBM3")
    assert machine(torch.device("cuda", 0))["bf16_peak_tflops"] == 989.0
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "NVIDIA H100 PCIe")
    assert machine(torch.device("cuda", 0))["bf16_peak_tflops"] == dict(BF16_PEAKS)["H100 PCIe"]
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "Some Future GPU")
    assert machine(torch.device("cuda", 0))["bf16_peak_tflops"] is None
    assert machine(torch.device("cpu"))["bf16_peak_tflops"] is None


def test_a_failing_measurement_is_recorded_and_the_others_go_on(tmp_path, one_torch_thread, monkeypatch, capsys):
    def broken(*args, **kwargs):
        raise RuntimeError("CUDA error: out of memory")

    monkeypatch.setattr(bench.gpu, "measure_long", broken)
    with pytest.raises(SystemExit) as stopped:
        main(["--quick", "--models", "vq", "m2d2m", "--out", str(tmp_path)])
    assert stopped.value.code == 1
    written = json.loads((tmp_path / "gpu.json").read_text(encoding="utf-8"))
    assert written["failures"] == ["the 0.1-minute sequence by m2d2m: RuntimeError: CUDA error: out of memory"]
    assert [row["model"] for row in written["training"]] == ["vq", "m2d2m"] and len(written["sampling"]) == 2
    assert "Failed: the 0.1-minute sequence by m2d2m" in (tmp_path / "gpu.md").read_text(encoding="utf-8")


def test_paper_batches_choose_the_paper_size_s_training_batches():
    config = {"data": {"batch_size": 64}}
    args = parse(["--paper-batches", "64", "256", "--out", "x"])
    assert training_batches(args, "paper", config) == [64, 256] and training_batches(args, "demo", config) == [64]
    assert training_batches(parse(["--out", "x"]), "paper", config) == [64]
    assert training_batches(parse(["--batch", "8", "--paper-batches", "256", "--out", "x"]), "paper", config) == [8]


def test_training_steps_are_timed_eager_and_compiled_on_a_gpu_and_eager_on_a_cpu():
    assert parse(["--out", "x"]).train_compile == ["off"]
    assert parse(["--out", "x", "--device", "cuda"]).train_compile == ["off", "on"]
    assert parse(["--out", "x", "--train-compile", "on", "off", "on"]).train_compile == ["off", "on"]


@pytest.mark.slow
def test_a_compiled_training_step_is_timed_beside_the_eager_one_with_the_eager_flops(tmp_path, one_torch_thread):
    """On the CPU through inductor's C++ kernels: the compiled row says so, its warm-up holds the
    compiling, and its FLOPs are the eager step's (FlopCounterMode sees none inside a compiled pass)."""
    result = main(["--quick", "--models", "mmm", "--train-compile", "off", "on", "--out", str(tmp_path)])
    eager, compiled = result["training"]
    assert (eager["compiled"], compiled["compiled"]) == (False, True)
    assert compiled["gflop_per_step"] == pytest.approx(eager["gflop_per_step"]) and compiled["steps_per_s"] > 0
    assert "| mmm | demo | " in (tmp_path / "gpu.md").read_text(encoding="utf-8")


# Run in a fresh interpreter: the packages a bare GPU machine lacks cannot be imported.
WITHOUT_THEM = lacking("pygltflib", "ray", "spacy", "mlflow") + 'sys.path.insert(0, "bench")\nimport gpu\n'


@pytest.mark.slow
def test_the_bench_imports_with_only_the_packages_its_docstring_names():
    """Issue 54: `m2d2m.motion.clip` imported pygltflib at module level, so bench/gpu.py did not
    start on a machine given only what its docstring lists."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", WITHOUT_THEM], cwd=root, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr[-2000:]


def test_the_command_line_s_steps_per_second_run_from_its_first_progress_line_to_its_last(monkeypatch, tmp_path):
    """Start-up (imports, data, the first batches) is not in the rate; validations and previews
    between the lines are: (200 − 20) steps in (40 − 4) s."""
    from exit_time import Timed

    seen = {}

    def run(command, cwd, env):
        seen.update(command=command, cwd=cwd)
        lines = [(1.0, "loading"), (4.0, "training: 20/200 step (10 %)"), (40.0, "training: 200/200 step (100 %)")]
        return Timed(41.5, 0.5, 0, [*lines, (41.0, "finished runs/x")])

    monkeypatch.setattr(bench.gpu, "timed", run)
    figure = bench.gpu.measure_cli("mmm", tmp_path, 200, compiled=True)
    assert figure.steps_per_s == pytest.approx(180 / 36) and figure.total_s == 41.5 and figure.finished_to_exit_s == 0.5
    assert seen["cwd"] == tmp_path and seen["command"][3:6] == ["train-mmm", "--config", "demo"]
    assert "--set=trainer.compile=on" in seen["command"] and "--set=trainer.val_every_steps=100" in seen["command"]
    monkeypatch.setattr(
        bench.gpu, "timed", lambda command, cwd, env: Timed(3.0, None, 2, [(2.0, "m2d2m: error: no data")])
    )
    with pytest.raises(RuntimeError, match="exited 2: m2d2m: error: no data"):
        bench.gpu.measure_cli("mmm", tmp_path, 200, compiled=False)


def test_a_command_too_quick_for_two_progress_lines_gives_its_last_line_s_rate(monkeypatch, tmp_path):
    """Progress lines come at most one each 5 s: a VQ-VAE's 500 steps on a GPU print only the last,
    whose own rate (over the whole training) stands in, marked as not steady."""
    from exit_time import Timed

    for line, rate in [
        ("training: 500/500 step (100 %), 87.5 step/s, 0 s left", 87.5),
        ("training: 4/4 step (100 %), 2.5 s/step, 0 s left", 0.4),
    ]:
        monkeypatch.setattr(
            bench.gpu,
            "timed",
            lambda command, cwd, env, line=line: Timed(9.0, 0.4, 0, [(8.0, line), (8.5, "finished runs/x")]),
        )
        figure = bench.gpu.measure_cli("vq", tmp_path, 500, compiled=False)
        assert figure.steps_per_s == pytest.approx(rate) and not figure.steady
    monkeypatch.setattr(bench.gpu, "timed", lambda command, cwd, env: Timed(3.0, 0.4, 0, [(2.0, "finished runs/x")]))
    with pytest.raises(RuntimeError, match="printed no progress line"):
        bench.gpu.measure_cli("vq", tmp_path, 500, compiled=False)
