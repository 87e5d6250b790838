"""Shared fixtures: paths to the real HumanML3D sample files in ../shared."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]
HUMANML3D_SAMPLE = PROJECT_ROOT.parent / "shared" / "data" / "humanml3d-sample"


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


@pytest.fixture(scope="session")
def ray_local():
    """One local Ray (2 CPUs) for the whole session: starting Ray costs seconds."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    ray.data.DataContext.get_current().enable_progress_bars = False
    yield
    ray.shutdown()
