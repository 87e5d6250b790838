"""MotionDiffuse's pieces checked against independent constructions: efficient attention against
its formula written out with loops and its cost against sequence length, padding invariance of
the network, the time-varied and body-part combinations against the masked sums of eqs. 10–11,
the correction's disagreement term, the generator's requests (seeds, editing, body parts), and
ε-prediction training that recovers a known 1-D Gaussian."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.flop_counter import FlopCounterMode

from m2d2m.generators.motiondiffuse.checkpoint import MOTIONDIFFUSE_FORMAT, load_motiondiffuse
from m2d2m.generators.motiondiffuse.generator import MotionDiffuseGenerator
from m2d2m.generators.motiondiffuse.sampling import FeatureRequest, Layout, Term, sample
from m2d2m.generators.protocol import Keep, keep_part
from m2d2m.model_files import LengthPrior
from m2d2m.motion.representation.body_parts import LOWER, UPPER, part_mask
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.networks.config import ConfigError
from m2d2m.networks.motiondiffuse_transformer import (
    MotionDiffuseConfig,
    MotionDiffuseTransformer,
    efficient_attention,
    softmax_attention,
    timestep_embedding,
)
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion
from m2d2m.text import LearnedTextEncoder
from training.motiondiffuse_module import MotionDiffuseModule, masked_mse

SENTENCES = ["a person walks forward", "a person jumps", "a person waves their right hand", "a person runs"]
D = T2M.feature_dim


def tiny_config(**changes) -> MotionDiffuseConfig:
    values = {
        "feature_dim": D,
        "width": 16,
        "layers": 2,
        "heads": 2,
        "ffn": 32,
        "text_dim": 16,
        "text_width": 16,
        "text_layers": 1,
        "text_heads": 2,
        "text_ffn": 32,
        "max_frames": 64,
    }
    return MotionDiffuseConfig(**{**values, **changes})


def awake(network: torch.nn.Module, seed: int = 0, scale: float = 0.2) -> torch.nn.Module:
    """Every weight random: the zero-initialised projections would otherwise hide what is tested."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in network.parameters():
            parameter.copy_(torch.randn(parameter.shape, generator=generator) * scale)
    return network.eval()


# ------------------------------------------------------------------------------------- attention
def test_efficient_attention_equals_its_formula_written_out():
    """Eq. 8 per head with loops: F_g[a, b] = Σ_n softmax_n(K)[n, a] V[n, b] over valid keys,
    Y[m, b] = Σ_a softmax_a(Q)[m, a] F_g[a, b]."""
    torch.manual_seed(0)
    q, k, v = torch.randn(2, 3, 5, 4), torch.randn(2, 3, 6, 4), torch.randn(2, 3, 6, 4)
    key_mask = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    out = efficient_attention(q, k, v, key_mask)
    for b in range(2):
        valid = [n for n in range(6) if key_mask[b, n]]
        for h in range(3):
            for m in range(5):
                query = [float(x) for x in q[b, h, m]]
                qs = [np.exp(x) / sum(np.exp(y) for y in query) for x in query]
                for col in range(4):
                    total = 0.0
                    for a in range(4):
                        column = [float(k[b, h, n, a]) for n in valid]
                        ks = [np.exp(x) / sum(np.exp(y) for y in column) for x in column]
                        global_ab = sum(ks[i] * float(v[b, h, n, col]) for i, n in enumerate(valid))
                        total += qs[a] * global_ab
                    assert out[b, h, m, col].item() == pytest.approx(total, abs=1e-5)


def test_softmax_attention_equals_the_standard_formula_with_masked_keys():
    torch.manual_seed(1)
    q, k, v = torch.randn(1, 2, 3, 4), torch.randn(1, 2, 5, 4), torch.randn(1, 2, 5, 4)
    key_mask = torch.tensor([[True, True, True, False, False]])
    weights = (q @ k[:, :, :3].transpose(-1, -2) / 2.0).softmax(dim=-1)  # √d = 2
    assert torch.allclose(softmax_attention(q, k, v, key_mask), weights @ v[:, :, :3], atol=1e-6)


