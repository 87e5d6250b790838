"""M2D2MModule on a tiny denoiser and fake token batches: gradients, overfitting, validation
metrics, sampling, non-finite losses and the codebook in checkpoints."""

import lightning.pytorch as pl
import pytest
import torch
from torch.utils.data import DataLoader

from m2d2m.generators.m2d2m.options import M2D2MOptions
from m2d2m.generators.m2d2m.sampling import TokenRequest
from m2d2m.text import LearnedTextEncoder
from training.losses import NonFiniteLossError
from training.m2d2m_module import M2D2MModule

K = 8
STEPS = 10
SENTENCES = [
    "a person walks forward",
    "a person jumps up high",
    "someone waves the left hand",
    "a man turns around and sits down",
]


def make_module(seed: int = 0, text_drop: float = 0.1, **diffusion) -> M2D2MModule:
    torch.manual_seed(seed)
    codebook = torch.randn(K, 4)
    return M2D2MModule(
        denoiser={
            "layers": 1,
            "heads": 2,
            "width": 32,
            "ffn": 64,
            "text_dim": 32,
            "num_buckets": 8,
            "max_distance": 16,
        },
        text={"kind": "learned", "dim": 32, "layers": 1, "heads": 2, "dropout": 0.0},
        diffusion={
            "steps": STEPS,
            "kind": "dynamic",
            "eta": 0.5,
            "distance": "l2_rank",
            "schedule": "linear",
            "aux_weight": 0.01,
            "timestep_sampling": "uniform",
            **diffusion,
        },
        optim={
            "lr": 3e-3,
            "betas": [0.9, 0.99],
            "weight_decay": 0.0,
            "warmup_steps": 0,
            "milestones": [1000],
            "gamma": 0.1,
        },
        codebook=codebook,
        vocabulary=LearnedTextEncoder.build_vocabulary(SENTENCES),
        text_drop=text_drop,
    )


def make_batch(seed: int = 0, lengths=(6, 4, 5)) -> dict:
    g = torch.Generator().manual_seed(seed)
    batch, length = len(lengths), max(lengths)
    lengths_t = torch.tensor(lengths)
    mask = torch.arange(length)[None, :] < lengths_t[:, None]
    tokens = torch.randint(K, (batch, length), generator=g).masked_fill(~mask, 0)
    actions = [[SENTENCES[i % len(SENTENCES)]] for i in range(batch)]
    actions[-1] = [SENTENCES[1], SENTENCES[2]]  # a two-action caption
    return {
        "tokens": tokens,
        "padding_mask": mask,
        "lengths": lengths_t,
        "actions": actions,
        "text": [" and ".join(a) for a in actions],
        "keys": [f"k{i}" for i in range(batch)],
    }


class Recorder:
    def __init__(self):
        self.logged = {}

    def __call__(self, name, value, **kwargs):
        self.logged[name] = float(value.detach() if torch.is_tensor(value) else value)


def test_training_step_is_finite_and_reaches_denoiser_and_text_encoder(monkeypatch):
    module = make_module(text_drop=0.0)
    recorder = Recorder()
    monkeypatch.setattr(module, "log", recorder)
    loss = module.training_step(make_batch(), 0)
    assert torch.isfinite(loss)
    loss.backward()
    for part in (module.denoiser, module.text_encoder):
        grads = [p.grad for p in part.parameters() if p.grad is not None]
        assert grads and any(g.abs().sum() > 0 for g in grads)
    assert {"train/loss", "train/vlb", "train/aux"} <= set(recorder.logged)
    buckets = [name for name in recorder.logged if name.startswith("train/vlb_t")]
    assert buckets and set(buckets) <= {"train/vlb_t1-3", "train/vlb_t4-5", "train/vlb_t6-8", "train/vlb_t9-10"}
    assert module.timesteps.count.sum() == 3


def test_overfits_one_batch(monkeypatch):
    module = make_module(text_drop=0.0)
    monkeypatch.setattr(module, "log", lambda *a, **k: None)
    batch = make_batch()
    optimizer = module.configure_optimizers()["optimizer"]

    def mean_loss() -> float:  # fixed t's so the comparison is not timestep noise
        torch.manual_seed(123)
        return sum(float(module.training_step(batch, 0).detach()) for _ in range(8)) / 8

    before = mean_loss()
    torch.manual_seed(0)
    for _ in range(60):
        optimizer.zero_grad()
        module.training_step(batch, 0).backward()
        optimizer.step()
    after = mean_loss()
    assert after < 0.7 * before, (before, after)


