"""What every LightningModule here shares about how its training step runs on the device
(docs/training.md, "Compiled training steps"):

- with ``trainer.compile`` (off, auto, on), the step's forward and loss — and so, through
  AOTAutograd, its backward — run through ``torch.compile`` (:mod:`m2d2m.compiling`), on CUDA as
  CUDA graphs: at paper size the eager step is bound by launching its thousands of small kernels,
  not by their arithmetic;
- AdamW runs fused, one kernel over every parameter instead of a dozen per tensor, wherever no
  gradient scaler has to unscale the gradients before they are clipped (fp16 mixed precision);
- gradients are clipped by their global norm on the device, without a host read.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import torch

from m2d2m.compiling import Compiled, compiles
from training.losses import FiniteLossGuard

Result = TypeVar("Result")
SCALED_PRECISION = "16-mixed"  # Lightning's precision whose GradScaler unscales before clipping


def _copied_out(run: Callable[..., Result]) -> Callable[..., Result]:
    """``run`` with its tensors copied out of the CUDA graphs' memory, which the next step's replay
    reuses ("CUDAGraph Trees" documentation): Lightning keeps a step's loss until it logs it. A
    loss and per-sample terms: nothing to speak of."""

    def call(*args: object) -> Result:
        out = run(*args)
        return tuple(x.clone() for x in out) if isinstance(out, tuple) else out.clone()

    return call


class TrainingModule(FiniteLossGuard):
    """A LightningModule whose training passes may run compiled and whose optimiser may be fused."""

    compile_steps: str = "off"  # trainer.compile of the run (orchestration.train.fit sets it)

    def compiles_steps(self) -> bool:
        """Whether a training step here runs compiled: when ``compile_steps`` asks for it on this
        device, and not in validation (no gradients: a graph of its own, for a pass that runs rarely)."""
        return self.training and torch.is_grad_enabled() and compiles(self.compile_steps, self.device)

    def compiled(self, function: Callable[..., Result]) -> Callable[..., Result]:
        """``function`` — a method of this module taking and returning tensors — as this run's
        training step runs it: compiled where :meth:`compiles_steps`, each method once for the
        module's life, eagerly otherwise."""
        if not self.compiles_steps():
            return function
        passes: dict[str, Compiled] = self.__dict__.setdefault("_compiled_passes", {})
        name = function.__name__
        if name not in passes:
            # dynamic=None: the first shape compiled as it is, the sizes that vary symbolic at the
            # first other (batches come in a few bucketed lengths)
            what = f"{type(self).__name__}.{name}"
            cuda = self.device.type == "cuda"
            compiled = Compiled(function, what, cuda=cuda, dynamic=None)
            passes[name] = _copied_out(compiled) if cuda else compiled
        return passes[name]

    def fuses_optimizer(self) -> bool:
        """Whether AdamW may run fused: on the CPU or CUDA, unless fp16 mixed precision's gradient
        scaler must unscale the gradients between backward and clipping, which a fused AdamW does
        only inside its own step."""
        trainer = self._trainer
        on_fused_devices = all(p.device.type in ("cpu", "cuda") for p in self.parameters())
        return on_fused_devices and (trainer is None or trainer.precision != SCALED_PRECISION)

    def configure_gradient_clipping(
        self,
        optimizer: torch.optim.Optimizer,
        gradient_clip_val: float | None = None,
        gradient_clip_algorithm: str | None = None,
    ) -> None:
        """Clip by the global norm as Lightning would (``Trainer(gradient_clip_val=…)``), but here:
        Lightning's mixed-precision plugin refuses to clip for a fused optimiser even under bf16,
        where no scaler is involved. ``clip_grad_norm_`` scales on the device, never reading the norm."""
        if not gradient_clip_val:
            return
        if gradient_clip_algorithm not in (None, "norm"):
            raise ValueError(f"only clipping by the global norm is supported, not {gradient_clip_algorithm!r}")
        parameters = [p for group in optimizer.param_groups for p in group["params"] if p.grad is not None]
        torch.nn.utils.clip_grad_norm_(parameters, gradient_clip_val, foreach=True)
