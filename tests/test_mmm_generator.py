"""MMM's generator (m2d2m/generators/mmm/generator.py) on a tiny random model file: lengths, transitions,
editing, batch independence and the model file's round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from m2d2m.generators.mmm.checkpoint import MMM_FORMAT, load_mmm
from m2d2m.generators.mmm.generator import MMMGenerator
from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.generators.protocol import Keep
from m2d2m.model_files import LengthPrior
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig, canvas
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE
from m2d2m.text import LearnedTextEncoder
from tests.helpers import TINY_VQ

SENTENCES = ["a person walks forward", "a person jumps", "a person sits down"]
TEXT = {"kind": "learned", "dim": 16, "layers": 1, "heads": 2, "dropout": 0.0}


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("mmm")
    torch.manual_seed(0)
    vq = MotionVQVAE(TINY_VQ)
    vq.quantizer.codebook.normal_()
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    VQ_FORMAT.save(folder / "vq.pt", model=vq, normalizer=normalizer, skeleton="t2m", extra={})
    config = MaskedTransformerConfig(
        codebook_size=32,
        code_dim=16,
        width=32,
        heads=4,
        layers=2,
        cross_layers=1,
        ffn=64,
        dropout=0.0,
        text_dim=16,
        max_tokens=12,
    )
    transformer = MaskedMotionTransformer(config, vq.codebook)
    text = LearnedTextEncoder(LearnedTextEncoder.build_vocabulary(SENTENCES), dim=16, layers=1, heads=2, dropout=0.0)
    lengths = LengthPrior({"walk": 6}, 5, 12)
    return MMM_FORMAT.save(
        folder / "model.pt", transformer=transformer, text=text, vq=folder / "vq.pt", lengths=lengths, extra={}
    )


@pytest.fixture(scope="module")
def generator(model_file) -> MMMGenerator:
    return MMMGenerator.load(model_file)


def test_the_model_file_round_trips(model_file, generator):
    again = load_mmm(model_file)
    config = again.transformer.config
    tokens = canvas(torch.tensor([[1, config.mask_id, 3]]), torch.tensor([3]), config)
    words, mask, sentence = again.text_encoder.encode_pooled(["a person jumps"])
    torch.testing.assert_close(
        again.transformer(tokens, sentence, words, mask),
        generator.checkpoint.transformer(tokens, sentence, words, mask),
    )
    assert generator.typical_frames("walk") == 24 and generator.longest_frames == 48


def test_one_action_is_as_long_as_asked(generator):
    (motion,) = generator.generate([[SENTENCES[0]]], [[22]], generator.options(SINGLE), [0])
    assert len(motion.features) == 20 and motion.ranges == [(0, 20)]  # 22 frames round to 5 tokens
    assert ((motion.tokens >= 0) & (motion.tokens < 32)).all()


def test_transitions_join_shortened_actions_to_the_asked_length(generator):
    (motion,) = generator.generate([SENTENCES], [[20, 20, 20]], generator.options(MULTI), [1])
    # 5 tokens, then 2 transition tokens and 3 (5 − 2) for each later action: 15 tokens, 60 frames
    assert len(motion.tokens) == 15 and len(motion.features) == 60
    assert motion.ranges == [(0, 20), (28, 40), (48, 60)]
    assert motion.boundaries == [24, 44]  # the middle of each transition
    (independent,) = generator.generate(
        [SENTENCES], [[20, 20, 20]], generator.options(MULTI, method="independent"), [1]
    )
    assert independent.ranges == [(0, 20), (20, 40), (40, 60)]


def test_kept_tokens_come_back_bit_exact(generator):
    features = np.random.default_rng(0).normal(size=(32, 263)).astype(np.float32)
    frames = np.zeros(32, dtype=bool)
    frames[:8] = frames[-8:] = True  # in-betweening: keep the first and last 2 tokens
    kept = generator.codec.encode(features)
    (motion,) = generator.generate(
        [[SENTENCES[1]]], [[32]], generator.options(SINGLE), [2], keep=[Keep(features, frames)]
    )
    assert np.array_equal(motion.tokens[[0, 1, 6, 7]], kept[[0, 1, 6, 7]].numpy())
    with pytest.raises(ValueError, match="one action at a time"):
        generator.generate(
            [SENTENCES[:2]],
            [[32, 20]],
            generator.options(MULTI),
            [2],
            keep=[Keep(np.zeros((52, 263), np.float32), np.zeros(52, dtype=bool))],
        )


def test_a_sequence_does_not_depend_on_its_batch(generator):
    options = generator.options(MULTI)
    both = generator.generate([SENTENCES, SENTENCES[1:]], [[16, 20, 24], [28, 12]], options, [5, 6])
    alone = generator.generate([SENTENCES[1:]], [[28, 12]], options, [6])
    assert np.array_equal(both[1].tokens, alone[0].tokens)


def test_requests_it_cannot_serve_are_refused(generator):
    with pytest.raises(ValueError, match="at most 12 tokens"):
        generator.generate([[SENTENCES[0]]], [[60]], generator.options(SINGLE), [0])
    with pytest.raises(ValueError, match="option transition must be >= 1"):
        generator.options(MULTI, transition=0)
    assert "2 transition tokens" in generator.describe(generator.options(MULTI))
