"""No training step and no sampling step of MMM, its upper-body editor, MotionDiffuse, the VQ-VAE
or the evaluator makes the device wait for the host (M2D2M's: tests/test_host_syncs.py).

A training step is counted from one ``on_train_batch_start`` of a Lightning Trainer set up as
orchestration/train.py's ``fit`` sets it up (gradient clipping, the learning-rate monitor, the
progress lines and bar, a logger) to the next: the optimiser step, the logging, the progress
display and the next batch's transfer are inside. Lightning reads its logged metrics at every
``log_every_n_steps``-th step only (as does the non-finite loss guard: training/losses.py), so the
counted steps fall between two of those. A sampling step is counted from one call of the network
to the next (the last to the end of the loop), so a call's setup before its first step is not.
"""

from __future__ import annotations

import contextlib
import inspect
import io
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import pytest
import torch
from lightning.pytorch.callbacks import LearningRateMonitor
from lightning.pytorch.loggers import CSVLogger
from torch.overrides import TorchFunctionMode

from m2d2m.evaluation.evaluator import BiGRUEncoder, TextMotionEvaluator, learned_vocabulary
from m2d2m.generators.mmm.generator import Row, decode_sentences
from m2d2m.generators.mmm.options import DecodingOptions
from m2d2m.generators.motiondiffuse.sampling import FeatureRequest, Term, sample
from m2d2m.generators.token_model import FREE
from m2d2m.motion.representation.body_parts import UPPER, part_mask
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.networks.mmm_body_transformer import BodyMaskedTransformer, BodyTransformerConfig, body_canvas
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig
from m2d2m.networks.motiondiffuse_transformer import MotionDiffuseConfig, MotionDiffuseTransformer
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion
from m2d2m.text import LearnedTextEncoder
from tests.helpers import TINY_EVALUATOR
from tests.host_syncs import PROJECT, FoundOps, host_syncs
from training.callbacks import PlainProgress, StepProgressBar
from training.evaluator_module import EvaluatorModule
from training.mmm_body_module import BodyMMMModule
from training.mmm_module import MMMModule
from training.motiondiffuse_module import MotionDiffuseModule
from training.vq_module import VQVAEModule

STEPS = 4
D = T2M.feature_dim
SENTENCES = ["a person walks forward", "a person jumps", "a person waves", "a person runs"]
VOCABULARY = LearnedTextEncoder.build_vocabulary(SENTENCES)
TEXT = {"kind": "learned", "dim": 16, "layers": 1, "heads": 2, "dropout": 0.0}
MASKED = {"width": 32, "heads": 4, "layers": 2, "cross_layers": 1, "ffn": 64, "dropout": 0.0, "max_tokens": 8}
OPTIM = {"lr": 1e-3, "warmup_steps": 2}


def text_encoder() -> LearnedTextEncoder:
    return LearnedTextEncoder(VOCABULARY, dim=16, layers=1, heads=2, dropout=0.0).eval()


# ------------------------------------------------------------------------------- training steps
def mmm() -> tuple[pl.LightningModule, dict[str, Any]]:
    module = MMMModule(MASKED, TEXT, {"alpha": 0.5}, OPTIM, torch.randn(12, 4), VOCABULARY, text_drop=0.5)
    tokens = torch.tensor([[1, 2, 3, 4, 5, 6], [7, 8, 9, 10, 0, 0]])
    return module, {"tokens": tokens, "padding_mask": tokens > 0, "text": SENTENCES[:2]}


def mmm_body() -> tuple[pl.LightningModule, dict[str, Any]]:
    module = BodyMMMModule(
        MASKED, TEXT, {"alpha": 0.5, "lower_most": 0.5}, OPTIM, torch.randn(12, 4), torch.randn(10, 4), VOCABULARY, 0.5
    )
    tokens = torch.tensor([[[1, 1], [2, 2], [3, 3], [4, 4]], [[7, 7], [8, 8], [0, 0], [0, 0]]])
    return module, {"tokens": tokens, "padding_mask": tokens[..., 0] > 0, "text": SENTENCES[:2]}


MOTIONDIFFUSE = {"width": 16, "layers": 1, "heads": 2, "ffn": 32, "text_width": 16, "text_layers": 1, "text_heads": 2}