def _flops(attend, length: int, width: int = 64, heads: int = 4) -> int:
    q = k = v = torch.randn(1, heads, length, width // heads)
    with FlopCounterMode(display=False) as counter:
        attend(q, k, v, torch.ones(1, length, dtype=torch.bool))
    return counter.get_total_flops()


def test_efficient_attention_costs_grow_linearly_with_length_softmax_quadratically():
    linear = [_flops(efficient_attention, n) for n in (200, 400, 800)]
    quadratic = [_flops(softmax_attention, n) for n in (200, 400, 800)]
    assert linear[1] == 2 * linear[0] and linear[2] == 2 * linear[1]
    assert quadratic[1] == 4 * quadratic[0] and quadratic[2] == 4 * quadratic[1]


# --------------------------------------------------------------------------------------- network
@pytest.mark.parametrize("attention", ["linear", "softmax"])
def test_padded_frames_never_influence_valid_ones(attention):
    network = awake(MotionDiffuseTransformer(tiny_config(attention=attention)))
    words, mask = torch.randn(3, 5, 16), torch.ones(3, 5, dtype=torch.bool)
    mask[1, 3:] = False
    text = network.encode_text(words, mask)
    x, lengths, t = torch.randn(3, 40, D), torch.tensor([40, 25, 9]), torch.tensor([0, 500, 999])
    changed = x.clone()
    changed[1, 25:] = 50.0
    changed[2, 9:] = -7.0
    with torch.no_grad():
        before, after = network(x, t, lengths, text), network(changed, t, lengths, text)
        alone = network(x[2:, :9], t[2:], lengths[2:], network.encode_text(words[2:], mask[2:]))
    for row, n in enumerate(lengths.tolist()):
        assert torch.equal(before[row, :n], after[row, :n])
    assert torch.allclose(before[2, :9], alone[0], atol=1e-5)  # a padded row = the row alone


def test_a_fresh_network_predicts_zero_noise_and_bad_settings_are_one_line_errors():
    network = MotionDiffuseTransformer(tiny_config())
    text = network.encode_text(torch.randn(1, 2, 16), torch.ones(1, 2, dtype=torch.bool))
    assert not network(torch.randn(1, 10, D), torch.tensor([3]), torch.tensor([10]), text).any()
    with pytest.raises(ConfigError, match="attention"):
        tiny_config(attention="flash")
    with pytest.raises(ConfigError, match="divisible"):
        tiny_config(width=15)
    with pytest.raises(ValueError, match="at most 64 frames"):
        network(torch.randn(1, 65, D), torch.tensor([3]), torch.tensor([65]), text)
    embedding = timestep_embedding(torch.tensor([0, 999]), 16)
    assert embedding.shape == (2, 16) and torch.equal(embedding[0, :8], torch.ones(8))


# ------------------------------------------------------------------------------- combining terms
def _layout(requests, feature_dim=6, max_term=64):
    return Layout(requests, feature_dim, max_term, torch.device("cpu"))


def test_time_varied_combination_without_correction_is_the_masked_sum():
    """Eq. 11 with λ2 = 0 and intervals tiling the sequence: Σ_i pad(ε_i)."""
    terms = (Term("a", 0, 4), Term("b", 4, 9), Term("c", 9, 12))
    layout = _layout([FeatureRequest(12, terms, 0), FeatureRequest(7, (Term("d", 0, 7),), 1)])
    eps = torch.randn(4, layout.width, 6)
    expected = torch.zeros(2, 12, 6)
    for k, term in enumerate(terms):
        padded = torch.zeros(12, 6)
        padded[term.start : term.end] = eps[k, : term.end - term.start]
        expected[0] += padded
    expected[1, :7] = eps[3, :7]
    assert torch.allclose(layout.combine(eps), expected)
    assert layout.pair_count == 0  # tiling intervals share no frame: nothing to correct


def test_overlapping_intervals_are_averaged_where_they_overlap():
    layout = _layout([FeatureRequest(10, (Term("a", 0, 6), Term("b", 4, 10)), 0)])
    eps = torch.randn(2, layout.width, 6)
    combined = layout.combine(eps)[0]
    assert torch.allclose(combined[:4], eps[0, :4])
    assert torch.allclose(combined[4:6], (eps[0, 4:6] + eps[1, :2]) / 2)
    assert torch.allclose(combined[6:], eps[1, 2:6])


def test_body_part_combination_is_the_sum_of_masked_estimates_and_parts_must_cover_the_body():
    """Eq. 10 with λ1 = 0: Σ_i ε_i · M_i, the masks partitioning the dimensions."""
    upper, lower = part_mask(T2M, UPPER), part_mask(T2M, LOWER)
    layout = _layout([FeatureRequest(5, (Term("u", 0, 5, upper), Term("l", 0, 5, lower)), 0)], feature_dim=D)
    eps = torch.randn(2, 5, D)
    expected = eps[0] * torch.as_tensor(upper) + eps[1] * torch.as_tensor(lower)
    assert torch.allclose(layout.combine(eps)[0], expected)
    with pytest.raises(ValueError, match="without a sentence"):
        _layout([FeatureRequest(5, (Term("u", 0, 5, upper),), 0)], feature_dim=D)
    with pytest.raises(ValueError, match="without a sentence"):
        _layout([FeatureRequest(10, (Term("a", 0, 4), Term("b", 6, 10)), 0)])


def test_terms_estimated_in_length_groups_equal_one_padded_call():
    network = awake(MotionDiffuseTransformer(tiny_config(feature_dim=6)))
    requests = [FeatureRequest(n, (Term("a", 0, n),), n) for n in range(3, 40)]  # 37 terms: two groups
    layout = _layout(requests)
    x = torch.randn(len(requests), layout.frames, 6)
    text = network.encode_text(torch.randn(37, 2, 16), torch.ones(37, 2, dtype=torch.bool))
    t = torch.arange(37) * 20
    with torch.no_grad():
        grouped = layout.estimate(network, x, t, text)
        direct = network(layout.terms_of(x), t, layout.lengths, text) * layout.valid[:, :, None]
    assert len(layout.groups) == 2 and [width for _, width in layout.groups] == [39, 7]
    assert torch.allclose(grouped, direct, atol=1e-5)


def test_disagreement_is_the_sum_of_norms_over_shared_frames_both_orders():
    layout = _layout([FeatureRequest(10, (Term("a", 0, 6), Term("b", 4, 10), Term("c", 5, 10)), 0)])
    eps = torch.randn(3, layout.width, 6)
    ab = torch.linalg.norm(eps[0, 4:6] - eps[1, 0:2])
    ac = torch.linalg.norm(eps[0, 5:6] - eps[2, 0:1])
    bc = torch.linalg.norm(eps[1, 1:6] - eps[2, 0:5])
    assert layout.pair_count == 3
    assert layout.disagreement(eps).item() == pytest.approx(2 * (ab + ac + bc).item(), rel=1e-5)


class _ShiftNetwork(torch.nn.Module):
    """ε = x · a_text: a closed-form stand-in whose per-sentence estimates differ, for the
    correction's gradient (one sentence → one scale)."""

    def __init__(self, feature_dim: int) -> None:
        super().__init__()
        self.config = tiny_config(feature_dim=feature_dim)

    def forward(self, x, t, lengths, text):
        return x * text.sentence[:, None, :1]


def test_correction_moves_the_estimate_along_the_gradient_of_disagreement():
    """With ε_i = a_i·x on the shared frames, Σ_{i≠j}‖ε_i − ε_j‖ = 2|a_1 − a_2|·‖x_shared‖, whose
    gradient is 2|a_1 − a_2|·x/‖x‖ there and 0 elsewhere: one reverse step with λ against one
    without differs by exactly the step's ε coefficient times λ times that gradient."""
    from m2d2m.networks.motiondiffuse_transformer import EncodedText

    process = GaussianDiffusion(np.array([0.3]))  # one step: x_0 = (x_1 − √(1−ᾱ) ε̄)/√ᾱ
    requests = [FeatureRequest(6, (Term("a", 0, 4), Term("b", 2, 6)), 7)]
    text = EncodedText(torch.zeros(2, 1, 16), torch.ones(2, 1, dtype=torch.bool), torch.tensor([[1.0], [3.0]]))
    network = _ShiftNetwork(4)
    step = lambda x, t, eps, noise: process.p_sample(x, t, eps, noise)  # noqa: E731
    plain = sample(network, text, requests, process, step, 0.0)[0]
    corrected = sample(network, text, requests, process, step, 0.5)[0]
    x1 = torch.randn(6, 4, generator=torch.Generator().manual_seed(7))
    gradient = torch.zeros(6, 4)
    gradient[2:4] = 2 * 2.0 * x1[2:4] / torch.linalg.norm(x1[2:4])
    coefficient = -float(np.sqrt(1 - process.alphas_cumprod[0]) / np.sqrt(process.alphas_cumprod[0]))
    assert torch.allclose(corrected - plain, coefficient * 0.5 * gradient, atol=1e-5)


# ------------------------------------------------------------------------------------- generator
@pytest.fixture(scope="module")
def generator(tmp_path_factory) -> MotionDiffuseGenerator:
    encoder = LearnedTextEncoder(LearnedTextEncoder.build_vocabulary(SENTENCES), dim=16, layers=1, heads=2, dropout=0.0)
    network = awake(MotionDiffuseTransformer(tiny_config()), seed=3, scale=0.05)
    rng = np.random.default_rng(0)
    normalizer = Normalizer(rng.normal(size=D).astype(np.float32), rng.uniform(0.5, 2.0, D).astype(np.float32))
    path = tmp_path_factory.mktemp("motiondiffuse") / "model.pt"
    MOTIONDIFFUSE_FORMAT.save(
        path,
        network=network,
        text=encoder,
        diffusion={"steps": 20, "beta_start": 1e-4, "beta_end": 0.01},
        normalizer=normalizer,
        skeleton="t2m",
        lengths=LengthPrior({"walk": 30}, 24, 60),
        extra={"data_dir": "/nowhere"},
    )
    return MotionDiffuseGenerator.load(path)


def test_model_file_round_trip(generator):
    again = load_motiondiffuse(generator.source)
    for key, value in generator.checkpoint.network.state_dict().items():
        assert torch.equal(value, again.network.state_dict()[key])
    assert generator.process.num_steps == 20 and generator.typical_frames("walk") == 30
    assert generator.longest_frames == 60 and generator.data_dir == Path("/nowhere")


def test_multi_action_request_gives_ranges_and_each_sequence_depends_on_its_seed_alone(generator):
    options = generator.options(overlap=4)
    together = generator.generate([SENTENCES[:2], SENTENCES[2:]], [[20, 12], [16, 16]], options, [5, 6])
    alone = generator.generate([SENTENCES[2:]], [[16, 16]], options, [6])[0]
    assert together[0].ranges == [(0, 20), (20, 32)] and together[0].actions == SENTENCES[:2]
    assert together[0].features.shape == (32, D) and together[0].joints.shape == (32, 22, 3)
    assert np.allclose(together[1].features, alone.features, rtol=1e-4, atol=1e-4)
    assert together[0].settings["method"] == "time-varied" and together[0].settings["seed"] == 5
    other_seed = generator.generate([SENTENCES[2:]], [[16, 16]], options, [7])[0]
    assert not np.allclose(other_seed.features, alone.features)


def test_independent_equals_each_action_sampled_alone(generator):
    options = generator.options(method="independent", steps=5, sampler="ddim")
    joined = generator.generate([SENTENCES[:2]], [[10, 14]], options, [3])[0]
    network, encoder = generator.checkpoint.network, generator.checkpoint.text_encoder
    words, mask = encoder.encode(SENTENCES[:2])
    text = network.encode_text(words, mask)
    process = generator.process.respaced(5)
    requests = [FeatureRequest(24, (Term(SENTENCES[0], 0, 10), Term(SENTENCES[1], 10, 24)), 3)]
    direct = sample(
        network, text, requests, process, lambda x, t, eps, noise: process.ddim_sample(x, t, eps, noise, 0.0), 0.0
    )[0]
    assert np.allclose(joined.features, generator.checkpoint.normalizer.denormalize(direct.numpy()), atol=1e-5)


def test_body_part_request_and_editing_keep_what_they_must(generator):
    options = generator.options(steps=5)
    motion = generator.generate_parts([{UPPER: SENTENCES[2], LOWER: SENTENCES[3]}], [24], options, [1])[0]
    assert motion.features.shape == (24, D) and motion.settings["parts"] == {UPPER: SENTENCES[2], LOWER: SENTENCES[3]}
    with pytest.raises(ValueError, match="missing lower"):
        generator.generate_parts([{UPPER: "a person waves"}], [24], options, [1])
    source = motion.features
    upper = generator.generate([[SENTENCES[0]]], [[24]], options, [2], [keep_part(source, T2M, LOWER)])[0]
    lower = part_mask(T2M, LOWER)
    assert np.allclose(upper.features[:, lower], source[:, lower], atol=1e-4)
    assert not np.allclose(upper.features[:, ~lower], source[:, ~lower], atol=1e-2)
    frames = np.zeros(24, dtype=bool)
    frames[:6] = frames[-6:] = True
    between = generator.generate([[SENTENCES[0]]], [[24]], options, [2], [Keep(source, frames)])[0]
    assert np.allclose(between.features[frames], source[frames], atol=1e-4)


def test_bad_options_are_refused(generator):
    for changes, message in (
        ({"steps": 21}, "steps must lie in 1..20"),
        ({"sampler": "euler"}, "sampler"),
        ({"variance": "learned"}, "variance"),
        ({"ddim_eta": 2.0}, "ddim_eta"),
        ({"overlap": -1}, "overlap"),
        ({"method": "tps"}, "unknown method"),
    ):
        with pytest.raises(ValueError, match=message):
            generator.options(**changes)
    assert "ancestral" in generator.describe(generator.options())
    assert "DDIM" in generator.describe(generator.options(sampler="ddim", steps=5))


# -------------------------------------------------------------------------------------- training
def test_masked_mse_ignores_padding_and_weighs_motions_alike():
    target = torch.zeros(2, 4, 3)
    predicted = torch.zeros(2, 4, 3)
    predicted[0, :2] = 1.0
    predicted[0, 2:] = 100.0  # padding of a 2-frame motion
    predicted[1] = 2.0
    assert torch.allclose(masked_mse(predicted, target, torch.tensor([2, 4])), torch.tensor([1.0, 4.0]))


def test_module_logs_the_loss_per_quarter_of_the_steps():
    module = MotionDiffuseModule(
        {k: v for k, v in tiny_config().to_dict().items() if k not in ("feature_dim", "text_dim")},
        {"kind": "learned", "dim": 16, "layers": 1, "heads": 2},
        {"steps": 40},
        {"lr": 1e-3},
        D,
        0.1,
        LearnedTextEncoder.build_vocabulary(SENTENCES),
    )
    logged = {}
    module.log = lambda name, value, **kwargs: logged.__setitem__(name, float(value.detach()))
    batch = {
        "motion": torch.randn(8, 30, D),
        "lengths": torch.tensor([30, 20, 10, 30, 25, 30, 12, 30]),
        "text": SENTENCES * 2,
    }
    module.validation_step(batch, 0)
    first = dict(logged)
    module.validation_step(batch, 0)
    assert logged == first  # validation draws t and noise from its own seeded generator
    buckets = [name for name in logged if name.startswith("val/loss_t")]
    assert buckets and set(buckets) <= {"val/loss_t0-9", "val/loss_t10-19", "val/loss_t20-29", "val/loss_t30-39"}
    assert np.isfinite(logged["val/loss"])
    previews = module.preview(["a person jumps"], [12], seed=0, steps=3)
    assert previews[0].shape == (12, D)


def test_x0_prediction_and_the_cosine_schedule_are_what_the_module_trains_and_samples_with(tmp_path):
    """``diffusion.prediction: x0`` makes x_0 the regression target; the generator turns the
    network's x_0 into the ε it implies (``sample(prediction="x0")``), so a network whose output
    is x_0 = 0 samples what an ε network predicting predict_eps(x_t, t, 0) does."""
    diffusion = {"steps": 30, "schedule": "cosine", "prediction": "x0"}
    module = MotionDiffuseModule(
        {k: v for k, v in tiny_config().to_dict().items() if k not in ("feature_dim", "text_dim")},
        {"kind": "learned", "dim": 16, "layers": 1, "heads": 2},
        diffusion,
        {"lr": 1e-3},
        D,
        0.0,
        LearnedTextEncoder.build_vocabulary(SENTENCES),
    )
    assert module.process.betas[-1] == pytest.approx(0.999)  # the cosine schedule's clipped end
    batch = {"motion": torch.randn(4, 16, D), "lengths": torch.tensor([16, 12, 16, 8]), "text": SENTENCES}
    seen = {}
    original = module.network.forward
    module.network.forward = lambda *args: seen.setdefault("out", original(*args))
    losses, _ = module._losses(batch, torch.Generator().manual_seed(0))
    x0 = (batch["motion"] - module.feature_mean) / module.feature_scale
    torch.testing.assert_close(losses, masked_mse(seen["out"].float(), x0, batch["lengths"]))
    with pytest.raises(ConfigError, match="diffusion.prediction one of epsilon, x0"):
        MotionDiffuseModule(
            {},
            {"kind": "learned", "dim": 16},
            {"prediction": "v"},
            {},
            D,
            0.0,
            LearnedTextEncoder.build_vocabulary(SENTENCES),
        )

    network = MotionDiffuseTransformer(tiny_config())  # a fresh network predicts 0 everywhere
    encoder = LearnedTextEncoder(LearnedTextEncoder.build_vocabulary(SENTENCES), dim=16, layers=1, heads=2)
    text = network.encode_text(*encoder.encode(["a person jumps"]))
    process = GaussianDiffusion(module.process.betas)
    ddim = lambda x, t, eps, noise: process.ddim_sample(x, t, eps, noise, 0.0)  # noqa: E731
    request = [FeatureRequest(12, (Term("a person jumps", 0, 12),), 3)]
    as_x0 = sample(network, text, request, process, ddim, 0.0, prediction="x0")[0]
    x = torch.randn(1, 12, D, generator=torch.Generator().manual_seed(3))
    for index in reversed(range(process.num_steps)):
        t = torch.full((1,), index)
        x = ddim(x, t, process.predict_eps(x, t, torch.zeros_like(x)), torch.zeros_like(x))
    torch.testing.assert_close(as_x0, x[0], rtol=1e-4, atol=1e-4)


class _ToyEstimator(torch.nn.Module):
    """ε_θ(x_t, t) for scalar data: an MLP of x_t and a sinusoidal embedding of t."""

    def __init__(self) -> None:
        super().__init__()
        self.net = torch.nn.Sequential(
            torch.nn.Linear(17, 64), torch.nn.SiLU(), torch.nn.Linear(64, 64), torch.nn.SiLU(), torch.nn.Linear(64, 1)
        )

    def forward(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([x, timestep_embedding(t, 16)], dim=-1))


def test_epsilon_prediction_training_recovers_a_known_gaussian(one_torch_thread):
    """Train ε_θ with eq. 4 on samples of N(1.5, 0.5²), then sample by the reverse process: the
    samples' mean and std come back (the oracle bounds the 50-step sampler's own bias: test_gaussian_diffusion)."""
    torch.manual_seed(0)
    process = GaussianDiffusion.linear(200)
    model = _ToyEstimator()
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, 2000)
    for _ in range(2000):
        x0 = 1.5 + 0.5 * torch.randn(1024, 1)
        t = torch.randint(0, process.num_steps, (1024,))
        noise = torch.randn_like(x0)
        loss = ((model(process.q_sample(x0, t, noise), t) - noise) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
    x = torch.randn(20000, 1)
    with torch.no_grad():
        for index in reversed(range(process.num_steps)):
            t = torch.full((len(x),), index)
            x = process.p_sample(x, t, model(x, t), torch.randn_like(x))
    assert x.mean().item() == pytest.approx(1.5, abs=0.03)
    assert x.std().item() == pytest.approx(0.5, abs=0.03)
