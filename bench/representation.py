"""Speed of the motion representation on one core: joints → features and features → joints.

HumanML3D's reference feature code takes about 17 ms per 196-frame clip on one core of the
project's machine; our goal is at most 3.5 ms. Run with ``make bench``; prints a Markdown table.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m2d2m.motion.representation.features import features_to_joints, joints_to_features  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "humanml3d-sample"
FRAMES = 196


def _clip() -> np.ndarray:
    """The real sample clip, extended to 196 frames by playing its end backwards."""
    joints = np.load(SAMPLE / "new_joints" / "012314.npy")
    return np.concatenate([joints, joints[::-1][1 : FRAMES - len(joints) + 1]])[:FRAMES]


def _best_ms(fn, repeats: int = 7, number: int = 50) -> float:
    """Best mean over repeats: the least disturbed estimate on a shared machine."""
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - started) / number)
    return best * 1e3


def main() -> None:
    torch.set_num_threads(1)
    joints = _clip()
    features = joints_to_features(joints)
    batch = torch.from_numpy(np.stack([features] * 32))
    rows = [
        ("joints_to_features, one 196-frame clip", _best_ms(lambda: joints_to_features(joints))),
        ("features_to_joints, one clip (NumPy in/out)", _best_ms(lambda: features_to_joints(features))),
        ("features_to_joints, batch of 32 clips (torch)", _best_ms(lambda: features_to_joints(batch), number=10)),
    ]
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, 1 thread used")
    print("| operation | ms |\n| --- | --- |")
    for name, ms in rows:
        print(f"| {name} | {ms:.2f} |")


if __name__ == "__main__":
    main()
