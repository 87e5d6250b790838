"""The embedded corpus stays calibrated against real HumanML3D motion (docs/data.md)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.calibrate_corpus import CALIBRATED, band_ratio, group_spectra, synthetic
from pipelines.synthetic import TEXTURE, Texture
from tests.conftest import HUMANML3D_SAMPLE


@pytest.fixture(scope="module")
def real() -> dict[str, np.ndarray]:
    return group_spectra([np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")])


def test_textured_clips_have_the_real_high_to_low_band_ratio(real):
    textured = group_spectra(synthetic(TEXTURE, 60, seed=3))  # other clips than the calibration's
    for group in CALIBRATED:
        assert band_ratio(textured[group]) == pytest.approx(band_ratio(real[group]), rel=0.2), group


def test_without_texture_the_corpus_is_far_smoother_than_real_motion(real):
    smooth = group_spectra(synthetic(Texture(), 60, seed=3))
    for group in CALIBRATED:
        assert band_ratio(smooth[group]) < 0.7 * band_ratio(real[group]), group
