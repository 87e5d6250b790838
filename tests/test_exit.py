"""A command ends with its last line (issue 54 §2): the console script freezes the process's
objects out of the garbage collector's last passes, and a local Ray started to tokenize before
training is shut down once the tokens are made (BENCHMARKS.md, "From the last line to the exit")."""

from __future__ import annotations

import gc
import tomllib
from pathlib import Path

import pytest

import pipelines.token_sets as token_sets
import pipelines.tokenize as tokenize
from orchestration import cli

ROOT = Path(__file__).resolve().parents[1]


def test_the_console_script_freezes_the_heap_after_the_verb(monkeypatch):
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]
    assert scripts["m2d2m"] == "orchestration.cli:command"
    calls = []
    monkeypatch.setattr(cli, "main", lambda: calls.append("main") or 3)
    monkeypatch.setattr(gc, "freeze", lambda: calls.append("freeze"))
    assert cli.command() == 3 and calls == ["main", "freeze"]


@pytest.mark.parametrize("running", [False, True], ids=["started-here", "a-sweeps"])
def test_a_ray_started_to_tokenize_is_shut_down_after_it_and_a_running_one_kept(monkeypatch, tmp_path, running):
    import ray

    shutdowns = []
    monkeypatch.setattr(token_sets, "token_set", lambda vq, extra=None: (tmp_path / "data", tmp_path / "tokens"))
    monkeypatch.setattr(tokenize, "current_tokens", lambda *args: None)
    monkeypatch.setattr(tokenize, "tokenize_dataset", lambda *args: None)
    monkeypatch.setattr(ray, "is_initialized", lambda: running)
    monkeypatch.setattr(ray, "shutdown", lambda: shutdowns.append(True))
    assert token_sets.ensure_tokens(tmp_path / "vq.pt", extra={}) == (tmp_path / "data", tmp_path / "tokens")
    assert shutdowns == ([] if running else [True])
