"""bench/attention.py at toy size: what it measures and writes, not how fast."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # bench scripts import `timing` beside them
from bench.attention import Size, main, matrix_bytes, settings_of  # noqa: E402


def test_softmax_state_grows_as_the_square_of_the_length_and_linear_state_not_at_all():
    size = Size()  # the paper's: 8 heads of 64
    assert matrix_bytes("softmax", 98, size) == 8 * 98 * 98 * 4
    assert matrix_bytes("softmax", 3136, size) == 32**2 * matrix_bytes("softmax", 98, size)
    assert matrix_bytes("linear", 98, size) == matrix_bytes("linear", 3136, size) == 8 * 64 * 64 * 4


def test_the_whole_network_can_be_capped_but_the_attention_call_reaches_the_longest():
    args = type("Args", (), {"lengths_actions": [1, 2, 4], "action_frames": 10, "network_max_actions": 2})()
    settings = settings_of(args)
    assert {(s.scope, s.frames) for s in settings if s.kind == "softmax"} == {
        ("attention", 10),
        ("attention", 20),
        ("attention", 40),
        ("network", 10),
        ("network", 20),
    }


@pytest.mark.slow
def test_times_and_memory_of_both_kinds_at_every_length(tmp_path, capsys):
    out = tmp_path / "attention"
    main(
        [
            "--width",
            "16",
            "--heads",
            "2",
            "--layers",
            "1",
            "--text-dim",
            "8",
            "--text-layers",
            "1",
            "--lengths-actions",
            "1",
            "2",
            "4",
            "--action-frames",
            "8",
            "--warmup",
            "0",
            "--repeats",
            "1",
            "--threads",
            "1",
            "--out",
            str(out),
        ]
    )
    result = json.loads((out / "attention.json").read_text(encoding="utf-8"))
    rows = {(row["scope"], row["kind"], row["frames"]): row for row in result["rows"]}
    assert set(rows) == {
        (scope, kind, frames)
        for scope in ("attention", "network")
        for kind in ("linear", "softmax")
        for frames in (8, 16, 32)
    }
    for (_, _, frames), row in rows.items():
        assert row["actions"] * 8 == frames
        assert len(row["times"]) == 1 and row["median"] > 0 and row["spread"] == [row["median"]] * 2
        assert row["rss_before"] > 0 and row["rss_growth"] >= 0
    for scope in ("attention", "network"):
        softmax = [rows[(scope, "softmax", frames)]["matrix_bytes"] for frames in (8, 16, 32)]
        assert softmax[1] == 4 * softmax[0] and softmax[2] == 4 * softmax[1] == 2 * 32 * 32 * 4  # 2 heads
        assert len({rows[(scope, "linear", frames)]["matrix_bytes"] for frames in (8, 16, 32)}) == 1
    assert result["size"]["width"] == 16 and result["size"]["parameters"] > 0
    assert result["machine"]["torch_threads"] == 1
    assert (out / "attention.png").stat().st_size > 0
    printed = capsys.readouterr().out
    assert "One attention call" in printed and "One forward pass of the whole network" in printed
    assert "| 4 | 32 |" in printed


def test_sizes_the_network_cannot_take_are_refused(tmp_path):
    with pytest.raises(SystemExit):
        main(["--width", "10", "--heads", "3", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()