def motiondiffuse() -> tuple[pl.LightningModule, dict[str, Any]]:
    network = {**MOTIONDIFFUSE, "text_ffn": 32, "max_frames": 32}
    module = MotionDiffuseModule(network, TEXT, {"steps": 40}, OPTIM, D, 0.5, VOCABULARY)
    batch = {"motion": torch.randn(4, 20, D), "lengths": torch.tensor([20, 12, 16, 8]), "text": SENTENCES}
    return module, batch


def vq(reset_every: int) -> Callable[[], tuple[pl.LightningModule, dict[str, Any]]]:
    def build() -> tuple[pl.LightningModule, dict[str, Any]]:
        model = {"width": 16, "depth": 1, "code_dim": 8, "codebook_size": 16, "reset_every": reset_every}
        module = VQVAEModule(model, OPTIM, {"recon": 1.0, "joint": 0.5, "commit": 0.02}, D, "t2m")
        return module, {"motion": torch.randn(4, 32, D)}

    return build


def evaluator() -> tuple[pl.LightningModule, dict[str, Any]]:
    tokens = [[f"{word}/NOUN" for word in sentence.split()] for sentence in SENTENCES]
    module = EvaluatorModule({**TINY_EVALUATOR, "dropout": 0.0}, OPTIM, {"margin": 10.0}, D, learned_vocabulary(tokens))
    batch = {"motion": torch.randn(4, 48, D), "lengths": torch.tensor([48, 40, 44, 48]), "tokens": tokens}
    return module, {**batch, "text": SENTENCES}


class BatchWindows(pl.Callback):
    """What ``watch`` (:func:`host_syncs` or :func:`float64_ops`) finds in each training batch, from
    its start to the next one's (the last one's to the end of its epoch), and in each validation
    batch, from its start to its end."""

    def __init__(self, watch: Callable[[], contextlib.AbstractContextManager[FoundOps]]) -> None:
        self.watch = watch
        self.training: list[FoundOps] = []
        self.validation: list[FoundOps] = []
        self._window = contextlib.ExitStack()

    def _open(self, into: list[FoundOps]) -> None:
        self._window.close()
        into.append(self._window.enter_context(self.watch()))

    def on_train_batch_start(self, trainer: pl.Trainer, module: pl.LightningModule, *args: Any) -> None:
        self._open(self.training)

    def on_train_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self._window.close()

    def on_validation_batch_start(self, trainer: pl.Trainer, module: pl.LightningModule, *args: Any) -> None:
        self._open(self.validation)

    def on_validation_batch_end(self, trainer: pl.Trainer, module: pl.LightningModule, *args: Any) -> None:
        self._window.close()


class FusedAdamW(pl.Callback):
    """Steps with torch's fused AdamW. Its for-loop and foreach implementations read each
    parameter's step count with ``.item()`` and keep those counts on the host unless fused or
    capturable (torch/optim/adam.py, ``_init_group``): on a GPU that read waits for nothing, on
    the CPU it looks like any other. The fused one keeps them beside the parameters and reads none."""

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        for optimizer in trainer.optimizers:
            for group in optimizer.param_groups:
                group["foreach"], group["fused"] = False, True


def run(
    build: Callable[[], tuple[pl.LightningModule, dict[str, Any]]],
    tmp_path,
    validate: bool,
    watch: Callable[[], contextlib.AbstractContextManager[FoundOps]] = host_syncs,
) -> BatchWindows:
    """Train the module of ``build`` for STEPS steps on copies of its batch (and, when ``validate``,
    validate it on two), watching every batch with ``watch`` (its host syncs by default)."""
    torch.manual_seed(0)
    module, batch = build()
    loader = torch.utils.data.DataLoader([batch] * (STEPS + 2), batch_size=None, collate_fn=lambda item: item)
    counted = BatchWindows(watch)
    shown = [LearningRateMonitor(logging_interval="step"), PlainProgress(io.StringIO()), StepProgressBar()]
    trainer = pl.Trainer(
        max_steps=STEPS,
        accelerator="cpu",
        devices=1,
        logger=CSVLogger(tmp_path),
        log_every_n_steps=50,
        gradient_clip_val=1.0,
        limit_val_batches=2,
        num_sanity_val_steps=0,
        enable_checkpointing=False,
        enable_model_summary=False,
        callbacks=[counted, FusedAdamW(), *shown],
    )
    trainer.fit(module, train_dataloaders=loader)
    if validate:
        trainer.validate(module, dataloaders=loader, verbose=False)
    return counted


