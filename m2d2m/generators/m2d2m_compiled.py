"""M2D2M's denoiser compiled for sampling (the ``compile`` option; docs/generation.md, "Compiled
sampling").

A reverse step is a dozen transformer blocks of small kernels. On a GPU at a small batch the step is
bound by launching those kernels, not by their arithmetic (at paper size a step cost about 16 ms
for 49 tokens as for 784). ``torch.compile`` fuses them and, on CUDA with
``mode="reduce-overhead"``, replays the whole pass as CUDA graphs (PyTorch's "torch.compile" and
"CUDAGraph Trees" documentation). Both want static shapes, so the sampler pads each forward pass to
a bucket (:func:`bucket`): a few sizes, each compiled once per process. Padding changes nothing at
the real positions — padded tokens and text tokens are masked keys, padded rows are dropped
(the denoiser's padding invariance, tests/test_denoiser.py) — but the kernels of another shape
may round differently, so compiled logits equal eager ones to float32 rounding, not bit for bit.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import torch

from m2d2m.networks.m2d2m_denoiser import MotionDenoiser

LOG = logging.getLogger(__name__)


def bucket(size: int, smallest: int = 1) -> int:
    """The padded size of ``size``: the least 2^k or 3·2^(k−1) (1, 2, 3, 4, 6, 8, 12, 16, 24, …) at
    or above it and at least ``smallest``, so padding stays under a half of a pass and the number of
    shapes grows with the logarithm of the largest."""
    size = max(size, smallest, 1)
    power = 1 << (size - 1).bit_length()  # the least power of two >= size
    return 3 * power // 4 if power >= 4 and 3 * power // 4 >= size else power


def compiles(choice: str, device: torch.device) -> bool:
    """Whether the ``compile`` option ``choice`` (off, auto, on) compiles on ``device``."""
    return choice == "on" or (choice == "auto" and device.type == "cuda")


class CompiledDenoise:
    """:meth:`MotionDenoiser.denoise` through ``torch.compile`` with static shapes (the caller pads
    them to buckets). Where compiling fails — no C++ compiler or Triton, an unsupported Python — it
    says so in one logged line and runs eagerly from then on; it never raises for that."""

    def __init__(self, denoiser: MotionDenoiser) -> None:
        self.denoiser = denoiser
        self.cuda = next(denoiser.parameters()).device.type == "cuda"
        self._compiled: Callable[..., torch.Tensor] | None = torch.compile(
            denoiser.denoise, dynamic=False, mode="reduce-overhead" if self.cuda else None
        )

    @property
    def compiled(self) -> bool:
        """False once compiling has failed and the denoiser runs eagerly."""
        return self._compiled is not None

    def __call__(self, *args: object) -> torch.Tensor:
        if self._compiled is not None:
            try:
                if self.cuda:  # a new step: the graphs may reuse the previous outputs' memory
                    torch.compiler.cudagraph_mark_step_begin()
                return self._compiled(*args)
            except Exception as error:  # a missing compiler or backend shows only at the first call
                self._compiled = None
                LOG.warning("torch.compile failed (%s: %s); the denoiser runs eagerly", type(error).__name__, error)
        return self.denoiser.denoise(*args)
