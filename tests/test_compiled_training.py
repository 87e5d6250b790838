"""How a training step runs on the device (training/step.py): compiled passes equal eager ones,
the padding a compiled M2D2M step adds changes nothing, AdamW runs fused where it may, and
gradients are clipped by their global norm (docs/training.md, "Compiled training steps")."""

from __future__ import annotations

import lightning.pytorch as pl
import pytest
import torch
from torch.utils.data import DataLoader

from m2d2m.compiling import Compiled, pad_to_bucket
from m2d2m.text import LearnedTextEncoder
from tests.test_m2d2m_module import make_batch, make_module
from tests.test_mmm_module import batch as mmm_batch
from tests.test_mmm_module import module as mmm_module
from tests.test_motiondiffuse import SENTENCES, D, tiny_config
from training.motiondiffuse_module import MotionDiffuseModule
from training.step import TrainingModule


def motiondiffuse_module() -> MotionDiffuseModule:
    torch.manual_seed(0)
    return MotionDiffuseModule(
        {k: v for k, v in tiny_config().to_dict().items() if k not in ("feature_dim", "text_dim")},
        {"kind": "learned", "dim": 16, "layers": 1, "heads": 2, "dropout": 0.0},
        {"steps": 40},
        {"lr": 1e-3, "grad_clip": 1.0},
        D,
        0.0,
        LearnedTextEncoder.build_vocabulary(SENTENCES),
    )


def motiondiffuse_batch() -> dict:
    generator = torch.Generator().manual_seed(0)
    return {
        "motion": torch.randn(3, 12, D, generator=generator),
        "lengths": torch.tensor([12, 7, 9]),
        "text": SENTENCES[:3],
    }


def _m2d2m_pass(module):
    batch = make_batch()
    z0, valid = batch["tokens"].long(), batch["padding_mask"].bool()
    t = torch.tensor([1, 4, 9])
    z_t = module._corrupt(z0, valid, t, torch.Generator().manual_seed(1))
    text, text_mask = module._condition(batch["actions"])
    return module._training_loss, (z0, valid, z_t, t, torch.full((3,), 0.1), text, text_mask)


def _mmm_pass(module):
    codes, masked, inputs = module._masked_inputs(mmm_batch(), torch.Generator().manual_seed(1))
    return module._masked_loss, (inputs, codes, masked, *module._condition(mmm_batch()["text"]))


def _motiondiffuse_pass(module):
    batch = motiondiffuse_batch()
    generator = torch.Generator().manual_seed(1)
    t = torch.randint(0, 40, (3,), generator=generator)
    noise = torch.randn(batch["motion"].shape, generator=generator)
    words, mask = module.text_encoder.encode(batch["text"])
    return module._noise_losses, (batch["motion"], batch["lengths"], t, noise, words, mask)


PASSES = {
    # text_drop 0 and no dropout: the passes draw nothing that the result depends on
    "m2d2m": (lambda: make_module(text_drop=0.0), _m2d2m_pass),
    "mmm": (mmm_module, _mmm_pass),
    "motiondiffuse": (motiondiffuse_module, _motiondiffuse_pass),
}


