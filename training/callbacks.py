"""Callbacks shared by the training stages: pictures of progress logged to MLflow, a progress bar
that counts the steps training is bounded by, and snapshots of the weights at chosen steps."""

from __future__ import annotations

import json
import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
from lightning.pytorch.callbacks import RichProgressBar
from lightning.pytorch.loggers import MLFlowLogger

from m2d2m.atomic import atomic_path
from m2d2m.generators.token_model import TokenCodec
from m2d2m.motion.files.render import render_comparison, render_motion
from m2d2m.motion.representation.features import features_to_joints
from m2d2m.motion.representation.skeleton import SKELETONS, Skeleton
from m2d2m.networks.vqvae import load_vq
from m2d2m.progress import ProgressLines
from training.losses import is_logging_step


class Drawing(pl.Callback):
    """Previews drawn off the training path: a GIF is drawn by Matplotlib in a process of its own
    (started at the first, spawned so that it shares nothing with CUDA or the loader's threads)
    while training goes on, and logged to MLflow once drawn — at the next validation, or at the
    end of training, which waits for the last (docs/training.md, "Previews off the step path").
    Drawn in the training process, four GIFs held a demo-size GPU run for seconds at every
    preview, longer than a hundred of its steps."""

    artifact_path = "previews"

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._drawing: list[Future[Path]] = []

    def draw(self, function: Callable[..., Path], *args: Any, **kwargs: Any) -> None:
        """Have ``function(*args, **kwargs)`` (a picture writer, returning its path) run in the
        drawing process."""
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
        self._drawing.append(self._pool.submit(function, *args, **kwargs))

    def _log_drawn(self, trainer: pl.Trainer, wait: bool) -> None:
        """Log the pictures drawn so far (all of them, waiting, when ``wait``)."""
        pending = []
        for future in self._drawing:
            if not (wait or future.done()):
                pending.append(future)
                continue
            path = future.result()  # a drawing that failed fails training here, as it did drawn in place
            if isinstance(trainer.logger, MLFlowLogger):
                trainer.logger.experiment.log_artifact(
                    trainer.logger.run_id, str(path), artifact_path=self.artifact_path
                )
        self._drawing = pending

    def _close(self, cancel: bool) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=not cancel, cancel_futures=cancel)
            self._pool = None

    def on_validation_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self._log_drawn(trainer, wait=False)

    def on_train_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        try:
            self._log_drawn(trainer, wait=True)
        finally:
            self._close(cancel=False)

    def on_exception(self, trainer: pl.Trainer, module: pl.LightningModule, exception: BaseException) -> None:
        self._drawing = []
        self._close(cancel=True)


class ReconstructionPreview(Drawing):
    """Every ``every`` validations, a GIF of the first validation clip: ground truth beside the
    model's reconstruction, written under ``directory`` and logged as an MLflow artifact."""

    def __init__(self, directory: str | Path, every: int = 1) -> None:
        super().__init__()
        self.directory = Path(directory)
        self.every = max(1, every)
        self.validations = 0

    def on_validation_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        super().on_validation_epoch_end(trainer, module)
        if trainer.sanity_checking or not trainer.is_global_zero or module.preview is None:
            return
        self.validations += 1
        if (self.validations - 1) % self.every:
            return
        truth, reconstruction = module.preview
        self.draw(
            render_comparison,
            [truth, reconstruction],
            ["ground truth", "reconstruction"],
            self.directory / f"step-{trainer.global_step:07d}.gif",
            skeleton=module.skeleton,
            size=240,
        )


