"""Bad input to the tool verbs (render, export, tokenize --vq) is one line on stderr and exit
status 2, never a traceback: motions that cannot be drawn, non-positive frame rates, and VQ model
files that are truncated, foreign or do not fit the model. And training's progress bar counts the
steps it is bounded by instead of printing "Epoch 0/-2"."""

from __future__ import annotations

import warnings
from pathlib import Path

import lightning.pytorch as pl
import numpy as np
import pytest
import torch
from lightning.pytorch.callbacks import RichProgressBar

from m2d2m.generators.m2d2m.checkpoint import M2D2M_FORMAT
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE
from tests.helpers import TINY_VQ, one_line_error
from training.callbacks import StepProgressBar


def broken_motions(folder: Path, sample_joints: np.ndarray, sample_features: np.ndarray) -> dict[str, Path]:
    with_nan, with_inf = sample_joints[:10].copy(), sample_features[:10].copy()
    with_nan[3, 2, 1] = np.nan
    with_inf[5, 7] = np.inf
    arrays = {
        "nan-joints": with_nan,
        "inf-features": with_inf,
        "no-joints": np.zeros((0, 22, 3), np.float32),
        "no-features": np.zeros((0, 263), np.float32),
        "joints-at-the-origin": np.zeros((1, 22, 3), np.float32),  # exported a BVH of NaN, exit 0
        "zero-features": np.zeros((5, 263), np.float32),
        "centimetre-joints": sample_joints[:10] * 100,  # exported a 160 m figure
    }
    files = {}
    for name, array in arrays.items():
        np.save(folder / f"{name}.npy", array)
        files[name] = folder / f"{name}.npy"
    files["zero-bytes"] = folder / "zero-bytes.npy"
    files["zero-bytes"].write_bytes(b"")
    return files


@pytest.mark.parametrize("verb, suffix", [("render", "gif"), ("export", "bvh")])
def test_motions_that_cannot_be_drawn_are_one_line(tmp_path, capsys, sample_joints, sample_features, verb, suffix):
    expected = {
        "nan-joints": "NaN or infinite",
        "inf-features": "NaN or infinite",
        "no-joints": "no frames",
        "no-features": "no frames",
        "zero-bytes": "not a readable .npy",
        "joints-at-the-origin": "have no length (joints on one point): not a body to draw or export",
        "zero-features": "have no length",
        "centimetre-joints": "the body is 100× the size of the t2m skeleton's (legs",
    }
    for name, path in broken_motions(tmp_path, sample_joints, sample_features).items():
        assert expected[name] in one_line_error([verb, str(path), "--out", str(tmp_path / f"out.{suffix}")], capsys)
    assert not list(tmp_path.glob("out.*"))


@pytest.mark.parametrize("verb, fps", [("render", "0"), ("export", "-1"), ("export", "nan"), ("render", "inf")])
def test_the_frame_rate_must_be_a_positive_number(tmp_path, capsys, sample_joints, verb, fps):
    np.save(tmp_path / "clip.npy", sample_joints[:10])
    out = tmp_path / ("out.gif" if verb == "render" else "out.bvh")
    assert "--fps: must be a positive number" in one_line_error(
        [verb, str(tmp_path / "clip.npy"), "--fps", fps, "--out", str(out)], capsys
    )
    assert not out.exists()


@pytest.fixture(scope="module")
def vq_payload(tmp_path_factory) -> tuple[Path, dict]:
    """A real tiny VQ model file and its contents, to spoil."""
    path = tmp_path_factory.mktemp("vq") / "vq.pt"
    torch.manual_seed(0)
    VQ_FORMAT.save(
        path,
        model=MotionVQVAE(TINY_VQ),
        normalizer=Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32)),
        skeleton="t2m",
        extra={"data_dir": str(path.parent / "data")},
    )
    return path, torch.load(path, weights_only=True)


def spoiled_vq_files(folder: Path, vq: Path, payload: dict) -> dict[str, Path]:
    data = vq.read_bytes()
    files = {
        name: folder / f"{name}.pt"
        for name in ("truncated", "random-bytes", "empty", "plain-dict", "denoiser", "no-extra", "other-weights")
    }
    files["truncated"].write_bytes(data[: len(data) // 2])
    files["random-bytes"].write_bytes(np.random.default_rng(0).bytes(4096))
    files["empty"].write_bytes(b"")
    torch.save({"weights": torch.zeros(3)}, files["plain-dict"])
    torch.save({"format": M2D2M_FORMAT.format, "state_dict": {}}, files["denoiser"])  # an M2D2M model.pt, not a VQ-VAE
    torch.save({k: v for k, v in payload.items() if k != "extra"}, files["no-extra"])
    torch.save({**payload, "state_dict": {"encoder.0.weight": torch.zeros(2, 2)}}, files["other-weights"])
    return files


def test_tokenize_with_a_spoiled_vq_file_is_one_line(tmp_path, capsys, vq_payload):
    vq, payload = vq_payload
    assert payload["format"] == VQ_FORMAT.format
    for name, path in spoiled_vq_files(tmp_path, vq, payload).items():
        err = one_line_error(["tokenize", "--vq", str(path), "--data", str(tmp_path)], capsys)
        assert str(path) in err and ("not a VQ-VAE model file" in err or "not a usable VQ-VAE" in err), name


class _Line(pl.LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.layer = torch.nn.Linear(1, 1)

    def training_step(self, batch, _index):
        return self.layer(batch[0]).pow(2).mean()

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_the_progress_bar_counts_steps_where_lightning_says_epoch_0_of_minus_2(tmp_path, monkeypatch, one_torch_thread):
    """Five steps in epochs of two batches, as training runs (max_steps, no max_epochs)."""
    bar, shown = StepProgressBar(), []
    label = bar._get_train_description
    monkeypatch.setattr(bar, "_get_train_description", lambda epoch: shown.append(label(epoch)) or shown[-1])
    trainer = pl.Trainer(
        max_steps=5,
        limit_train_batches=2,
        callbacks=[bar],
        logger=False,
        accelerator="cpu",
        enable_checkpointing=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
    )
    data = torch.utils.data.DataLoader(torch.utils.data.TensorDataset(torch.ones(8, 1)), batch_size=1)
    trainer.fit(_Line(), data)
    assert trainer.global_step == 5 and trainer.max_epochs == -1
    assert "/-2" in RichProgressBar._get_train_description(bar, 0)  # what Lightning itself would say
    assert [text.strip() for text in shown] == ["Steps 1–2 of 5", "Steps 3–4 of 5", "Step 5 of 5"]


def test_joints_that_show_no_facing_are_refused_as_a_motion_to_edit(tmp_path):
    """Every joint on one vertical line: HumanML3D's processing has no facing to turn the body to,
    and gave NaN features (with a RuntimeWarning) that an edit would have started from."""
    from m2d2m.motion.representation.skeleton import T2M
    from orchestration.errors import UserError
    from orchestration.viewing import load_features

    joints = np.zeros((12, 22, 3), dtype=np.float32)
    joints[:, :, 1] = np.linspace(0.0, 1.7, 22)
    np.save(tmp_path / "line.npy", joints)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning on the way
        with pytest.raises(UserError, match="no finite features: .* show which way it faces"):
            load_features(tmp_path / "line.npy", T2M)
