"""Length bucketing of training batches and the loader's workers and pinned memory on a GPU
(training/data/passes.py, feed.py), on in-memory samples: no shards, no Ray, no worker processes."""

import numpy as np
import pytest
import torch
import webdataset as wds

from training.data.feed import LoaderFeed, loader_feed, require_workers
from training.data.passes import BUCKET_POOL_BATCHES, LengthBuckets
from training.data.tokens import collate_captioned_tokens

BATCH = 16
CUDA, CPU = torch.device("cuda", 0), torch.device("cpu")


def spread_samples(count: int, seed: int = 0) -> list[dict]:
    """Captioned token sequences of 10 to 49 tokens, HumanML3D's spread at 4 frames a token
    (40 to 196 frames), each keyed by its position in the stream."""
    lengths = np.random.default_rng(seed).integers(10, 50, count)
    return [
        {"tokens": np.full(length, 1), "actions": ["a"], "text": "a", "__key__": f"{index:04d}"}
        for index, length in enumerate(lengths)
    ]


def buckets(seed: int = 0, rank: int = 0) -> LengthBuckets:
    return LengthBuckets(BATCH, collate_captioned_tokens, "tokens", seed, rank)


def keys(batches: list[dict]) -> list[str]:
    return [key for batch in batches for key in batch["keys"]]


def padding_fraction(batches: list[dict]) -> float:
    padded = sum(batch["tokens"].numel() for batch in batches)
    return 1 - sum(int(batch["lengths"].sum()) for batch in batches) / padded


def test_buckets_let_out_the_samples_plain_batches_do_each_once_in_full_batches():
    """A finite stream of 2.5 pools and 5 samples: the same samples as ``wds.batched(partial=False)``
    lets out, none twice, every batch of exactly ``BATCH``."""
    samples = spread_samples(BATCH * BUCKET_POOL_BATCHES * 5 // 2 + 5)
    plain = list(wds.batched(BATCH, collation_fn=collate_captioned_tokens, partial=False)(iter(samples)))
    bucketed = list(buckets()(iter(samples)))
    assert [len(batch["keys"]) for batch in bucketed] == [BATCH] * len(plain)
    assert len(set(keys(bucketed))) == len(keys(bucketed))
    assert sorted(keys(bucketed)) == sorted(keys(plain))
    for batch in bucketed:  # the rows are the samples themselves, padded and masked
        assert batch["lengths"].tolist() == [len(samples[int(key)]["tokens"]) for key in batch["keys"]]
        assert batch["padding_mask"].sum(dim=1).tolist() == batch["lengths"].tolist()


def test_buckets_cut_the_padding_of_a_length_spread():
    samples = spread_samples(BATCH * BUCKET_POOL_BATCHES * 8)
    plain = list(wds.batched(BATCH, collation_fn=collate_captioned_tokens, partial=False)(iter(samples)))
    bucketed = list(buckets()(iter(samples)))
    assert padding_fraction(plain) > 0.25
    assert padding_fraction(bucketed) < padding_fraction(plain) / 3


def test_the_bucketed_order_is_a_function_of_seed_and_rank_and_moves_on_each_epoch():
    samples = spread_samples(BATCH * BUCKET_POOL_BATCHES * 2)

    def order(stage: LengthBuckets) -> list[str]:
        return keys(list(stage(iter(samples))))

    first = order(buckets())
    assert order(buckets()) == first
    assert order(buckets(seed=1)) != first and order(buckets(rank=1)) != first
    stage = buckets()
    assert order(stage) == first and order(stage) != first  # its Generator carries on into the next epoch


@pytest.mark.parametrize(
    "requested, device, cpus, processes, feed",
    [
        ("auto", CUDA, 16, 1, LoaderFeed(8, True)),  # capped: 8 keep a paper-size step fed
        ("auto", CUDA, 6, 1, LoaderFeed(5, True)),  # a core stays with the training process
        ("auto", CUDA, 16, 8, LoaderFeed(1, True)),  # 8 DDP ranks share the cores
        ("auto", CUDA, 2, 2, LoaderFeed(1, True)),  # never none on a GPU
        ("auto", CPU, 16, 1, LoaderFeed(0, False)),  # the CPU's step keeps its cores busy
        (3, CUDA, 16, 1, LoaderFeed(3, True)),
        (2, CPU, 16, 1, LoaderFeed(2, False)),
    ],
)
def test_the_feed_follows_the_device(requested, device, cpus, processes, feed):
    assert loader_feed(requested, device, cpus, processes) == feed


@pytest.mark.parametrize("requested", [-1, "many", True, 1.5, None])
def test_a_worker_count_that_is_no_count_is_refused(requested):
    with pytest.raises(ValueError, match="num_workers must be"):
        require_workers(requested)
