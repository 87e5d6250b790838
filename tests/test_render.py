"""Rendering: animations and contact sheets are written, valid and actually show a moving figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageSequence

from m2d2m.motion.files import render
from m2d2m.motion.files.render import render_comparison, render_frames, render_motion
from m2d2m.motion.representation.skeleton import KIT, T2M


@pytest.fixture(scope="module")
def clip(sample_joints: np.ndarray) -> np.ndarray:
    """The first 24 frames of the real sample clip (tests/fixtures/humanml3d-sample)."""
    return sample_joints[:24]


def gif_frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as im:
        assert im.format == "GIF" and im.is_animated
        return [np.asarray(frame.convert("RGB"), dtype=np.int16) for frame in ImageSequence.Iterator(im)]


def test_gif_has_every_frame_and_shows_motion(tmp_path: Path, clip: np.ndarray) -> None:
    path = render_motion(clip, tmp_path / "clip.gif", size=160)
    frames = gif_frames(path)
    assert len(frames) == len(clip)
    assert frames[0].shape == (160, 160, 3)
    with Image.open(path) as im:
        assert im.info["duration"] == pytest.approx(1000 / T2M.fps, abs=10)
    first, middle = frames[0], frames[len(frames) // 2]
    assert (first.std(axis=(0, 1)) > 10).all()  # something is drawn, not a blank picture
    assert np.abs(first - middle).max(axis=-1).astype(bool).mean() > 0.005  # and it moves


def test_segments_and_title(tmp_path: Path, clip: np.ndarray) -> None:
    segments = [(0, 10, "a person walks forward"), (14, 24, "then waves, a long caption " * 4)]
    path = render_motion(clip, tmp_path / "seg.gif", segments=segments, title="demo", size=200, fps=10)
    frames = gif_frames(path)
    assert len(frames) == len(clip)
    with Image.open(path) as im:
        assert im.info["duration"] == pytest.approx(100, abs=10)

    # Each segment colours the figure: blue for the first, orange for the second.
    def red_minus_blue(frame: np.ndarray) -> float:
        saturated = frame[np.ptp(frame, axis=-1) > 80]
        return float(np.median(saturated[:, 0] - saturated[:, 2]))

    assert red_minus_blue(frames[5]) < -50 and red_minus_blue(frames[20]) > 50


def test_a_caption_in_a_script_the_font_lacks_draws_without_a_warning_per_frame(tmp_path, clip) -> None:
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        render_motion(clip[:4], tmp_path / "cjk.gif", segments=[(0, 4, "一个人在走路 🙂")], size=120, fps=10)
    assert not [w for w in caught if "Glyph" in str(w.message)]


def test_kit_units_are_fitted_to_the_view(tmp_path: Path) -> None:
    # KIT bodies are ~640 units per metre: the view must scale to the data, not to metres.
    rest = np.zeros((KIT.num_joints, 3))
    for joint in KIT.bones:
        rest[joint] = rest[KIT.parents[joint]] + KIT.offsets()[joint]
    rest[:, 1] -= rest[:, 1].min()
    sway = np.linspace(0.0, 300.0, 8)[:, None, None] * np.array([1.0, 0.0, 0.0])
    joints = rest[None] + sway
    frames = gif_frames(render_motion(joints, tmp_path / "kit.gif", skeleton=KIT, size=120))
    ink = (frames[0].sum(axis=-1) < 300).mean()  # dark bone pixels
    assert 0.002 < ink < 0.2


def test_unknown_suffix_raises(tmp_path: Path, clip: np.ndarray) -> None:
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        render_motion(clip, tmp_path / "clip.avi")
    assert not (tmp_path / "clip.avi").exists()


def test_bad_joints_raise(tmp_path: Path, clip: np.ndarray) -> None:
    with pytest.raises(ValueError, match="shape"):
        render_motion(clip[:, :21], tmp_path / "clip.gif")
    broken = clip.copy()
    broken[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        render_motion(broken, tmp_path / "clip.gif")


def test_mp4_without_ffmpeg_fails_clearly(tmp_path: Path, clip: np.ndarray, monkeypatch) -> None:
    monkeypatch.setattr(render, "_find_ffmpeg", lambda: None)
    with pytest.raises(RuntimeError, match="imageio-ffmpeg"):
        render_motion(clip, tmp_path / "clip.mp4")
    assert not (tmp_path / "clip.mp4").exists()


def test_mp4_written(tmp_path: Path, clip: np.ndarray) -> None:
    path = render_motion(clip, tmp_path / "clip.mp4", size=161)  # odd sizes are evened out
    data = path.read_bytes()
    assert len(data) > 1000 and data[4:8] == b"ftyp"


def test_contact_sheet(tmp_path: Path, clip: np.ndarray) -> None:
    path = render_frames(
        clip,
        tmp_path / "sheet.png",
        frames=[0, 5, 10, 23, 23],
        size=100,
        columns=3,
        title="sheet",
        segments=[(0, 12, "walk")],
    )
    with Image.open(path) as im:
        assert im.format == "PNG"
        width, height = im.size
        pixels = np.asarray(im.convert("RGB"), dtype=np.int16)
    assert width == 300 and height > 200
    assert pixels.std() > 10
    with pytest.raises(ValueError, match="frames"):
        render_frames(clip, tmp_path / "bad.png", frames=[len(clip)])


def test_comparison_plays_motions_side_by_side(tmp_path, sample_joints):
    path = render_comparison(
        [sample_joints[:30], sample_joints[:20] + 0.1],
        ["ground truth", "reconstruction"],
        tmp_path / "pair.gif",
        size=160,
    )
    with Image.open(path) as gif:
        assert gif.n_frames == 30 and gif.size == (320, 160)
    with pytest.raises(ValueError, match="one label per motion"):
        render_comparison([sample_joints], ["a", "b"], tmp_path / "bad.gif")
