"""The denoiser's DataModule on a tiny token set made by the real pipelines (Ray, local, 2 CPUs)."""

import logging
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import webdataset as wds

from m2d2m.motion.representation.skeleton import T2M
from pipelines.features import DataConfig, build_dataset
from pipelines.tokenize import tokenize_dataset
from tests.helpers import random_vq, write_corpus
from training.data.feed import LoaderFeed
from training.data.tokens import CaptionSampler, TokenDataModule, caption_span

KICK_SHORT = "a person kicks#a/DET person/NOUN kick/VERB#0.5#0.55"  # shorter than a token: widened to one
KICK_LATE = "a person kicks#a/DET person/NOUN kick/VERB#20.0#30.0"  # past every clip's end: whole clip


@pytest.fixture(scope="module")
def token_set(tmp_path_factory, ray_local):
    """Tokens of 6 train motions (12 clips with mirrors, 3 shards), 3 val (6 clips, 2 shards) and
    2 test; train clip 000000 has only a caption past its end, val clip 000006 starts with a
    sub-token segment, 000007 with one past its end, 000008 with the 0.5–2.0 s one. Returns the
    token directory and every split's clips read back: {key: (tokens, meta)}, in shard order."""
    root = tmp_path_factory.mktemp("token-data")
    raw = root / "raw"
    write_corpus(raw, {"train": 6, "val": 3, "test": 2}, T2M)
    captions = (raw / "texts" / "000006.txt").read_text().splitlines()
    (raw / "texts" / "000000.txt").write_text(KICK_LATE + "\n")
    (raw / "texts" / "000006.txt").write_text("\n".join([KICK_SHORT, *captions]) + "\n")
    (raw / "texts" / "000007.txt").write_text("\n".join([KICK_LATE, *captions]) + "\n")
    (raw / "texts" / "000008.txt").write_text("\n".join([captions[2], *captions[:2]]) + "\n")
    data = root / "data"
    build_dataset(DataConfig(dataset="synthetic", raw=str(raw), out=str(data), samples_per_shard=4, workers=2))
    random_vq(root / "vq.pt", data, seed=0)
    manifest = tokenize_dataset(data, root / "vq.pt", root / "tokens", workers=2)
    clips = {
        split: {
            s["__key__"]: (s["tokens.npy"], s["meta.json"])
            for s in wds.WebDataset(
                [str(root / "tokens" / s["name"]) for s in manifest["shards"][split]], shardshuffle=False
            ).decode()
        }
        for split in ("train", "val", "test")
    }
    return root / "tokens", clips


def expected_span(caption: dict, num_tokens: int) -> tuple[int, int]:
    """T2M-GPT's cut at 20 fps and 4 frames a token, written out independently of the module."""
    if caption["start"] == caption["end"] == 0:
        return 0, num_tokens
    first = int(caption["start"] * 20 / 4)
    last = min(max(int(caption["end"] * 20 / 4), first + 1), num_tokens)
    return (first, last) if first < last else (0, num_tokens)


def check_batch(batch: dict, clips: dict, first_caption: bool = False, max_tokens: int | None = None) -> list[dict]:
    """Every row is its caption's segment of one of ``clips`` (or a crop of it to ``max_tokens``),
    padded with 0 and masked; returns the captions seen."""
    assert set(batch) == {"tokens", "padding_mask", "lengths", "actions", "text", "keys"}
    tokens, mask, lengths = batch["tokens"], batch["padding_mask"], batch["lengths"]
    size = len(batch["keys"])
    assert tokens.dtype == torch.long and mask.dtype == torch.bool and lengths.dtype == torch.long
    assert tokens.shape == mask.shape == (size, int(lengths.max())) and lengths.shape == (size,)
    assert len(batch["actions"]) == len(batch["text"]) == size
    seen = []
    for row, valid, length, key, text, actions in zip(
        tokens.numpy(), mask.numpy(), lengths.tolist(), batch["keys"], batch["text"], batch["actions"]
    ):
        assert key in clips, f"{key} is not a clip of this split"
        codes, meta = clips[key]
        matching = [c for c in meta["captions"] if c["text"] == text]
        assert matching, f"{text!r} is no caption of {key}"
        caption = meta["captions"][0] if first_caption else matching[0]
        assert caption["text"] == text and actions == (caption["actions"] or [text])
        assert valid.tolist() == [True] * length + [False] * (len(row) - length) and not row[length:].any()
        first, last = expected_span(caption, len(codes))
        segment = codes[first:last].astype(np.int64)
        if max_tokens is None:
            np.testing.assert_array_equal(row[:length], segment)
        else:
            assert length == min(max_tokens, len(segment))
            assert any(np.array_equal(row[:length], segment[s : s + length]) for s in range(len(segment) - length + 1))
        seen.append(caption)
    return seen