def _loss_and_grads(module, prepare, run=None, pad=None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The pass's loss and gradients, on inputs prepared afresh (the text features carry a graph
    of their own), run by ``run`` (the method itself by default), its inputs padded by ``pad``."""
    module.zero_grad()
    function, args = prepare(module)
    out = (run or function)(*(pad(args) if pad else args))
    loss = (out[0] if isinstance(out, tuple) else out).sum()
    loss.backward()
    return loss.detach(), {n: p.grad.clone() for n, p in module.named_parameters() if p.grad is not None}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(PASSES))
def test_a_compiled_training_pass_equals_the_eager_one(name):
    """torch.compile's inductor on the CPU (a C++ compiler builds the kernels): the loss and every
    gradient of the compiled pass — forward, loss and AOTAutograd's backward — equal eager ones
    to float32 rounding. Slow: compiling takes about a minute on two cores."""
    make, prepare = PASSES[name]
    module = make()
    module.train()
    eager_loss, eager_grads = _loss_and_grads(module, prepare)
    module.compile_steps = "on"
    compiled = module.compiled(prepare(module)[0])
    assert isinstance(compiled, Compiled)
    loss, grads = _loss_and_grads(module, prepare, run=compiled)
    assert compiled.compiled, "compiling fell back to eager"
    torch.testing.assert_close(loss, eager_loss, rtol=1e-5, atol=1e-6)
    assert grads.keys() == eager_grads.keys() and grads
    for parameter, grad in grads.items():
        torch.testing.assert_close(grad, eager_grads[parameter], rtol=1e-4, atol=1e-6, msg=parameter)


def test_padding_the_m2d2m_step_to_buckets_changes_neither_loss_nor_gradients():
    """What a compiled step adds before its pass — tokens and text padded to a bucket — leaves
    the loss, the per-sample terms and the gradients of the batch as it came (here eagerly)."""
    module = make_module(text_drop=0.0)
    module.train()
    widths = []

    def padded(args):
        z0, valid, z_t, t, pt, text, text_mask = args
        tokens = [pad_to_bucket(x, 1) for x in (z0, valid, z_t)]
        widths.append((z0.shape[1], tokens[0].shape[1], text.shape[1], pad_to_bucket(text, 1).shape[1]))
        return (*tokens, t, pt, pad_to_bucket(text, 1), pad_to_bucket(text_mask, 1))

    plain_loss, plain_grads = _loss_and_grads(module, _m2d2m_pass)
    loss, grads = _loss_and_grads(module, _m2d2m_pass, pad=padded)
    ((tokens, padded_tokens, text, padded_text),) = widths
    assert (tokens, padded_tokens) == (6, 8) and padded_text > text
    torch.testing.assert_close(loss, plain_loss, rtol=1e-5, atol=1e-6)
    for parameter, grad in grads.items():
        torch.testing.assert_close(grad, plain_grads[parameter], rtol=1e-4, atol=1e-7, msg=parameter)


def test_steps_run_eagerly_unless_compiling_is_asked_for_on_the_device():
    module = make_module()
    module.train()
    function = module._training_loss
    assert module.compiled(function) == function  # trainer.compile: off, the default
    module.compile_steps = "auto"
    assert module.compiled(function) == function  # auto compiles on CUDA only
    module.compile_steps = "on"
    assert isinstance(module.compiled(function), Compiled)
    assert module.compiled(function) is module.compiled(function)  # one per method for the module's life
    with torch.no_grad():
        assert module.compiled(function) == function  # validation: no gradients, eager
    module.eval()
    assert module.compiled(function) == function


class _Tiny(TrainingModule):
    def __init__(self) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.tensor([3.0, 4.0]))

    def training_step(self, batch, batch_idx):
        return 50.0 * (self.weight * self.weight * batch).sum()  # gradient 100·w: (300, 400)

    def configure_optimizers(self):
        return torch.optim.AdamW(self.parameters(), lr=0.0, fused=self.fuses_optimizer())


@pytest.mark.parametrize(("precision", "fused"), [("32-true", True), ("bf16-mixed", True), ("16-mixed", False)])
def test_adamw_fuses_unless_a_gradient_scaler_must_unscale_before_clipping(precision, fused):
    class Trainer:
        pass

    module = _Tiny()
    trainer = Trainer()
    trainer.precision = precision
    module._trainer = trainer
    assert module.fuses_optimizer() is fused
    module._trainer = None
    assert module.fuses_optimizer()  # no trainer: nothing to scale


def test_a_fused_optimizer_trains_under_bf16_with_its_gradients_clipped_to_the_global_norm(tmp_path):
    """Lightning's bf16 plugin refuses to clip for a fused optimiser; the module clips itself:
    a gradient of (300, 400) (norm 500) clipped to norm 1 is (0.6, 0.8)."""
    seen = []

    class Recorder(pl.Callback):
        def on_before_optimizer_step(self, trainer, module, optimizer):
            seen.append(module.weight.grad.clone())

    module = _Tiny()
    trainer = pl.Trainer(
        accelerator="cpu",
        max_steps=1,
        precision="bf16-mixed",
        gradient_clip_val=1.0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[Recorder()],
        default_root_dir=tmp_path,
    )
    trainer.fit(module, DataLoader([torch.ones(2)], batch_size=None))
    assert trainer.optimizers[0].defaults["fused"]
    clipped = module.weight.grad
    assert seen and seen[0].tolist() == [300.0, 400.0]
    torch.testing.assert_close(clipped, torch.tensor([0.6, 0.8]))


@pytest.mark.parametrize(("value", "choice"), [(False, "off"), (True, "on"), ("auto", "auto"), ("off", "off")])
def test_trainer_compile_takes_yaml_s_bare_off_and_on_for_the_words(value, choice):
    """``--set trainer.compile=off`` reaches the config as False: YAML 1.1's boolean."""
    from orchestration.config import apply_overrides
    from orchestration.train import compile_setting

    assert compile_setting(value) == choice
    assert (
        compile_setting(
            apply_overrides({"trainer": {"compile": "auto"}}, ["trainer.compile=off"])["trainer"]["compile"]
        )
        == "off"
    )


def test_a_trainer_compile_that_is_none_of_the_choices_is_refused_in_one_line():
    from orchestration.errors import UserError
    from orchestration.train import compile_setting

    with pytest.raises(UserError, match="^trainer.compile must be one of off, auto, on, got 'yes please'$"):
        compile_setting("yes please")


@pytest.mark.parametrize("name", sorted(PASSES))
def test_each_training_pass_is_traced_whole_as_one_graph(name):
    """A graph break splits a compiled step into graphs and launches between them (on CUDA, CUDA
    graphs apart). M2D2M's pass broke five times at ``max(..., default=0)`` in the posterior's
    grouping, which dynamo does not take. Tracing only (torch._dynamo.explain): no kernel is built."""
    make, prepare = PASSES[name]
    module = make()
    module.train()
    function, args = prepare(module)
    torch._dynamo.reset()
    explained = torch._dynamo.explain(function)(*args)
    assert (explained.graph_count, explained.graph_break_count) == (1, 0), explained.break_reasons
