"""A second process that samples M2D2M compiled does not compile again (issue 54 §3): PyTorch's
on-disk caches (inductor's FX graph cache, AOTAutograd's cache) hand it the first process's
kernels, so only tracing is left (docs/generation.md, "Compiled sampling")."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow  # two processes, the first compiling for about a minute on two cores

SAMPLE = """
import json, sys, torch
from torch._dynamo.utils import counters
from m2d2m.generators.options import MULTI
from orchestration.registry import model
generator = model("m2d2m").load("generator").load(sys.argv[1], torch.device("cpu"))
options = generator.options(MULTI, compile="on", steps=2)
generator.generate([["a person walks forward", "a person jumps"]], [[40, 40]], options, [0])
print(json.dumps({"inductor": dict(counters["inductor"]), "aot_autograd": dict(counters["aot_autograd"])}))
"""


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    """M2D2M's demo config with random weights, written by its recipe (bench/gpu.py's build)."""
    sys.path.insert(0, str(ROOT / "bench"))
    import gpu

    out = tmp_path_factory.mktemp("compile-cache")
    built = gpu.build("m2d2m", "demo", out, gpu.random_clip(out / "clip"))
    return built.save(out / "m2d2m.pt")


def test_a_second_process_takes_the_compiled_kernels_from_the_first(model_file, tmp_path):
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "inductor"), "PYTHONPATH": str(ROOT)}

    def sample() -> dict:
        answer = subprocess.run(
            [sys.executable, "-c", SAMPLE, str(model_file)], env=env, capture_output=True, text=True, check=True
        )
        return json.loads(answer.stdout.strip().splitlines()[-1])

    first, second = sample(), sample()
    assert first["inductor"].get("fxgraph_cache_miss", 0) >= 1 and not first["inductor"].get("fxgraph_cache_hit")
    assert second["inductor"].get("fxgraph_cache_hit", 0) == first["inductor"]["fxgraph_cache_miss"]
    assert not second["inductor"].get("fxgraph_cache_miss")