def place_of(function: Callable, snippet: str) -> str:
    """file:line of the line of ``function``'s source that holds ``snippet``, as ``host_syncs`` names places."""
    lines, first = inspect.getsourcelines(function)
    number = next(first + index for index, line in enumerate(lines) if snippet in line)
    return f"{Path(inspect.getsourcefile(function)).relative_to(PROJECT)}:{number}"


# Reads of host data, which wait for nothing on a GPU but look like any other read on the CPU. The
# evaluator's module keeps the motions' lengths on the host (training/evaluator_module.py,
# ``transfer_batch_to_device``), where the evaluator checks them and its GRUs pack by them
# (``PackedSequence`` keeps its batch sizes on the host, and ``nn.GRU`` reads them there).
EVALUATOR_HOST_READS = {
    place_of(TextMotionEvaluator.embed_motion, "host >= UNIT_LENGTH"),
    place_of(BiGRUEncoder.forward, "self.gru("),
}


@pytest.mark.parametrize(
    ("build", "validate", "host_reads"),
    [
        (mmm, True, set()),
        (mmm_body, True, set()),
        (motiondiffuse, True, set()),
        (vq(1), False, set()),
        (vq(3), False, set()),
        (evaluator, True, EVALUATOR_HOST_READS),
    ],
    ids=["mmm", "mmm-body", "motiondiffuse", "vq", "vq-reset-every-3", "evaluator"],
)
def test_a_training_step_never_waits_for_the_device(build, validate, host_reads, tmp_path, one_torch_thread):
    """The VQ-VAE's quantizer reads its ``initialised`` flag once, at its first step (m2d2m/networks/
    vqvae.py, EMACodebook); its validation reconstructs clip by clip at each clip's own length, a
    host loop over the batch's lengths on purpose (training/vq_module.py), so it is left out."""
    counted = run(build, tmp_path, validate)
    assert len(counted.training) == STEPS and len(counted.validation) == (2 if validate else 0)
    first, *rest = counted.training
    assert all(place.startswith("m2d2m/networks/vqvae.py:") or place in host_reads for _, place in first.calls), (
        first.report()
    )
    for step in [*rest, *counted.validation]:
        assert all(place in host_reads for _, place in step.calls), step.report()


# ------------------------------------------------------------------------------- sampling steps
class HostBuiltTensors(TorchFunctionMode):
    """Tensors made from host data (Python numbers and lists, NumPy arrays) with ``torch.tensor``
    or ``torch.as_tensor``: on a GPU a step would copy each to the device, a copy from pageable
    memory that waits for the device's queue (CUDA runtime API, "API synchronization behavior"),
    which ``host_syncs`` cannot see on the CPU. Each call is recorded with its place, as
    ``host_syncs`` records its operations."""

    def __init__(self) -> None:
        super().__init__()
        self.places: list[str] = []

    def __torch_function__(self, func, types, args=(), kwargs=None):
        if func in (torch.tensor, torch.as_tensor) and args and not isinstance(args[0], torch.Tensor):
            frame = next(f for f in reversed(traceback.extract_stack()[:-1]) if "/torch/" not in f.filename)
            self.places.append(f"{frame.filename}:{frame.lineno}")
        return func(*args, **(kwargs or {}))


@contextlib.contextmanager
def per_call(network: torch.nn.Module) -> Iterator[list[tuple[FoundOps, HostBuiltTensors]]]:
    """The host syncs and host-built tensors of each call of ``network`` in the block, from the
    call to the next (the last to the end of the block)."""
    steps: list[tuple[FoundOps, HostBuiltTensors]] = []
    with contextlib.ExitStack() as block:
        window = block.enter_context(contextlib.ExitStack())

        def next_step(module: torch.nn.Module, args: tuple) -> None:
            window.close()
            steps.append((window.enter_context(host_syncs()), window.enter_context(HostBuiltTensors())))

        block.callback(network.register_forward_pre_hook(next_step).remove)
        yield steps


