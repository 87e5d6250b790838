"""The numeric precision sampling runs in: bf16 autocast on a GPU that has it, float32 elsewhere.

A sampler's cost is its network's matrix products, repeated over every step; under autocast they
run in bfloat16 on the tensor cores while the arithmetic that needs range or exactness stays in
float32 or float64 (softmax, the posteriors, the VQ-VAE's codec and quantizer, which opt out). On
a CPU bf16 is slower than float32, so ``auto`` keeps float32 there. ``M2D2M_PRECISION`` chooses
for every command at once (``fp32`` to sample a GPU model as a CPU would); the evaluator always
measures in float32, so metrics stay comparable between machines (docs/generation.md, "Precision").
PyTorch's "Automatic Mixed Precision" notes list what autocast runs in which dtype.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import torch

PRECISIONS = ("auto", "bf16", "fp32")
ENVIRONMENT = "M2D2M_PRECISION"


def resolve(precision: str | None, device: torch.device | str) -> str:
    """``bf16`` or ``fp32`` for ``precision`` on ``device``; None reads ``M2D2M_PRECISION``
    (``auto`` when unset): ``auto`` is bf16 on a CUDA device that supports it, else fp32."""
    precision = precision or os.environ.get(ENVIRONMENT) or "auto"
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r} ({ENVIRONMENT})")
    if precision != "auto":
        return precision
    return "bf16" if fast_bf16(device) else "fp32"


def fast_bf16(device: torch.device | str) -> bool:
    """Whether ``device`` runs bfloat16 on its own hardware: a CUDA device that supports it (a CPU
    without AVX-512 emulates it, slower than float32). Training's ``precision: auto`` asks the same."""
    return torch.device(device).type == "cuda" and torch.cuda.is_bf16_supported()


@contextlib.contextmanager
def autocast(precision: str, device: torch.device | str) -> Iterator[None]:
    """The autocast context of a resolved ``precision`` on ``device`` (a no-op for fp32).

    Under a CPU's bf16 it also turns off the inference fast path of ``nn.TransformerEncoder``,
    which asks ``torch.is_autocast_enabled()`` about CUDA only and so fails on a CPU's bfloat16
    (torch/nn/modules/transformer.py, ``TransformerEncoderLayer.forward``); on a GPU autocast
    already turns it off."""
    device = torch.device(device)
    bf16 = precision == "bf16"
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16), contextlib.ExitStack() as stack:
        if bf16 and device.type == "cpu" and torch.backends.mha.get_fastpath_enabled():
            torch.backends.mha.set_fastpath_enabled(False)
            stack.callback(torch.backends.mha.set_fastpath_enabled, True)
        yield


def full_precision(device: torch.device | str) -> contextlib.AbstractContextManager:
    """Autocast switched off inside a bf16 block: code whose numbers must be float32 (a codec)."""
    return torch.autocast(torch.device(device).type, enabled=False)
