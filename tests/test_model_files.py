"""One way to write and read a model file (m2d2m/model_files.py): a kind's parts registered by
name come back from its file as they went in, inline parts keep the payload's layout, a text
encoder is recorded by the options it was constructed with, and a save that misses or invents a
part is refused before anything is written."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from m2d2m.model_files import PLAIN, Float32, LengthPrior, Lengths, ModelFileKind, Network, Normalization, Text
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.vqvae import MotionVQVAE, VQConfig
from m2d2m.text import LearnedTextEncoder
from tests.helpers import TINY_VQ

KIND = ModelFileKind(
    "test-kind/1",
    "a test model file",
    {
        "network": Network.of(MotionVQVAE, VQConfig),
        "text": Text(),
        "codebook": Float32(),
        "normalizer": Normalization(),
        "lengths": Lengths(),
        "extra": PLAIN,
    },
    inline=frozenset({"normalizer"}),
)


def parts() -> dict:
    torch.manual_seed(0)
    network = MotionVQVAE(TINY_VQ).eval()
    text = LearnedTextEncoder(LearnedTextEncoder.build_vocabulary(["a person walks"]), dim=16, layers=1, heads=2)
    normalizer = Normalizer(np.linspace(-1, 1, 263), np.linspace(0.5, 2, 263), 4.0)
    codebook = torch.randn(8, 4, dtype=torch.float64)
    return {
        "network": network,
        "text": text.eval(),
        "codebook": codebook,
        "normalizer": normalizer,
        "lengths": LengthPrior({"walk": 6}, 5, 12),
        "extra": {"run": "abc"},
    }


def test_every_part_comes_back_as_it_went_in(tmp_path):
    given = parts()
    loaded = KIND.load(KIND.save(tmp_path / "model.pt", **given))
    motion = torch.randn(1, 16, 263)
    with torch.no_grad():
        assert torch.equal(loaded["network"](motion).reconstruction, given["network"](motion).reconstruction)
        assert not loaded["network"].training and not loaded["text"].training
        features, mask = loaded["text"].encode(["a person walks"])
        expected, _ = given["text"].encode(["a person walks"])
    assert torch.equal(features, expected) and mask.all()
    assert loaded["codebook"].dtype == torch.float32 and torch.equal(loaded["codebook"], given["codebook"].float())
    np.testing.assert_array_equal(loaded["normalizer"].scale, given["normalizer"].scale)
    assert loaded["normalizer"].feat_bias == 4.0
    assert loaded["lengths"] == given["lengths"] and loaded["extra"] == {"run": "abc"}


def test_inline_parts_keep_their_keys_at_the_top_and_text_records_its_constructor(tmp_path):
    payload = KIND.read(KIND.save(tmp_path / "model.pt", **parts()))
    assert {"mean", "std", "feat_bias"} <= set(payload) and "normalizer" not in payload
    assert set(payload["network"]) == {"config", "state_dict"}
    text = payload["text"]
    assert text["kind"] == "learned"
    assert text["options"] == {"dim": 16, "layers": 1, "heads": 2, "dropout": 0.1, "max_length": 77}


@pytest.mark.parametrize(
    ("change", "refusal"),
    [
        (lambda given: given.pop("lengths"), r"parts missing \['lengths'\], unknown \[\]"),
        (lambda given: given.update(sampling={}), r"parts missing \[\], unknown \['sampling'\]"),
    ],
)
def test_a_save_that_misses_or_invents_a_part_is_refused_with_nothing_written(tmp_path, change, refusal):
    given = parts()
    change(given)
    with pytest.raises(TypeError, match=f"a test model file: {refusal}"):
        KIND.save(tmp_path / "model.pt", **given)
    assert not list(tmp_path.iterdir())
