"""The text–motion evaluator: shapes, padding invariance, word features, the model file, Guo's
published checkpoint layout, the contrastive loss, and a short training run on a tiny dataset."""

from __future__ import annotations

import pickle
from pathlib import Path

import lightning.pytorch as pl
import numpy as np
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint

from m2d2m.evaluation.evaluator import (
    EVALUATOR_FORMAT,
    POS_INDEX,
    EvaluatorConfig,
    TextMotionEvaluator,
    contrastive_loss,
    learned_vocabulary,
    load_evaluator,
    load_glove,
    load_guo_checkpoint,
)
from tests.helpers import CAPTIONS, TINY_EVALUATOR
from training.evaluator_module import CaptionMotionDataModule, EvaluatorModule

D = 263
TOKENS = [line.split("#")[1].split() for line in CAPTIONS]


def tiny_evaluator(seed: int = 0, **sizes) -> TextMotionEvaluator:
    torch.manual_seed(seed)
    config = EvaluatorConfig(feature_dim=D, **{**TINY_EVALUATOR, **sizes})
    model = TextMotionEvaluator(config, learned_vocabulary(TOKENS))
    g = torch.Generator().manual_seed(seed)
    model.set_statistics(torch.randn(D, generator=g), torch.rand(D, generator=g) + 0.5)
    return model.eval()


def test_embeddings_have_the_configured_size():
    model = tiny_evaluator()
    assert model.embed_text(TOKENS).shape == (3, 8)
    assert model.embed_motion(torch.randn(3, 50, D), torch.tensor([50, 40, 4])).shape == (3, 8)
    with pytest.raises(ValueError, match="lengths"):
        model.embed_motion(torch.randn(2, 50, D), torch.tensor([50, 3]))
    with pytest.raises(ValueError, match="features"):
        model.embed_motion(torch.randn(2, 50, D - 4), torch.tensor([50, 40]))


def test_padding_after_the_length_does_not_change_the_motion_embedding():
    model = tiny_evaluator()
    g = torch.Generator().manual_seed(1)
    # 28 and 36 frames are padded to max_motion_length (48) inside; 64 frames are not padded
    features, lengths = torch.randn(3, 64, D, generator=g), torch.tensor([64, 28, 36])
    reference = model.embed_motion(features, lengths)
    padded = torch.cat([features, torch.randn(3, 20, D, generator=g)], dim=1)
    for row, length in enumerate(lengths.tolist()):
        padded[row, length:] = torch.randn(padded.shape[1] - length, D, generator=g) * 100
    torch.testing.assert_close(model.embed_motion(padded, lengths), reference)
    alone = model.embed_motion(features[1:2, :28], lengths[1:2])  # no padding at all, batch of one
    torch.testing.assert_close(alone, reference[1:2])


