"""Which way is up, read from the motion (m2d2m/motion/rigs/up_axis.py): HumanML3D's sample clip
turned to stand along each world axis comes back upright, by a proper rotation; a motion
standing along no one axis is refused in one line. ``z_up_bvh`` writes a Y-up BVH as a Z-up
exporter does (tests/test_mocap_corpora.py, tests/test_bandai_namco.py read such files)."""

from __future__ import annotations

import numpy as np
import pytest

from m2d2m.motion.rigs.up_axis import stance
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_export import axis_rotation

# Y-up → Z-up (Rx(+90°)), as a Z-up exporter writes a Y-up scene: p' = (x, −z, y). A rotation
# about Y becomes one about Z, one about Z one about −Y; a Y position becomes a Z position, a Z
# position a −Y one.
_Z_UP_CHANNELS = {
    "Xposition": ("Xposition", 1.0),
    "Yposition": ("Zposition", 1.0),
    "Zposition": ("Yposition", -1.0),
    "Xrotation": ("Xrotation", 1.0),
    "Yrotation": ("Zrotation", 1.0),
    "Zrotation": ("Yrotation", -1.0),
}


def z_up_bvh(text: str) -> str:
    """A Y-up BVH's text written Z-up: every OFFSET, End Site and channel of every frame turned
    by +90° about X, so its rest pose and its motion stand along +Z."""
    head, motion = text.split("MOTION", 1)
    lines, signs = [], []
    for line in head.splitlines():
        words = line.split()
        indent = line[: len(line) - len(line.lstrip())]
        if words[:1] == ["OFFSET"]:
            x, y, z = (float(w) for w in words[1:4])
            line = f"{indent}OFFSET {x:.6f} {-z:.6f} {y:.6f}"
        elif words[:1] == ["CHANNELS"]:
            turned = [_Z_UP_CHANNELS[name] for name in words[2:]]
            signs += [sign for _, sign in turned]
            line = f"{indent}CHANNELS {words[1]} {' '.join(name for name, _ in turned)}"
        lines.append(line)
    frames = motion.strip().splitlines()
    sign = np.array(signs)
    body = [" ".join(f"{v:.6f}" for v in np.array(f.split(), dtype=float) * sign) for f in frames[2:] if f.strip()]
    return "\n".join([*lines, "MOTION", *frames[:2], *body]) + "\n"


def handedness(joints: np.ndarray) -> np.ndarray:
    """Per frame, the triple product of right → left hip, pelvis → neck and left ankle → right
    toe: kept by a rotation, negated by a mirror."""
    vectors = [joints[:, 1] - joints[:, 2], joints[:, 12] - joints[:, 0], joints[:, 11] - joints[:, 7]]
    return np.linalg.det(np.stack(vectors, axis=1))


@pytest.fixture(scope="module")
def sample() -> np.ndarray:
    return np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy").astype(np.float64)


@pytest.mark.parametrize(
    "axis, turn",
    [
        ("+Y", np.eye(3)),
        ("+Z", axis_rotation("X", np.array(90.0))),
        ("-Z", axis_rotation("X", np.array(-90.0))),
        ("-Y", axis_rotation("X", np.array(180.0))),
        ("+X", axis_rotation("Z", np.array(-90.0))),
        ("-X", axis_rotation("Z", np.array(90.0))),
    ],
)
def test_a_motion_standing_along_any_axis_is_turned_upright_by_a_proper_rotation(sample, axis, turn):
    """The sample turned to stand along ``axis`` is found standing there and turned back to +Y
    with its heading possibly changed but never mirrored: the same height over the floor in
    every frame, the left still the left."""
    turned = sample @ turn.T
    found = stance(turned)
    assert found.axis == axis
    assert np.linalg.det(found.rotation) == pytest.approx(1.0)
    upright = found.upright(turned)
    np.testing.assert_allclose(upright[..., 1], sample[..., 1], atol=1e-9)
    # the same rotation about +Y for every joint and frame: horizontal distances are kept, and the
    # left hip stays on the body's left (a mirror would flip the sign of this triple product)
    np.testing.assert_allclose(handedness(upright), handedness(sample), atol=1e-9)
    assert found.height == pytest.approx(stance(sample).height)


def test_a_motion_standing_along_no_one_axis_is_refused_in_one_line(sample):
    tilted = sample @ axis_rotation("X", np.array(45.0)).T
    with pytest.raises(ValueError, match="cannot tell which way is up: the head is over the feet along no one axis"):
        stance(tilted)
