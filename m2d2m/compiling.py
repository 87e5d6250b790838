"""``torch.compile`` for the passes that launch many small kernels: a sampler's denoiser pass and a
training step's forward, loss and backward (docs/generation.md, "Compiled sampling";
docs/training.md, "Compiled training steps").

On a GPU such a pass is bound by launching its kernels, not by their arithmetic. ``torch.compile``
fuses them and, on CUDA with ``mode="reduce-overhead"``, replays the whole pass as CUDA graphs
(PyTorch's "torch.compile" and "CUDAGraph Trees" documentation), which want few shapes: the
callers pad their sequences to a :func:`bucket`. Where compiling is impossible — no C++ compiler
or Triton, a Python or an operator that ``torch.compile`` does not support — :class:`Compiled`
says so in one logged line and runs eagerly from then on; any other error is the caller's and is
raised as it is.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Generic, TypeVar

import torch
import torch._dynamo.exc
import torch._inductor.exc

LOG = logging.getLogger(__name__)

# what a pass that cannot be compiled raises at its first call: every dynamo and inductor failure
# (BackendCompilerFailed, InductorError, Unsupported, TritonMissing, GPUTooOldForTriton are
# TorchDynamoExceptions) and the C++ toolchain's own (a missing or broken compiler)
COMPILE_FAILURES: tuple[type[Exception], ...] = (
    torch._dynamo.exc.TorchDynamoException,
    torch._inductor.exc.InvalidCxxCompiler,
    torch._inductor.exc.CppCompileError,
)

Result = TypeVar("Result")


def compiles(choice: str, device: torch.device) -> bool:
    """Whether the ``compile`` option ``choice`` (off, auto, on: :data:`m2d2m.generators.options.COMPILE`)
    compiles on ``device``."""
    return choice == "on" or (choice == "auto" and device.type == "cuda")


def bucket(size: int, smallest: int = 1) -> int:
    """The padded size of ``size``: the least 2^k or 3·2^(k−1) (1, 2, 3, 4, 6, 8, 12, 16, 24, …) at
    or above it and at least ``smallest``, so padding stays under a half of a pass and the number of
    shapes grows with the logarithm of the largest."""
    size = max(size, smallest, 1)
    power = 1 << (size - 1).bit_length()  # the least power of two >= size
    return 3 * power // 4 if power >= 4 and 3 * power // 4 >= size else power


def pad_to_bucket(tensor: torch.Tensor, dim: int, smallest: int = 8) -> torch.Tensor:
    """``tensor`` padded with zeros (False) at the end of ``dim`` to :func:`bucket` of its size."""
    extra = bucket(tensor.shape[dim], smallest) - tensor.shape[dim]
    if extra == 0:
        return tensor
    widths = [0, 0] * (tensor.dim() - 1 - dim) + [0, extra]
    return torch.nn.functional.pad(tensor, widths)


class Compiled(Generic[Result]):
    """``function`` through ``torch.compile``, or eagerly once compiling it has failed.

    ``what`` names it in the logged line. ``dynamic`` is torch.compile's: False compiles each
    shape once (the sampler's few buckets); None compiles the first shape statically and, at the
    first other, once more with the varying sizes symbolic (a training step's batches). On CUDA the
    passes are captured as CUDA graphs, so each call marks a new step: a captured pass may reuse
    the memory of the previous call's outputs, which the caller has used by then."""

    def __init__(self, function: Callable[..., Result], what: str, cuda: bool, dynamic: bool | None = False) -> None:
        self.function, self.what, self.cuda = function, what, cuda
        self._compiled: Callable[..., Result] | None = torch.compile(
            function, dynamic=dynamic, mode="reduce-overhead" if cuda else None
        )

    @property
    def compiled(self) -> bool:
        """False once compiling has failed and ``function`` runs eagerly."""
        return self._compiled is not None

    def __call__(self, *args: object) -> Result:
        if self._compiled is not None:
            try:
                if self.cuda:
                    torch.compiler.cudagraph_mark_step_begin()
                return self._compiled(*args)
            except COMPILE_FAILURES as error:  # a missing compiler or backend shows only at the first call
                self._compiled = None
                LOG.warning("torch.compile failed (%s: %s); %s runs eagerly", type(error).__name__, error, self.what)
        return self.function(*args)