class SamplePreview(Drawing):
    """Every ``every`` validations, one GIF per fixed prompt of the module's samples, drawn and
    logged as MLflow artifacts: what a person looks at to judge whether samples follow their
    text. Subclasses say how a model's samples become features (:meth:`_sample`); the samples are
    drawn in the training process, the GIFs in the drawing one."""

    artifact_path = "samples"

    def __init__(
        self, directory: str | Path, prompts: list[str], seconds: list[float], every: int = 1, seed: int = 0
    ) -> None:
        super().__init__()
        if len(prompts) != len(seconds):
            raise ValueError("give one duration in seconds per preview prompt")
        self.directory = Path(directory)
        self.prompts, self.seconds = prompts, seconds
        self.every, self.seed = max(1, every), seed
        self.validations = 0

    def _sample(self, module: pl.LightningModule) -> tuple[list[np.ndarray], Skeleton]:
        """Un-normalised features (F, D) for each prompt, and their skeleton."""
        raise NotImplementedError

    def on_validation_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        super().on_validation_epoch_end(trainer, module)
        if trainer.sanity_checking or not trainer.is_global_zero:
            return
        self.validations += 1
        if (self.validations - 1) % self.every:
            return
        samples, skeleton = self._sample(module)
        for n, (prompt, features) in enumerate(zip(self.prompts, samples)):
            self.draw(
                render_motion,
                features_to_joints(features, skeleton),
                self.directory / f"step-{trainer.global_step:07d}-{n}.gif",
                skeleton=skeleton,
                title=prompt,
                size=240,
            )


class TokenSamplePreview(SamplePreview):
    """Previews of a model over VQ tokens (M2D2M, MMM): tokens from the module's
    ``preview_tokens(prompts, lengths, seed, **knobs)``, decoded by the VQ-VAE of ``vq_file``."""

    def __init__(
        self,
        directory: str | Path,
        vq_file: str | Path,
        prompts: list[str],
        seconds: list[float],
        every: int = 1,
        seed: int = 0,
        **knobs: Any,
    ) -> None:
        super().__init__(directory, prompts, seconds, every, seed)
        self.vq_file, self.knobs = Path(vq_file), knobs

    def _sample(self, module: pl.LightningModule) -> tuple[list[np.ndarray], Skeleton]:
        vq, normalizer, meta = load_vq(self.vq_file)
        codec = TokenCodec(vq, normalizer, SKELETONS[meta["skeleton"]])
        lengths = [max(1, round(s * codec.skeleton.fps / vq.frames_per_token)) for s in self.seconds]
        sampled = module.preview_tokens(self.prompts, lengths, self.seed, **self.knobs)
        return [codec.decode(tokens) for tokens in sampled], codec.skeleton


class FeatureSamplePreview(SamplePreview):
    """Previews of a model on features (MotionDiffuse): the module's ``preview(prompts, frames,
    seed)`` gives the features themselves."""

    def __init__(
        self,
        directory: str | Path,
        skeleton: Skeleton,
        prompts: list[str],
        seconds: list[float],
        every: int = 1,
        seed: int = 0,
    ) -> None:
        super().__init__(directory, prompts, seconds, every, seed)
        self.skeleton = skeleton

    def _sample(self, module: pl.LightningModule) -> tuple[list[np.ndarray], Skeleton]:
        frames = [max(1, round(s * self.skeleton.fps)) for s in self.seconds]
        return module.preview(self.prompts, frames, self.seed), self.skeleton


class LoggedLoss:
    """The training loss as of the last step Lightning logged, for a progress display. Read only at
    those steps (:func:`training.losses.is_logging_step`, every ``log_every_n_steps``), where
    Lightning reads its metrics to the host anyway: on a GPU, reading it every step would make the
    host wait for each step to finish before queuing the next."""

    def __init__(self) -> None:
        self.value: float | None = None

    def update(self, trainer: pl.Trainer) -> None:
        loss = trainer.callback_metrics.get("train/loss") if is_logging_step(trainer) else None
        if loss is not None:
            self.value = float(loss)