def test_the_manifest_facts_are_exposed(token_set):
    tokens, clips = token_set
    module = TokenDataModule(tokens, batch_size=3)
    assert (module.codebook_size, module.frames_per_token, module.fps) == (32, 4, 20.0)
    assert module.vq_file == tokens / "vq.pt" and module.vq_file.exists() and module.manifest["kind"] == "tokens"
    assert module.train_clips == len(clips["train"]) == 12 and module.steps_per_epoch == 12 // 3
    assert module.empty_segments == 2  # 000000 and its mirror
    for key, (codes, meta) in clips["train"].items():
        assert len(codes) == math.ceil(meta["frames"] / 4)


def test_training_batches_are_random_captions_with_their_token_segments(token_set, caplog):
    tokens, clips = token_set
    module = TokenDataModule(tokens, batch_size=3, num_workers=2)
    with caplog.at_level(logging.INFO):
        loader = module.train_dataloader()
    assert any("2 of 32 train captions" in record.message for record in caplog.records)
    assert len(loader) == module.steps_per_epoch == 4
    captions, keys = [], set()
    for _ in range(3):  # persistent workers: every epoch has the same length
        batches = list(loader)
        assert len(batches) == 4 and all(len(batch["keys"]) == 3 for batch in batches)
        for batch in batches:
            captions += check_batch(batch, clips["train"])
            keys |= set(batch["keys"])
    assert keys.isdisjoint(clips["val"].keys() | clips["test"].keys())
    assert len({c["text"] for c in captions}) > 2  # captions are drawn, not always the first
    cut = [c for c in captions if (c["start"], c["end"]) == (0.5, 2.0)]
    assert cut, "no caption with a start/end segment was drawn"  # its rows hold tokens [2:10], checked above


def test_max_tokens_crops_each_segment_at_random(token_set):
    tokens, clips = token_set
    module = TokenDataModule(tokens, batch_size=4, num_workers=2, steps_per_epoch=5, max_tokens=5)
    batches = list(module.train_dataloader())
    assert len(batches) == 5
    for batch in batches:
        check_batch(batch, clips["train"], max_tokens=5)
    assert max(int(batch["lengths"].max()) for batch in batches) == 5


def test_validation_reads_every_clip_once_with_its_first_caption_in_shard_order(token_set):
    tokens, clips = token_set
    module = TokenDataModule(tokens, val_batch_size=4, num_workers=2)
    passes = [list(module.val_dataloader()) for _ in range(2)]
    keys = [key for batch in passes[0] for key in batch["keys"]]
    assert keys == list(clips["val"]) == [key for batch in passes[1] for key in batch["keys"]]
    lengths = {}
    for batch in passes[0]:
        check_batch(batch, clips["val"], first_caption=True)
        lengths |= dict(zip(batch["keys"], batch["lengths"].tolist()))
    # The first captions: 0.5–0.55 s is one token ([2:3]), 20–30 s lies past the clip (whole
    # clip), 0.5–2.0 s is tokens [2:10].
    for key in ("000006", "M000006"):
        assert lengths[key] == 1
    for key in ("000007", "M000007"):
        assert lengths[key] == len(clips["val"][key][0])
    for key in ("000008", "M000008"):
        assert lengths[key] == 8
    test_keys = [key for batch in module.test_dataloader() for key in batch["keys"]]
    assert test_keys == list(clips["test"])


def test_ranks_run_equal_epochs_and_share_validation(token_set, monkeypatch):
    tokens, clips = token_set
    shares = []
    for rank in (0, 1):
        monkeypatch.setenv("RANK", str(rank))
        monkeypatch.setenv("WORLD_SIZE", "2")
        module = TokenDataModule(tokens, batch_size=3, val_batch_size=2, num_workers=2)
        batches = list(module.train_dataloader())
        assert module.steps_per_epoch == len(batches) == 12 // (3 * 2)
        for batch in batches:
            check_batch(batch, clips["train"])
        shares.append([key for batch in module.val_dataloader() for key in batch["keys"]])
    assert len(shares[0]) == len(shares[1]) == 3 and sorted(shares[0] + shares[1]) == sorted(clips["val"])


