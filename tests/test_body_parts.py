"""The body split (m2d2m/motion/representation/body_parts.py) and the part tokenizers it gives
(VQConfig.part, the VQ module's part losses, Keep of a part)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from m2d2m.generators.protocol import keep_part
from m2d2m.motion.representation.body_parts import (
    FULL,
    LOWER,
    PARTS,
    UPPER,
    joint_dims,
    merge,
    part_dims,
    part_joints,
    split,
)
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import KIT, T2M
from m2d2m.networks.config import ConfigError
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE, VQConfig, load_vq
from tests.helpers import TINY_VQ_RUN
from training.vq_module import VQVAEModule


@pytest.mark.parametrize("skeleton, upper, lower", [(T2M, 156, 107), (KIT, 120, 131)])
def test_the_parts_partition_the_features_with_mmms_sizes(skeleton, upper, lower):
    dims = {part: part_dims(skeleton, part) for part in PARTS}
    assert (len(dims[UPPER]), len(dims[LOWER])) == (upper, lower)
    assert np.array_equal(np.sort(np.concatenate(list(dims.values()))), np.arange(skeleton.feature_dim))
    # the root's 4 dimensions and the 4 foot contacts go with the lower body
    root_and_contacts = [0, 1, 2, 3, *range(skeleton.feature_dim - 4, skeleton.feature_dim)]
    assert set(root_and_contacts) <= set(dims[LOWER].tolist())
    assert np.array_equal(part_dims(skeleton, FULL), np.arange(skeleton.feature_dim))
    joints = np.concatenate([part_joints(skeleton, part) for part in PARTS])
    assert sorted(joints.tolist()) == list(range(skeleton.num_joints))


def test_a_joints_dimensions_follow_the_feature_layout():
    # T2M: RIC of joint j at 4 + 3(j−1), rotation at 67 + 6(j−1), velocity at 193 + 3j
    assert joint_dims(T2M, 0).tolist() == [193, 194, 195]
    assert joint_dims(T2M, 21).tolist() == [64, 65, 66, *range(187, 193), 256, 257, 258]
    assert 0 in part_joints(T2M, LOWER) and 15 in part_joints(T2M, UPPER)  # pelvis below, head above
    with pytest.raises(ValueError, match="joints 0..21"):
        joint_dims(T2M, 22)


@pytest.mark.parametrize("skeleton", [T2M, KIT])
def test_split_and_merge_round_trip(skeleton):
    features = np.random.default_rng(0).normal(size=(5, 7, skeleton.feature_dim)).astype(np.float32)
    parts = split(features, skeleton)
    assert parts[UPPER].shape == (5, 7, len(part_dims(skeleton, UPPER)))
    assert np.array_equal(merge(parts, skeleton), features)
    with pytest.raises(ValueError, match="lower missing"):
        merge({UPPER: parts[UPPER]}, skeleton)
    with pytest.raises(ValueError, match="unknown body part 'arms'"):
        part_dims(skeleton, "arms")


def test_a_part_tokenizer_reads_the_whole_body_and_writes_its_part(tmp_path):
    model = MotionVQVAE(VQConfig(width=16, code_dim=8, codebook_size=16, depth=1, part=LOWER))
    features = torch.randn(2, 16, 263)
    out = model(features)
    assert out.reconstruction.shape == (2, 16, 107) and out.tokens.shape == (2, 4)
    # the upper body's dimensions do not reach the encoder: changing them leaves the tokens alone
    changed = features.clone()
    changed[..., part_dims(T2M, UPPER)] += 5.0
    model.eval()
    assert torch.equal(model.encode(features), model.encode(changed))
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    VQ_FORMAT.save(tmp_path / "vq.pt", model=model, normalizer=normalizer, skeleton="t2m", extra={})
    _, _, meta = load_vq(tmp_path / "vq.pt")
    assert meta["part"] == LOWER  # the file says which part it tokenizes
    with pytest.raises(ConfigError, match="part must be one of"):
        VQConfig(part="arms")
    with pytest.raises(ConfigError, match="no skeleton has 100-d features"):
        VQConfig(feature_dim=100, part=UPPER)


def test_a_part_tokenizer_is_trained_on_its_part_alone():
    module = VQVAEModule({**TINY_VQ_RUN["model"], "part": UPPER}, TINY_VQ_RUN["optim"], TINY_VQ_RUN["loss"], 263, "t2m")
    x = torch.randn(2, 32, 263)
    losses = module._losses(x)
    assert torch.isfinite(losses["loss"])
    # the loss reads the upper body's dimensions only: the lower body's targets change nothing
    changed = x.clone()
    changed[..., part_dims(T2M, LOWER)] = 9.0
    module.model.eval()
    assert torch.equal(module._losses(x)["recon"], module._losses(changed)["recon"])
    # its position term covers the RIC positions of the 13 upper joints, 3 each
    assert len(module.positions) == 3 * 13 and module.joints.tolist() == part_joints(T2M, UPPER).tolist()


def test_keep_part_keeps_a_part_on_every_frame():
    features = np.zeros((12, 263), np.float32)
    keep = keep_part(features, T2M, LOWER)
    assert keep.frames.all() and keep.dims.sum() == 107 and not keep.whole_frames
    with pytest.raises(ValueError, match="one boolean per feature dimension"):
        type(keep)(features, keep.frames, np.ones(5, dtype=bool))