class StepProgressBar(RichProgressBar):
    """Lightning's rich progress bar labelled with the steps each stretch covers ("Steps 1–500 of
    2000"), showing the training loss as last logged (:class:`LoggedLoss`). Training here is
    bounded by ``max_steps`` with ``max_epochs=-1``, which Lightning's own label prints as "Epoch
    0/-2" (``RichProgressBar._get_train_description``: ``max_epochs - 1``), and an epoch is only
    the stretch between validations (orchestration/train.py, ``validation_interval``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.loss = LoggedLoss()

    def on_train_batch_end(
        self, trainer: pl.Trainer, module: pl.LightningModule, outputs: Any, batch: Any, batch_idx: int
    ) -> None:
        self.loss.update(trainer)
        super().on_train_batch_end(trainer, module, outputs, batch, batch_idx)

    def get_metrics(self, trainer: pl.Trainer, module: pl.LightningModule) -> dict[str, Any]:
        metrics = super().get_metrics(trainer, module)
        return metrics if self.loss.value is None else {**metrics, "train/loss": self.loss.value}

    def _get_train_description(self, current_epoch: int) -> str:
        trainer = self.trainer
        if trainer.max_epochs != -1 or trainer.max_steps <= 0:
            return super()._get_train_description(current_epoch)
        first = trainer.global_step + 1
        last = int(min(trainer.global_step + self.total_train_batches, trainer.max_steps))
        description = f"{f'Step {last}' if first == last else f'Steps {first}–{last}'} of {trainer.max_steps}"
        return f"{description:{len(self.validation_description)}}"  # as Lightning pads it, against flicker


class PlainProgress(pl.Callback):
    """Training progress as plain lines where there is no terminal for a bar (a log file, CI, a
    cluster job): step of max_steps, the loss as last logged (:class:`LoggedLoss`), steps per
    second and time left, at each tenth of the run and at least every 30 s
    (:class:`m2d2m.progress.ProgressLines`); rank 0 only."""

    def __init__(self, file: Any = None) -> None:
        self.file = file
        self.lines: ProgressLines | None = None
        self.loss = LoggedLoss()

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if trainer.is_global_zero:
            total = trainer.max_steps if trainer.max_steps > 0 else None
            self.lines = ProgressLines(
                total=total, desc="training", unit="step", file=self.file, initial=trainer.global_step
            )

    def on_train_batch_end(self, trainer: pl.Trainer, module: pl.LightningModule, *args: Any) -> None:
        if self.lines is None:
            return
        self.loss.update(trainer)
        self.lines.set_postfix_str(f"loss {self.loss.value:.4g}" if self.loss.value is not None else "")
        self.lines.update(trainer.global_step - self.lines.n)

    def on_train_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if self.lines is not None:
            self.lines.close()


class StepSnapshots(pl.Callback):
    """The weights after each of ``steps`` training steps, as ``<directory>/step-<N>.ckpt``, and the
    training seconds it took to reach them (``seconds.json``): the points of a learning curve
    (bench/learning_curves.py) from one run. Seconds are wall-clock from the start of training; a
    resumed run continues from the last snapshot's count (the time after it until the stop is
    lost)."""

    SECONDS = "seconds.json"

    def __init__(self, directory: str | Path, steps: list[int]) -> None:
        self.directory = Path(directory)
        self.steps = set(steps)
        self._start = 0.0
        self._offset = 0.0

    @classmethod
    def recorded(cls, directory: str | Path) -> dict[str, float]:
        """The seconds of the snapshots a run in ``directory`` has taken so far, by step ("500": s)."""
        path = Path(directory) / cls.SECONDS
        return json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self._start = time.perf_counter()
        self._offset = max(self.recorded(self.directory).values(), default=0.0)

    def on_train_batch_end(self, trainer: pl.Trainer, module: pl.LightningModule, *args: Any) -> None:
        step = trainer.global_step
        if step not in self.steps:
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        # every rank takes part (Lightning writes on rank 0); a snapshot counts once its seconds are recorded.
        # A whole checkpoint, so that a weight average (trainer.ema) puts its weights in the state dict.
        trainer.save_checkpoint(self.directory / f"step-{step}.ckpt")
        if not trainer.is_global_zero:
            return
        seconds = {**self.recorded(self.directory), str(step): self._offset + time.perf_counter() - self._start}
        with atomic_path(self.directory / self.SECONDS) as path:
            path.write_text(json.dumps(seconds, indent=1), encoding="utf-8")
