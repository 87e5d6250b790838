"""Shared fixtures: the real HumanML3D sample files in tests/fixtures/humanml3d-sample."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from m2d2m.motion.representation.skeleton import T2M
from orchestration.recipe import train
from orchestration.recipes.evaluator import train_evaluator
from orchestration.recipes.vq import train_vq
from pipelines.features import DataConfig, build_dataset
from tests.helpers import TINY_DIFFUSION, TINY_EVALUATOR, TINY_VQ_RUN, write_corpus

pytest_plugins = ["tests.browser"]  # the page tests' Chromium
PROJECT_ROOT = Path(__file__).resolve().parents[1]
HUMANML3D_SAMPLE = PROJECT_ROOT / "tests" / "fixtures" / "humanml3d-sample"


# Fixtures that make a test slow, whatever else it does: Ray (and so every dataset built, every model
# trained on one), Chromium. `make test` leaves these tests to `make test-all` (what CI runs).
SLOW_FIXTURES = {"ray_local", "browser", "offline_browser"}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark ``slow`` every test that asks, directly or through its fixtures, for a slow fixture."""
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def humanml3d_sample() -> Path:
    """The directory of real HumanML3D files (one clip, Mean.npy, Std.npy)."""
    return HUMANML3D_SAMPLE


@pytest.fixture(scope="session")
def sample_joints() -> np.ndarray:
    """HumanML3D's processed joints of clip 012314, float32 (170, 22, 3)."""
    return np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")


@pytest.fixture(scope="session")
def sample_features() -> np.ndarray:
    """HumanML3D's 263-d features of clip 012314, float32 (170, 263)."""
    return np.load(HUMANML3D_SAMPLE / "new_joint_vecs" / "012314.npy")


@pytest.fixture
def one_torch_thread():
    """For tiny models: extra intra-op threads only contend with other work on the machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def ray_local():
    """One local Ray (2 CPUs) for the whole session: starting Ray costs seconds."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    ray.data.DataContext.get_current().enable_progress_bars = False
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory, ray_local) -> Path:
    root = tmp_path_factory.mktemp("vq-data")
    write_corpus(root / "raw", {"train": 6, "val": 2, "test": 1}, T2M)
    build_dataset(DataConfig(dataset="synthetic", raw=str(root / "raw"), out=str(root / "data"), samples_per_shard=4))
    return root / "data"


@pytest.fixture
def project(tmp_path, tiny_data, monkeypatch) -> Path:
    """A working directory with its own runs/ and MLflow store, and a tiny config file."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    config = {**TINY_VQ_RUN, "data": {**TINY_VQ_RUN["data"], "dir": str(tiny_data)}}
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    return tmp_path


TINY_EVALUATOR_RUN = {
    "dataset": "tiny",
    "seed": 7,
    "data": {"dir": None, "batch_size": 4, "num_workers": 0, "min_frames": 40, "max_frames": 196},
    "model": {**TINY_EVALUATOR, "max_text_len": 20, "dropout": 0.0},
    "glove_dir": None,
    "min_word_count": 1,
    "loss": {"margin": 10.0},
    "optim": {"lr": 1e-3, "betas": [0.9, 0.999], "weight_decay": 0.0, "grad_clip": 0.5},
    "trainer": {
        "max_steps": 4,
        "val_every_steps": 2,
        "val_batches": 1,
        "accelerator": "cpu",
        "devices": 1,
        "precision": "32-true",
    },
}


@pytest.fixture(scope="session")
def trained_store(tmp_path_factory, ray_local) -> Path:
    """A project directory with a tiny VQ-VAE, denoiser and evaluator trained on a corpus whose
    test split has 8 clips (16 with mirrors: 8 two-action instances when mirrors are distinct);
    trained once per session, and only ever read through :func:`trained_project`'s copies."""
    root = tmp_path_factory.mktemp("trained")
    write_corpus(root / "raw", {"train": 6, "val": 2, "test": 8}, T2M)
    data = root / "data"
    configs = {
        "vq": {**TINY_VQ_RUN, "data": {**TINY_VQ_RUN["data"], "dir": str(data)}},
        "diffusion": TINY_DIFFUSION,
        "evaluator": {**TINY_EVALUATOR_RUN, "data": {**TINY_EVALUATOR_RUN["data"], "dir": str(data)}},
    }
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny models: more intra-op threads only contend
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(root)
        patch.delenv("MLFLOW_TRACKING_URI", raising=False)
        build_dataset(DataConfig(dataset="synthetic", raw=str(root / "raw"), out=str(data), samples_per_shard=4))
        for name, config in configs.items():
            (root / f"{name}.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
        train_vq(str(root / "vq.yaml"))
        train("m2d2m", str(root / "diffusion.yaml"))
        train_evaluator(str(root / "evaluator.yaml"))
    torch.set_num_threads(threads)
    return root


@pytest.fixture(scope="module")
def trained_project(trained_store, tmp_path_factory) -> Iterator[Path]:
    """A module's own copy of :func:`trained_store`, its working directory while it runs: the runs,
    test sets and MLflow runs one module adds, no other module sees. The store's files name its
    dataset relative to it and its MLflow store follows the copy (docs/reliability.md, "A project
    can move"), so the copy reads and writes its own files; its configs are pointed at its own
    dataset too. (They named the store's, so token and test sets a module made went into the store,
    recording it as a dataset outside their project: the next copy, moved, looked for the original.)"""
    root = tmp_path_factory.mktemp("project")
    shutil.copytree(trained_store, root, dirs_exist_ok=True)
    for name in ("vq", "evaluator"):
        config = yaml.safe_load((root / f"{name}.yaml").read_text(encoding="utf-8"))
        config["data"]["dir"] = str(root / "data")
        (root / f"{name}.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(root)
        patch.delenv("MLFLOW_TRACKING_URI", raising=False)
        yield root
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def tiny_testset(trained_project) -> Path:
    """Two-action instances of the trained project's test split."""
    from orchestration.evaluate.testsets import make_testset

    return Path(make_testset(trained_project / "data", "tiny", n=2, seed=0, mirrors="distinct")["path"])
