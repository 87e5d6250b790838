"""bench/aits.py on the session's tiny models (M2D2M, MMM, MotionDiffuse): what it measures and writes,
not how fast."""

from __future__ import annotations

import json
import statistics
import sys
from collections import Counter
from pathlib import Path

import pytest
import yaml

from orchestration.recipe import train
from tests.helpers import TINY_MMM, TINY_MOTIONDIFFUSE

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # bench scripts import `timing` beside them
from bench.aits import long_plan, main  # noqa: E402


@pytest.fixture(scope="module")
def three_models(trained_project) -> Path:
    """The trained project (tiny VQ-VAE and denoiser) with a tiny MMM and a tiny MotionDiffuse (T = 50
    steps) beside its denoiser."""
    (trained_project / "mmm.yaml").write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    train("mmm", str(trained_project / "mmm.yaml"))
    config = {**TINY_MOTIONDIFFUSE, "data": {**TINY_MOTIONDIFFUSE["data"], "dir": str(trained_project / "data")}}
    (trained_project / "motiondiffuse.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    train("motiondiffuse", str(trained_project / "motiondiffuse.yaml"))
    return trained_project


def test_mmm_long_sequence_is_split_into_the_fewest_even_actions():
    frames = long_plan(10.873, fps=20, frame_step=4, action_frames=196)
    # 10.873 min at 20 fps = 3,262 tokens: 67 actions of at most 49 tokens, 48 or 49 each
    assert len(frames) == 67 and sum(frames) == 13048
    assert Counter(frames) == {196: 46, 192: 21}
    assert long_plan(0.05, fps=20, frame_step=4, action_frames=20) == [20, 20, 20]


def test_aits_and_long_sequence_of_three_models_in_one_run(three_models, capsys):
    out = three_models / "aits"
    main(
        [
            "--dataset",
            "tiny",
            "--lengths",
            "8",
            "16",
            "--batches",
            "1",
            "2",
            "--warmup",
            "0",
            "--repeats",
            "2",
            "--m2d2m-steps",
            "8",
            "2",
            "--m2d2m-long-steps",
            "4",
            "--md-steps",
            "10",
            "50",
            "--md-batches",
            "1",
            "--md-long-steps",
            "5",
            "--long-minutes",
            "0.05",
            "--action-frames",
            "24",
            "--long-repeats",
            "1",
            "--threads",
            "1",
            "--out",
            str(out),
        ]
    )
    result = json.loads((out / "aits.json").read_text(encoding="utf-8"))
    rows = {(row["series"], row["batch"], row["frames"]): row for row in result["aits"]}
    md = ("motiondiffuse (50 steps)", "motiondiffuse (10 steps)")
    m2 = ("m2d2m (8 steps)", "m2d2m (2 steps)")
    # M2D2M at --batches and MotionDiffuse at --md-batches, once per number of steps (most first)
    assert set(rows) == (
        {(m, b, f) for m in ("mmm", *m2) for b in (1, 2) for f in (8, 16)} | {(m, 1, f) for m in md for f in (8, 16)}
    )
    assert list(dict.fromkeys(row["series"] for row in result["aits"])) == ["mmm", *m2, *md]
    for (series, batch, _), row in rows.items():
        assert row["model"] == series.split(" ")[0]
        assert len(row["times"]) == 2 and all(t > 0 for t in row["times"])
        assert row["aits"] == pytest.approx(statistics.median(row["times"]) / batch)
        assert row["spread"][0] <= row["aits"] <= row["spread"][1]
    # MMM's T_dyn grows with the length, M2D2M and MotionDiffuse take the steps they are given
    # whatever the length (all T = 8 of the tiny denoiser, or 2)
    assert rows[("mmm", 1, 8)]["passes"] <= rows[("mmm", 1, 16)]["passes"] <= 10
    assert [rows[(m, 1, f)]["passes"] for m in m2 for f in (8, 16)] == [8, 8, 2, 2]
    assert [rows[(m, 1, f)]["passes"] for m in md for f in (8, 16)] == [50, 50, 10, 10]

    long = result["long"]
    assert long["frames"] == [20, 20, 20] and long["actions"] == 3 and long["minutes"] == pytest.approx(0.05)
    assert long["methods"] == {"mmm": "transition", "m2d2m": "tps", "motiondiffuse": "time-varied"}
    assert {name: len(times) for name, times in long["times"].items()} == {"mmm": 1, "m2d2m": 1, "motiondiffuse": 1}
    assert long["ratio"] == pytest.approx(long["median"]["m2d2m"] / long["median"]["mmm"])
    assert long["ratios"]["motiondiffuse"] == pytest.approx(long["median"]["motiondiffuse"] / long["median"]["mmm"])
    assert long["motiondiffuse"]["steps"] == 5 and long["motiondiffuse"]["trained_steps"] == 50
    assert long["motiondiffuse"]["extrapolated"] == pytest.approx(10 * long["median"]["motiondiffuse"])
    assert set(result["models"]) == {"mmm", "m2d2m", "motiondiffuse"}
    assert all(m["parameters"] for m in result["models"].values())
    assert set(result["models"]["motiondiffuse"]["parameters"]) == {"network", "text_encoder"}  # no codec
    assert result["models"]["motiondiffuse"]["long"].startswith("5 of T = 50 steps")
    assert result["models"]["m2d2m"]["long"].endswith("4 of 8 steps")
    assert result["machine"]["torch_threads"] == 1
    assert (out / "aits.png").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "AITS, 2 sentence(s) per call" in printed and "| mmm | transition |" in printed
    assert "| motiondiffuse | time-varied, 5 of T = 50 steps |" in printed
    assert "motiondiffuse (10 steps) / mmm" in printed and "m2d2m (2 steps) / mmm" in printed
    assert "Fewer steps: 50 → 10 (5.0× fewer) makes motiondiffuse's call" in printed
    assert "Fewer steps: 8 → 2 (4.0× fewer) makes m2d2m's call" in printed


def test_steps_motiondiffuse_was_not_trained_with_are_refused(three_models):
    with pytest.raises(SystemExit, match="trained with T = 50 steps"):
        main(
            [
                "--dataset",
                "tiny",
                "--lengths",
                "8",
                "--action-frames",
                "24",
                "--m2d2m-steps",
                "8",
                "--md-steps",
                "1000",
                "100",
                "--out",
                str(three_models / "refused"),
            ]
        )
    assert not (three_models / "refused").exists()


def test_steps_m2d2m_was_not_trained_with_are_refused(three_models):
    with pytest.raises(SystemExit, match="m2d2m was trained with T = 8 steps; give --m2d2m-steps"):
        main(
            [
                "--dataset",
                "tiny",
                "--lengths",
                "8",
                "--action-frames",
                "24",
                "--m2d2m-steps",
                "100",
                "--md-steps",
                "5",
                "--out",
                str(three_models / "refused"),
            ]
        )
    assert not (three_models / "refused").exists()


def test_a_missing_model_is_one_line_naming_how_to_train_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stopped:
        main(["--out", str(tmp_path / "out")])
    message = str(stopped.value)
    assert "make train-mmm" in message and "make train-diffusion" in message and "\n" not in message
    assert "make train-motiondiffuse" in message
    assert not (tmp_path / "out").exists()
