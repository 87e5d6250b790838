"""bench/delivery_figures.py draws every picture of docs/generation.md's "Delivering a clip", and
the figures the section quotes hold: the pictures are made from the code they describe."""

from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image

from bench.delivery_figures import FIGURES, main


def test_every_delivery_figure_is_drawn_with_its_numbers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    results = main(["--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert set(results) == set(FIGURES)
    for name in FIGURES:
        path = tmp_path / name
        assert f"{path}:" in printed
        with Image.open(path) as image:
            assert image.format == "PNG" and image.size == (900, 500)
            colours = image.convert("RGB").getcolors(maxcolors=1 << 20)
            assert len(colours) > 16, f"{name} is nearly one colour"  # lines, text and shading, anti-aliased
    feet, fps, root, loop, rig = (results[name] for name in FIGURES)
    assert feet["skating_after"] <= 1.5 * feet["skating_clean"] < feet["skating_before"]  # the slide fixed
    assert feet["toe_speed_in_contact_after_m_s"] < 0.6 * feet["toe_speed_in_contact_before_m_s"]
    assert feet["real_clip_moved_m"] < 1e-6  # the real clip's own feet left where they are (float32)
    assert (fps["frames_30"], fps["frames_60"]) == (255, 510)  # 8.5 s: 255 and 510 frames (docs/generation.md)
    assert max(fps["shared_error_30_m"], fps["shared_error_60_m"]) < 1e-6  # float32 joints
    assert root["in_place_drift_m"] == 0.0 and root["restored_m"] < 1e-6
    assert loop["seam_jerk_loop"] < loop["clip_jerk_p95"] < loop["seam_jerk_cut"]
    assert rig["rig_joints"] == 31
