"""A model that is no model, registered from outside the framework as a plugin
(``M2D2M_PLUGINS=tests.fake_model``): its generator plays back the ground-truth clip of each action
sentence, laid end to end. If evaluation or sweeps knew anything of M2D2M beyond the registry and
the generator protocol, this model could not go through them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from m2d2m.generators.options import MULTI, SINGLE, Sampling, knob
from m2d2m.generators.protocol import Keep, MotionGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.features import features_to_joints
from m2d2m.motion.representation.skeleton import SKELETONS, Skeleton
from orchestration.recipe import Recipe
from orchestration.registry import ModelEntry, register

NAME = "playback"


@dataclass(frozen=True)
class PlaybackOptions:
    method: str = knob("concat", "clips laid end to end", choices=("concat",))
    offset: int = knob(0, "frames skipped at the start of every clip: a knob for sweeps to vary", minimum=0)


SAMPLING = Sampling(NAME, PlaybackOptions, {SINGLE: PlaybackOptions(), MULTI: PlaybackOptions()})


def save_playback(path: Path, clips: dict[str, np.ndarray]) -> Path:
    """The model file: one feature clip per action sentence."""
    sentences = sorted(clips)
    np.savez(path, sentences=np.array(sentences), **{f"clip{i}": clips[s] for i, s in enumerate(sentences)})
    return path


def playback_of(testset_path: Path, path: Path) -> tuple[Path, dict[str, np.ndarray]]:
    """A model file that plays back every item of a test set by its sentence, and its clips."""
    from pipelines.testset import load_testset

    testset = load_testset(testset_path)
    clips = {
        item.action: testset.features(instance.index, p)
        for instance in testset
        for p, item in enumerate(instance.items)
    }
    return save_playback(path, clips), clips


def evaluate_playback(model_file: Path, testset: Path) -> list[str]:
    """`m2d2m evaluate`'s arguments for a playback model file on a test set of the tiny dataset, once."""
    return [
        "evaluate",
        "--model",
        NAME,
        "--checkpoint",
        str(model_file),
        "--dataset",
        "tiny",
        "--testset",
        str(testset),
        "--repeats",
        "1",
    ]


class PlaybackGenerator(MotionGenerator):
    model = NAME
    sampling = SAMPLING

    def __init__(self, clips: dict[str, np.ndarray], source: Path) -> None:
        self.clips = clips
        self.source = source

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> PlaybackGenerator:
        with np.load(path, allow_pickle=False) as arrays:
            clips = {str(s): arrays[f"clip{i}"] for i, s in enumerate(arrays["sentences"])}
        return cls(clips, Path(path))

    @property
    def skeleton(self) -> Skeleton:
        return SKELETONS["t2m"]

    @property
    def feature_dim(self) -> int:
        return self.skeleton.feature_dim

    @property
    def device(self) -> torch.device:
        return torch.device("cpu")

    def typical_frames(self, verb: str | None) -> int:
        return 40

    @property
    def longest_frames(self) -> int:
        return max(len(clip) for clip in self.clips.values())

    def describe(self, options: PlaybackOptions) -> str:
        return f"ground truth played back from frame {options.offset}"

    def generate(
        self,
        actions: Sequence[Sequence[str]],
        frames: Sequence[Sequence[int]],
        options: PlaybackOptions,
        seeds: Sequence[int],
        keep: Sequence[Keep | None] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        motions = []
        for sequence, lengths in zip(actions, frames):
            pieces = []
            for action, n in zip(sequence, lengths):
                clip = self.clips[action][options.offset :]
                pieces.append(clip[np.minimum(np.arange(n), len(clip) - 1)])
            features = np.concatenate(pieces)
            ends = np.cumsum([len(p) for p in pieces])
            motions.append(
                Motion(
                    features,
                    features_to_joints(features, self.skeleton),
                    self.fps,
                    "t2m",
                    list(sequence),
                    [(int(e - len(p)), int(e)) for p, e in zip(pieces, ends)],
                    {"model": NAME, "method": options.method, "offset": options.offset},
                )
            )
        return motions


RECIPE = Recipe()  # playback has nothing to train: the base recipe, which builds nothing

register(
    ModelEntry(
        name=NAME,
        summary="ground truth played back (a test of the registry)",
        stage=NAME,
        configs=NAME,
        train_verb="train-playback",
        model_file="playback.npz",
        generator=f"{__name__}:PlaybackGenerator",
        recipe=f"{__name__}:RECIPE",
        sampling=f"{__name__}:SAMPLING",
        shortcuts=("offset",),
    )
)