def test_training_batches_are_bucketed_by_length(token_set):
    """Over the same 40 batches, bucketing pads less; every batch is still full and holds its
    captions' segments (``check_batch``)."""
    tokens, clips = token_set

    def padding(bucket: bool) -> float:
        module = TokenDataModule(tokens, batch_size=3, num_workers=0, steps_per_epoch=40, bucket=bucket)
        batches = list(module.train_dataloader())
        assert len(batches) == 40 and all(len(batch["keys"]) == 3 for batch in batches)
        for batch in batches:
            check_batch(batch, clips["train"])
        return 1 - sum(int(b["lengths"].sum()) for b in batches) / sum(b["tokens"].numel() for b in batches)

    plain = padding(bucket=False)
    assert plain > 0.1 and padding(bucket=True) < plain / 2


@pytest.mark.parametrize("workers", [0, 2])
def test_the_bucketed_stream_is_a_function_of_the_seed(token_set, workers):
    """Two loaders of one config give the same batches, epoch after epoch; another seed others."""

    def batches(seed: int) -> list[list[str]]:
        module = TokenDataModule(token_set[0], batch_size=3, num_workers=workers, steps_per_epoch=8, seed=seed)
        loader = module.train_dataloader()
        return [batch["keys"] + batch["text"] for _ in range(2) for batch in loader]

    first = batches(7)
    assert batches(7) == first and batches(8) != first


def test_the_loaders_pin_and_start_workers_when_the_trainer_trains_on_a_gpu(token_set, monkeypatch):
    """The feed a DataModule takes from the trainer Lightning attaches (a stand-in naming a GPU: the
    decision needs none); ``auto`` means no workers on a CPU, as the demo configs' 0 did."""
    monkeypatch.setattr("training.data.shard_module.usable_cpus", lambda: 16)
    module = TokenDataModule(token_set[0], num_workers="auto")
    assert module.feed() == LoaderFeed(0, pin_memory=False)
    module.trainer = SimpleNamespace(strategy=SimpleNamespace(root_device=torch.device("cuda", 0)), num_devices=2)
    assert module.feed() == LoaderFeed(7, pin_memory=True)  # 14 cores left for 2 ranks
    module.trainer.strategy.root_device = torch.device("cpu")
    assert module.feed() == LoaderFeed(0, pin_memory=False)
    with pytest.raises(ValueError, match="num_workers must be"):
        TokenDataModule(token_set[0], num_workers="many")


def test_caption_choices_depend_on_seed_rank_and_worker_only():
    captions = [{"text": str(i), "start": 0.0, "end": 0.0, "actions": []} for i in range(5)]
    samples = [{"tokens.npy": np.arange(10), "meta.json": {"fps": 20.0, "captions": captions}}] * 30

    def choices(seed, rank):
        sampler = CaptionSampler(4, None, seed, rank)
        return [sampler(sample)["text"] for sample in samples]

    np.random.seed(1)
    first = choices(0, 0)
    np.random.seed(2)
    assert choices(0, 0) == first and choices(0, 1) != first and choices(1, 0) != first
    chosen = CaptionSampler(4, None, 0, 0)(samples[0])
    assert chosen["actions"] == [chosen["text"]]  # a caption without action sentences conditions as a whole


@pytest.mark.parametrize(
    "start, end, span",
    [
        (0.0, 0.0, (0, 20)),
        (0.5, 2.0, (2, 10)),
        (0.5, 0.55, (2, 3)),
        (1.0, 9.0, (5, 20)),
        (4.0, 5.0, None),
        (2.0, 1.0, None),
        (0.0, 0.1, (0, 1)),
    ],
)
def test_caption_span_follows_t2m_gpt(start, end, span):
    assert caption_span({"start": start, "end": end}, 20, 20.0, 4) == span


def test_a_missing_or_foreign_manifest_says_what_to_run(token_set, tmp_path):
    tokens, _ = token_set
    with pytest.raises(FileNotFoundError, match="m2d2m tokenize.*make tokens"):
        TokenDataModule(tmp_path)
    with pytest.raises(ValueError, match="not a token set"):
        TokenDataModule(tokens.parent / "data")  # a processed dataset, not its tokens
    with pytest.raises(ValueError, match="max_tokens must be a positive"):
        TokenDataModule(tokens, max_tokens=0)
