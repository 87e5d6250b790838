"""m2d2m.compiling: the eager fallback is taken on the failures of compiling, and on nothing else."""

from __future__ import annotations

import pytest
import torch
from torch._dynamo.exc import BackendCompilerFailed
from torch._inductor.exc import CppCompileError

from m2d2m.compiling import Compiled


def _with_compile(monkeypatch, failure: Exception):
    def compile_(function, **options):
        def run(*args):
            raise failure

        return run

    monkeypatch.setattr(torch, "compile", compile_)


@pytest.mark.parametrize(
    "failure",
    [
        CppCompileError(["g++"], "fatal error: Python.h: No such file"),
        BackendCompilerFailed(print, ValueError("x"), None),
    ],
)
def test_a_failure_of_compiling_runs_eagerly_from_then_on_with_one_logged_line(monkeypatch, caplog, failure):
    _with_compile(monkeypatch, failure)
    calls = []
    double = Compiled(lambda x: calls.append(x) or 2 * x, "the doubler", cuda=False)
    with caplog.at_level("WARNING", logger="m2d2m.compiling"):
        assert double(torch.tensor(3)) == 6 and double(torch.tensor(4)) == 8
    assert not double.compiled and len(calls) == 2
    (record,) = caplog.records
    assert record.getMessage().startswith(f"torch.compile failed ({type(failure).__name__}: ")
    assert record.getMessage().endswith("; the doubler runs eagerly")


def test_any_other_error_is_the_callers_and_raised(monkeypatch, caplog):
    """A shape mismatch inside the compiled pass is a bug to see, not a reason to run eagerly."""
    _with_compile(monkeypatch, RuntimeError("mat1 and mat2 shapes cannot be multiplied"))
    double = Compiled(lambda x: 2 * x, "the doubler", cuda=False)
    with pytest.raises(RuntimeError, match="shapes cannot be multiplied"):
        double(torch.tensor(3))
    assert double.compiled and not caplog.records