def test_validation_in_trainer_logs_accuracy(tmp_path):
    module = make_module()
    batches = [make_batch(seed) for seed in range(3)]
    loader = DataLoader(batches, batch_size=None)
    trainer = pl.Trainer(
        max_steps=2,
        limit_val_batches=2,
        val_check_interval=2,
        accelerator="cpu",
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
        num_sanity_val_steps=0,
    )
    trainer.fit(module, train_dataloaders=loader, val_dataloaders=loader)
    metrics = trainer.callback_metrics
    assert 0.0 <= float(metrics["val/token_accuracy"]) <= 1.0
    assert torch.isfinite(metrics["val/loss"]) and torch.isfinite(metrics["val/vlb"])


def test_validation_is_deterministic(monkeypatch):
    module = make_module()
    module.eval()
    values = []
    for _ in range(2):
        recorder = Recorder()
        monkeypatch.setattr(module, "log", recorder)
        with torch.no_grad():
            module.validation_step(make_batch(), 3)
        values.append(recorder.logged)
    assert values[0] == values[1]


def test_sampler_uses_the_modules_parts_and_restores_the_mode():
    module = make_module()
    requests = [TokenRequest([[SENTENCES[0]]], [7], seed=5), TokenRequest([[SENTENCES[1], SENTENCES[2]]], [3], seed=6)]
    first = module.sampler().sample(requests, M2D2MOptions(guidance=3.0, ts=0, eta=0.25))
    second = module.sampler().sample(requests, M2D2MOptions(guidance=3.0, ts=0, eta=0.25))
    assert [len(x[0]) for x in first] == [7, 3]
    for (a,), (b,) in zip(first, second):
        assert a.dtype == torch.long and int(a.min()) >= 0 and int(a.max()) < K
        assert torch.equal(a, b)
    assert module.training  # sampling restores the mode


@pytest.mark.parametrize("options", [{"kind": "uniform"}, {"timestep_sampling": "importance"}])
def test_other_schedules_and_importance_sampling(monkeypatch, options):
    module = make_module(**options)
    monkeypatch.setattr(module, "log", lambda *a, **k: None)
    for _ in range(3):
        assert torch.isfinite(module.training_step(make_batch(), 0))
    tokens = module.sampler().sample([TokenRequest([[SENTENCES[0]]], [5])], M2D2MOptions(guidance=1.0, ts=0))
    assert len(tokens[0][0]) == 5


@pytest.mark.parametrize("timestep_sampling", ["uniform", "importance"])
def test_non_finite_loss_is_noted_and_raised_at_the_next_read(monkeypatch, timestep_sampling):
    """The step notes a NaN loss on the device and goes on (no host read); the guard's read raises
    it with its step, and the steps in between draw t as before (a NaN never reaches p(t))."""
    module = make_module(timestep_sampling=timestep_sampling)
    monkeypatch.setattr(module, "log", lambda *a, **k: None)
    with torch.no_grad():
        module.denoiser.head.bias.fill_(float("nan"))
    for _ in range(2):
        module.training_step(make_batch(), 0)
    assert module.timesteps.count.sum() == 0 and torch.isfinite(module.timesteps.history).all()
    with pytest.raises(NonFiniteLossError, match="the training loss is nan at step 0"):
        module.raise_if_not_finite()


def test_codebook_in_state_dict_and_schedule_rebuilt_on_load():
    module = make_module(seed=0)
    state = module.state_dict()
    assert "codebook" in state and state["codebook"].shape == (K, 4)
    assert "codebook" not in module.hparams
    other = make_module(seed=1)
    assert not torch.equal(other.codebook, module.codebook)
    other.load_state_dict(state)
    assert torch.equal(other.codebook, module.codebook)
    assert torch.equal(other.schedule.cumulative_matrix(STEPS), module.schedule.cumulative_matrix(STEPS))