@pytest.mark.parametrize("length", [40, 196])
def test_motion_embedding_is_guos_computation_on_clips_zero_padded_to_196(length):
    model = tiny_evaluator(max_motion_length=196)
    features = torch.randn(1, length, D)
    x = torch.zeros(1, 196, D)
    x[:, :length] = (features - model.feature_mean) / model.feature_scale
    movement = model.movement
    latents = movement.project(movement.convs(x[..., :-4].transpose(1, 2)).transpose(1, 2))
    guo = model.motion(latents, torch.tensor([length // 4]))
    torch.testing.assert_close(model.embed_motion(features, torch.tensor([length])), guo)


def test_word_features_follow_guo():
    model = tiny_evaluator()
    words, pos, lengths = model.tokenize([["walk/VERB", "left/ADV", "and/CCONJ", "zebra/NOUN"], ["a/DET"] * 30])
    assert lengths.tolist() == [6, 22]  # sos + tokens (cropped to 20) + eos
    assert model.vocabulary[words[0, 0]] == "<sos>" and model.vocabulary[words[0, 5]] == "<eos>"
    assert model.vocabulary[words[0, 4]] == "<unk>"  # a word the vocabulary has never seen
    assert pos[0, :6].tolist() == [
        POS_INDEX[name] for name in ("OTHER", "Act_VIP", "Loc_VIP", "OTHER", "OTHER", "OTHER")
    ]
    assert pos[1, 1].item() == POS_INDEX["DET"]
    with pytest.raises(ValueError, match="word/POS"):
        model.tokenize([["walk"]])


def test_model_file_round_trip_gives_identical_embeddings(tmp_path):
    model = tiny_evaluator()
    features, lengths = torch.randn(2, 40, D), torch.tensor([40, 32])
    EVALUATOR_FORMAT.save(tmp_path / "evaluator.pt", model=model)
    loaded = load_evaluator(tmp_path / "evaluator.pt")
    assert loaded.config == model.config and loaded.vocabulary == model.vocabulary
    assert torch.equal(loaded.embed_text(TOKENS), model.embed_text(TOKENS))
    assert torch.equal(loaded.embed_motion(features, lengths), model.embed_motion(features, lengths))
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not an evaluator model file"):
        load_evaluator(tmp_path / "other.pt")


def test_contrastive_loss_pulls_matches_and_pushes_shifted_pairs():
    text = torch.tensor([[0.0, 0.0], [3.0, 4.0]])
    terms = contrastive_loss(text, text.clone(), shift=1, margin=10.0)
    assert terms.positive.item() == pytest.approx(0.0, abs=1e-6)
    assert terms.negative.item() == pytest.approx(25.0, abs=1e-3)  # (10 − 5)²
    with pytest.raises(ValueError, match="shift"):
        contrastive_loss(text, text, shift=0)


def test_a_few_steps_lower_the_contrastive_loss(one_torch_thread):
    model = tiny_evaluator().train()
    model.movement.convs[1].p = model.movement.convs[4].p = 0.0  # no dropout noise in the comparison
    captions = [[f"{w}/NOUN", "walk/VERB"] for w in ("a", "man", "person", "spot", "hand", "someone")]
    features, lengths = torch.randn(6, 40, D), torch.tensor([40, 36, 32, 28, 24, 40])
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)

    def loss() -> torch.Tensor:
        return contrastive_loss(model.embed_text(captions), model.embed_motion(features, lengths), 2, 1.0).total

    before = loss().item()
    for _ in range(30):
        optimizer.zero_grad()
        loss().backward()
        optimizer.step()
    assert loss().item() < 0.5 * before


# --------------------------------------------------------------------------------------------------
# Guo's published evaluator


def guo_weights(feature_dim: int = D) -> dict[str, dict[str, torch.Tensor]]:
    """Random weights under the names and shapes of Guo's ``finest.tar``, written out here
    independently of the evaluator's own modules."""
    g = torch.Generator().manual_seed(0)

    def bigru(input_dim: int, hidden: int, out: int, extra: dict) -> dict[str, tuple[int, ...]]:
        shapes = {
            "input_emb.weight": (hidden, input_dim),
            "input_emb.bias": (hidden,),
            "hidden": (2, 1, hidden),
            "output_net.0.weight": (hidden, 2 * hidden),
            "output_net.0.bias": (hidden,),
            "output_net.1.weight": (hidden,),
            "output_net.1.bias": (hidden,),
            "output_net.3.weight": (out, hidden),
            "output_net.3.bias": (out,),
            **extra,
        }
        for suffix in ("", "_reverse"):
            shapes |= {
                f"gru.weight_ih_l0{suffix}": (3 * hidden, hidden),
                f"gru.weight_hh_l0{suffix}": (3 * hidden, hidden),
                f"gru.bias_ih_l0{suffix}": (3 * hidden,),
                f"gru.bias_hh_l0{suffix}": (3 * hidden,),
            }
        return shapes

    shapes = {
        "movement_encoder": {
            "main.0.weight": (512, feature_dim - 4, 4),
            "main.0.bias": (512,),
            "main.3.weight": (512, 512, 4),
            "main.3.bias": (512,),
            "out_net.weight": (512, 512),
            "out_net.bias": (512,),
        },
        "text_encoder": bigru(300, 512, 512, {"pos_emb.weight": (300, 15), "pos_emb.bias": (300,)}),
        "motion_encoder": bigru(512, 1024, 512, {}),
    }
    return {
        module: {key: 0.02 * torch.randn(shape, generator=g) for key, shape in layers.items()}
        for module, layers in shapes.items()
    }


@pytest.fixture
def guo_files(tmp_path):
    """Guo's layout: checkpoints/t2m/text_mot_match/{model/finest.tar, meta/}, and glove/."""
    run = tmp_path / "checkpoints" / "t2m" / "text_mot_match"
    (run / "model").mkdir(parents=True)
    (run / "meta").mkdir()
    weights = guo_weights()
    torch.save({**weights, "epoch": 7, "niter": 1234}, run / "model" / "finest.tar")
    np.save(run / "meta" / "mean.npy", np.linspace(-1, 1, D).astype(np.float32))
    np.save(run / "meta" / "std.npy", np.linspace(0.5, 2, D).astype(np.float32))
    glove = tmp_path / "glove"
    glove.mkdir()
    words = ["sos", "eos", "unk", "a", "person", "walk", "forward", "left"]
    np.save(glove / "our_vab_data.npy", np.random.default_rng(0).normal(size=(len(words), 300)).astype(np.float32))
    (glove / "our_vab_words.pkl").write_bytes(pickle.dumps(words))
    (glove / "our_vab_idx.pkl").write_bytes(pickle.dumps({w: i for i, w in enumerate(words)}))
    return run, glove, weights


def test_guo_checkpoint_loads_into_the_evaluator(guo_files, tmp_path):
    run, glove, weights = guo_files
    model = load_guo_checkpoint(run, glove, run / "meta")
    assert model.config == EvaluatorConfig(feature_dim=D, word_features="glove")
    assert torch.equal(model.motion.initial_hidden, weights["motion_encoder"]["hidden"])
    assert torch.equal(model.movement.convs[3].weight, weights["movement_encoder"]["main.3.weight"])
    assert torch.equal(model.text.pos_projection.weight, weights["text_encoder"]["pos_emb.weight"])
    assert torch.allclose(model.feature_scale, torch.linspace(0.5, 2, D))
    assert not model.words.weight.requires_grad
    captions = [["a/DET", "person/NOUN", "walk/VERB", "forward/ADV"], ["someone/PRON", "jump/VERB"]]
    features, lengths = torch.randn(2, 60, D), torch.tensor([60, 40])
    text, motion = model.embed_text(captions), model.embed_motion(features, lengths)
    assert text.shape == motion.shape == (2, 512)
    EVALUATOR_FORMAT.save(tmp_path / "guo.pt", model=model)  # the GloVe table travels in the file
    loaded = load_evaluator(tmp_path / "guo.pt")
    assert torch.equal(loaded.embed_text(captions), text)
    assert torch.equal(loaded.embed_motion(features, lengths), motion)


def test_guo_checkpoint_of_other_shapes_is_refused_clearly(guo_files):
    run, glove, _ = guo_files
    kit = guo_weights(feature_dim=251)  # a KIT-ML evaluator with HumanML3D's statistics
    torch.save(kit, run / "model" / "finest.tar")
    with pytest.raises(
        ValueError,
        match=r"movement_encoder\.main\.0\.weight has shape \(512, 247, 4\), "
        r"expected \(512, 259, 4\)",
    ):
        load_guo_checkpoint(run, glove, run / "meta")
    del kit["motion_encoder"]
    torch.save(kit, run / "model" / "finest.tar")
    with pytest.raises(ValueError, match="lacks motion_encoder"):
        load_guo_checkpoint(run, glove, run / "meta")
    with pytest.raises(FileNotFoundError, match="our_vab_data.npy"):
        load_guo_checkpoint(run, run, run / "meta")


# --------------------------------------------------------------------------------------------------
# Training


def test_training_runs_end_to_end_on_a_tiny_dataset(tiny_data, tmp_path, one_torch_thread):
    datamodule = CaptionMotionDataModule(
        tiny_data, batch_size=4, num_workers=0, steps_per_epoch=3, val_batch_size=4, min_frames=40, seed=0
    )
    assert datamodule.train_clips > 0 and all("/" in t for c in datamodule.train_captions() for t in c)
    batch = next(iter(datamodule.train_dataloader()))
    assert batch["motion"].shape[0] == 4 and all(int(n) % 4 == 0 and int(n) >= 36 for n in batch["lengths"])
    pl.seed_everything(0, verbose=False)
    module = EvaluatorModule(
        model=dict(TINY_EVALUATOR),
        optim={"lr": 1e-3, "betas": [0.9, 0.999], "weight_decay": 0.0},
        loss={"margin": 10.0},
        feature_dim=datamodule.feature_dim,
        vocabulary=learned_vocabulary(datamodule.train_captions()),
    )
    module.set_normalizer(datamodule.normalizer)
    checkpoints = ModelCheckpoint(dirpath=tmp_path, filename="best", monitor="val/loss", mode="min")
    trainer = pl.Trainer(
        max_steps=6,
        accelerator="cpu",
        devices=1,
        logger=False,
        callbacks=[checkpoints],
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        gradient_clip_val=0.5,
        default_root_dir=tmp_path,
    )
    trainer.fit(module, datamodule=datamodule)
    metrics = trainer.callback_metrics
    assert all(torch.isfinite(metrics[name]) for name in ("train/loss", "val/loss", "val/matching_score"))
    assert 0.0 <= float(metrics["val/top1"]) <= 1.0
    assert checkpoints.best_model_path.endswith("best.ckpt")
    EVALUATOR_FORMAT.save(tmp_path / "evaluator.pt", **module.model_parts())
    loaded = load_evaluator(tmp_path / "evaluator.pt")
    assert torch.equal(loaded.feature_scale, torch.as_tensor(datamodule.normalizer.scale))


class _RunsCode:
    """A pickled object whose unpickling would call a function (here: create a file), as a
    tampered file could."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


@pytest.mark.parametrize("index", [{"a": np.int64(0), "person": np.int64(1)}, {"a": 0, "person": 1}])
def test_the_word_index_reader_takes_plain_and_numpy_rows(tmp_path, index):
    np.save(tmp_path / "our_vab_data.npy", np.zeros((2, 300), dtype=np.float32))
    (tmp_path / "our_vab_idx.pkl").write_bytes(pickle.dumps(index))
    assert load_glove(tmp_path)[0] == ["a", "person"]


def test_a_word_index_that_would_run_code_is_refused(tmp_path):
    marker = tmp_path / "created-by-the-pickle"
    np.save(tmp_path / "our_vab_data.npy", np.zeros((1, 300), dtype=np.float32))
    (tmp_path / "our_vab_idx.pkl").write_bytes(pickle.dumps({"a": _RunsCode(marker)}))
    with pytest.raises(ValueError, match="not a word index .*holds words and rows only"):
        load_glove(tmp_path)
    assert not marker.exists()