def assert_no_step_waits(steps: list[tuple[FoundOps, HostBuiltTensors]], expected: int, once: str = "") -> None:
    """``expected`` steps, none of which reads the device or builds a tensor from host data, but
    the first, which may build what is then kept, in the file ``once``."""
    assert len(steps) == expected
    for syncs, _ in steps:
        assert not syncs, syncs.report()
    (_, first), *rest = steps
    assert all(once and place.startswith(f"{PROJECT}/{once}:") for place in first.places), first.places
    for _, built in rest:
        assert not built.places, built.places


@pytest.mark.parametrize("body", [False, True], ids=["mmm", "mmm-body"])
def test_a_parallel_decoding_step_never_waits_for_the_device(body):
    """MMM's decoding reads the batch's free positions once per call, to know how many iterations
    to queue (m2d2m/generators/mmm/decoding.py); an iteration reads nothing."""
    torch.manual_seed(0)
    if body:
        config = BodyTransformerConfig(
            codebook_size=12, code_dim=4, lower_codebook_size=10, lower_code_dim=4, text_dim=16, **MASKED
        )
        transformer = BodyMaskedTransformer(config, torch.randn(12, 4), torch.randn(10, 4)).eval()
        lower = torch.randint(0, 10, (2, 8))

        def frame(upper: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
            return body_canvas(upper, lower[:, : upper.shape[1]], lengths, config)

    else:
        transformer = MaskedMotionTransformer(
            MaskedTransformerConfig(codebook_size=12, code_dim=4, text_dim=16, **MASKED), torch.randn(12, 4)
        ).eval()
        frame = None
    rows = [Row(SENTENCES[0], torch.full((8,), FREE), 1), Row(SENTENCES[1], torch.tensor([3, FREE, FREE, 4, FREE]), 2)]
    options = DecodingOptions(iterations=6, top_k=5, top_p=0.9)
    with per_call(transformer) as steps:
        decode_sentences(transformer, text_encoder(), rows, 8, options, frame)
    assert_no_step_waits(steps, expected=6)


@pytest.mark.parametrize(
    ("sampler", "correction", "prediction"),
    [("ancestral", 0.0, "epsilon"), ("ancestral", 0.5, "x0"), ("ddim", 0.5, "epsilon")],
    ids=["ancestral", "corrected-x0", "ddim-corrected"],
)
def test_a_reverse_diffusion_step_never_waits_for_the_device(sampler, correction, prediction):
    """Time-varied and body-part terms, one request keeping frames (editing), with and without the
    correction's backward pass, ε- and x_0-prediction: a step reads nothing and builds nothing
    from host data (the schedule's tables reach the device at the first step and stay there; the
    noise comes through pinned memory)."""
    torch.manual_seed(0)
    config = MotionDiffuseConfig(D, **MOTIONDIFFUSE, text_dim=16, text_ffn=32, max_frames=32)
    network = MotionDiffuseTransformer(config).eval()
    for parameter in network.parameters():
        torch.nn.init.normal_(parameter, std=0.2)  # the zero-initialised output would hide the arithmetic
    keep = torch.zeros(12, D, dtype=torch.bool)
    keep[:3] = True
    requests = [
        FeatureRequest(20, (Term(SENTENCES[0], 0, 12), Term(SENTENCES[1], 8, 20)), 1),
        FeatureRequest(
            12,
            (Term(SENTENCES[2], 0, 12, part_mask(T2M, UPPER)), Term(SENTENCES[3], 0, 12, ~part_mask(T2M, UPPER))),
            2,
            torch.randn(12, D),
            keep,
        ),
    ]
    with torch.no_grad():
        words, mask = text_encoder().encode([term.sentence for request in requests for term in request.terms])
        text = network.encode_text(words, mask)
    process = GaussianDiffusion.linear(40).respaced(5)
    if sampler == "ddim":
        step = lambda x, t, eps, noise: process.ddim_sample(x, t, eps, noise, 0.5)  # noqa: E731
    else:
        step = lambda x, t, eps, noise: process.p_sample(x, t, eps, noise, "posterior")  # noqa: E731
    with per_call(network) as steps:
        sample(network, text, requests, process, step, correction, prediction=prediction)
    assert_no_step_waits(steps, expected=5, once="m2d2m/processes/gaussian_diffusion.py")  # its tables, kept
