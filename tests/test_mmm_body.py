"""MMM's upper-body editor on tiny random models: the body transformer's shapes and padding, the
training step's loss, the model file, and the generator, which must never change a kept
lower-body token and must fill exactly the upper-body positions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from m2d2m.generators.mmm.body import BodyMMMGenerator, masked_lower
from m2d2m.generators.mmm.checkpoint import BODY_FORMAT, MMM_FORMAT, load_body_mmm
from m2d2m.generators.mmm.generator import MMMGenerator
from m2d2m.generators.options import SINGLE
from m2d2m.generators.protocol import Keep, keep_part
from m2d2m.model_files import LengthPrior
from m2d2m.motion.representation.body_parts import LOWER, UPPER
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.networks.mmm_body_transformer import BodyMaskedTransformer, BodyTransformerConfig, body_canvas
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE, VQConfig
from m2d2m.text import LearnedTextEncoder
from training.mmm_body_module import BodyMMMModule

SENTENCES = ["a person waves", "a person claps", "a person walks forward"]
TEXT = {"kind": "learned", "dim": 16, "layers": 1, "heads": 2, "dropout": 0.0}
NETWORK = {"width": 32, "heads": 4, "layers": 2, "cross_layers": 1, "ffn": 64, "dropout": 0.0, "max_tokens": 12}
K_UPPER, K_LOWER = 32, 24  # the two codebooks differ in size, so a mixed-up column shows


def part_vq(part: str, size: int, seed: int) -> MotionVQVAE:
    torch.manual_seed(seed)
    vq = MotionVQVAE(VQConfig(width=32, code_dim=8, codebook_size=size, depth=1, part=part))
    vq.quantizer.codebook.normal_()
    return vq.eval()


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("mmm-body")
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    upper, lower = part_vq(UPPER, K_UPPER, 0), part_vq(LOWER, K_LOWER, 1)
    VQ_FORMAT.save(folder / "upper.pt", model=upper, normalizer=normalizer, skeleton="t2m", extra={})
    VQ_FORMAT.save(folder / "lower.pt", model=lower, normalizer=normalizer, skeleton="t2m", extra={})
    config = BodyTransformerConfig(
        codebook_size=K_UPPER, code_dim=8, lower_codebook_size=K_LOWER, lower_code_dim=8, text_dim=16, **NETWORK
    )
    transformer = BodyMaskedTransformer(config, upper.codebook, lower.codebook)
    text = LearnedTextEncoder(LearnedTextEncoder.build_vocabulary(SENTENCES), dim=16, layers=1, heads=2, dropout=0.0)
    return BODY_FORMAT.save(
        folder / "model.pt",
        transformer=transformer,
        text=text,
        upper_vq=folder / "upper.pt",
        lower_vq=folder / "lower.pt",
        lengths=LengthPrior({"wave": 6}, 5, 12),
        extra={},
    )


@pytest.fixture(scope="module")
def generator(model_file) -> BodyMMMGenerator:
    return BodyMMMGenerator.load(model_file)


def source(frames: int = 32, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(frames, 263)).astype(np.float32)


def test_the_body_transformer_embeds_pairs_and_never_attends_to_padding(generator):
    transformer = generator.checkpoint.transformer
    config = transformer.config
    upper = torch.tensor([[1, config.mask_id, 3, 4], [5, 6, 0, 0]])
    lower = torch.tensor([[2, 3, config.lower_mask_id, 1], [7, 8, 0, 0]])
    inputs = body_canvas(upper, lower, torch.tensor([4, 2]), config)
    assert inputs.shape == (2, 5, 2)
    assert inputs[1, 2].tolist() == [config.end_id, config.lower_end_id]
    assert inputs[1, 3:].tolist() == [[config.pad_id, config.lower_pad_id]] * 2
    words, mask, sentence = generator.checkpoint.text_encoder.encode_pooled(SENTENCES[:2])
    logits = transformer(inputs, sentence, words, mask)
    assert logits.shape == (2, 5, K_UPPER)  # upper-body codes only
    # what stands in the padding does not change the real positions' logits
    changed = inputs.clone()
    changed[1, 4, 1] = 5
    changed[1, 4, 0] = config.pad_id
    torch.testing.assert_close(transformer(changed, sentence, words, mask)[1, :3], logits[1, :3])
    # the lower column is read: another lower token changes the logits
    other = inputs.clone()
    other[0, 0, 1] = 9
    assert not torch.allclose(transformer(other, sentence, words, mask)[0], logits[0])
    with pytest.raises(ValueError, match="token pairs"):
        transformer.embed_tokens(upper)


def test_the_training_step_scores_masked_upper_tokens_only(model_file):
    checkpoint = load_body_mmm(model_file)
    module = BodyMMMModule(
        NETWORK,
        TEXT,
        {"alpha": 0.5, "lower_most": 0.3},
        {"lr": 1e-3, "betas": [0.9, 0.99], "weight_decay": 0.0, "warmup_steps": 1, "milestones": [10], "gamma": 0.1},
        codebook=checkpoint.transformer.codebook,
        lower_codebook=checkpoint.transformer.lower_codebook,
        vocabulary=LearnedTextEncoder.build_vocabulary(SENTENCES),
    )
    pairs = torch.stack([torch.randint(0, K_UPPER, (3, 10)), torch.randint(0, K_LOWER, (3, 10))], dim=-1)
    lengths = torch.tensor([10, 7, 4])
    batch = {"tokens": pairs, "padding_mask": torch.arange(10)[None] < lengths[:, None], "text": SENTENCES}
    upper, masked, logits = module._predict(batch, torch.Generator().manual_seed(0))
    assert torch.equal(upper, pairs[..., 0]) and logits.shape == (3, 10, K_UPPER)
    assert not masked[1, 7:].any() and not masked[2, 4:].any() and masked.sum(dim=1).min() >= 1
    loss = module.training_step(batch, 0)
    assert torch.isfinite(loss) and loss.requires_grad
    with pytest.raises(ValueError, match="lower_most"):
        BodyMMMModule(
            NETWORK,
            TEXT,
            {"lower_most": 1.5},
            {},
            checkpoint.transformer.codebook,
            checkpoint.transformer.lower_codebook,
            LearnedTextEncoder.build_vocabulary(SENTENCES),
        )


def test_the_model_file_round_trips_with_both_tokenizers(model_file, generator):
    again = load_body_mmm(model_file)
    assert again.codec.upper.part == UPPER and again.codec.lower.part == LOWER
    features = source()
    pairs = again.codec.encode(features)
    assert pairs.shape == (8, 2) and int(pairs[:, 0].max()) < K_UPPER and int(pairs[:, 1].max()) < K_LOWER
    decoded = again.codec.decode(pairs)
    assert decoded.shape == (32, 263)
    with pytest.raises(ValueError, match="not an MMM model file"):
        MMMGenerator.load(model_file)  # a body file is not a whole-body MMM file, nor the other way round


class Recording:
    """A hand-set predictor in the transformer's place: every upper position's logits peak at
    ``targets``; it records the inputs of every decoding iteration."""

    def __init__(self, transformer: BodyMaskedTransformer, targets: torch.Tensor) -> None:
        self.transformer, self.targets, self.inputs = transformer, targets, []

    def __call__(self, inputs, sentence, words, word_mask):
        self.inputs.append(inputs.clone())
        logits = torch.zeros(*inputs.shape[:2], self.transformer.config.codebook_size)
        return logits.scatter_(-1, self.targets[: inputs.shape[1]].expand(inputs.shape[:2])[..., None], 50.0)


def test_the_editor_keeps_every_lower_token_and_fills_every_upper_one(generator, monkeypatch):
    features = source()
    kept = generator.codec.encode(features)
    config = generator.checkpoint.transformer.config
    targets = torch.tensor([3, 1, 4, 1, 5, 9, 2, 6, 5])  # what the predictor wants at each upper position
    recording = Recording(generator.checkpoint.transformer, targets)
    monkeypatch.setattr(generator.checkpoint.transformer, "forward", recording)
    options = generator.options(SINGLE, lower_mask=0.5)
    (motion,) = generator.generate([[SENTENCES[0]]], [[32]], options, [4], keep=[keep_part(features, T2M, LOWER)])
    assert np.array_equal(motion.tokens[:, 1], kept[:, 1].numpy())  # every lower token of the source, bit-exact
    assert np.array_equal(motion.tokens[:, 0], targets[:8].numpy())  # every upper position decoded
    assert len(recording.inputs) > 1 and motion.features.shape == (32, 263)
    lower_seen = {tuple(step[0, :8, 1].tolist()) for step in recording.inputs}
    assert len(lower_seen) == 1  # the lower condition, its [MASK]s included, is the same in every iteration
    (lower,) = lower_seen
    hidden = torch.tensor(lower) == config.lower_mask_id
    assert int(hidden.sum()) == 4  # half of the 8 lower tokens masked, the rest the source's
    assert torch.equal(torch.tensor(lower)[~hidden], kept[~hidden, 1])


def test_lower_mask_is_the_users_knob(generator):
    lower = torch.arange(20)
    assert torch.equal(masked_lower(lower, 0.0, 99, seed=1), lower)
    assert (masked_lower(lower, 1.0, 99, seed=1) == 99).all()
    assert torch.equal(masked_lower(lower, 0.3, 99, seed=1), masked_lower(lower, 0.3, 99, seed=1))
    assert int((masked_lower(lower, 0.3, 99, seed=1) == 99).sum()) == 6
    with pytest.raises(ValueError, match=r"option lower_mask must be \[0, 1\]"):
        generator.options(SINGLE, lower_mask=1.5)
    assert "25% of the lower-body tokens masked" in generator.describe(generator.options(SINGLE))


def test_requests_it_cannot_serve_are_refused(generator):
    features = source()
    with pytest.raises(ValueError, match="lower body to keep on every frame"):
        generator.generate([[SENTENCES[0]]], [[32]], generator.options(SINGLE), [0])  # nothing to keep
    with pytest.raises(ValueError, match="lower body to keep on every frame"):  # whole frames, not the lower body
        generator.generate(
            [[SENTENCES[0]]], [[32]], generator.options(SINGLE), [0], keep=[Keep(features, np.ones(32, dtype=bool))]
        )
    with pytest.raises(ValueError, match="holds 8 tokens but the request asks for 5"):
        generator.generate(
            [[SENTENCES[0]]], [[20]], generator.options(SINGLE), [0], keep=[keep_part(features, T2M, LOWER)]
        )


def test_whole_body_models_refuse_to_keep_a_part(tmp_path):
    vq = MotionVQVAE(VQConfig(width=16, code_dim=8, codebook_size=16, depth=1))
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    VQ_FORMAT.save(tmp_path / "vq.pt", model=vq, normalizer=normalizer, skeleton="t2m", extra={})
    transformer = MaskedMotionTransformer(
        MaskedTransformerConfig(codebook_size=16, code_dim=8, text_dim=16, **NETWORK), vq.codebook
    )
    text = LearnedTextEncoder(LearnedTextEncoder.build_vocabulary(SENTENCES), dim=16, layers=1, heads=2, dropout=0.0)
    whole = MMMGenerator.load(
        MMM_FORMAT.save(
            tmp_path / "model.pt",
            transformer=transformer,
            text=text,
            vq=tmp_path / "vq.pt",
            lengths=LengthPrior({}, 5, 12),
            extra={},
        )
    )
    with pytest.raises(ValueError, match="keeps whole frames, not a body part"):
        whole.generate([[SENTENCES[0]]], [[32]], whole.options(SINGLE), [0], keep=[keep_part(source(), T2M, LOWER)])
