"""The one call every model's generator answers, so that generation, evaluation and sweeps work
with any model (docs/architecture.md, "How to add a model").

A generator turns a request — action sentences per sequence, each action's length in *frames*,
a seed per sequence, optionally frames to keep — into one :class:`~m2d2m.motion.clip.Motion` per
sequence. Lengths are frames whatever the model works on: a token model rounds them to whole
tokens (:meth:`MotionGenerator.round_frames`). How the actions of one sequence are joined is the
*method*, one of the options; the options are a frozen dataclass of the model's own sampling
knobs, with named presets for the paper settings of single and multi-action generation, declared
in the model's :class:`~m2d2m.generators.options.Sampling` (its ``sampling``).
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from m2d2m.generators.options import MULTI, Sampling
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.body_parts import part_mask
from m2d2m.motion.representation.skeleton import Skeleton
from m2d2m.precision import autocast, resolve
from m2d2m.text import TextEncoder


@dataclass(frozen=True)
class Keep:
    """What to keep of a sequence while the rest is generated (editing): the frames of
    ``features`` (F, D, un-normalised) where ``frames`` (F,) is True, and of those only the
    feature dimensions where ``dims`` is True: (D,) the same on every frame, (F, D) frame by frame
    (a body part kept over a span only), None every dimension, whole frames. A model that
    generates in coarser units keeps every unit that holds a kept frame; one that cannot keep
    some dimensions alone (a body part: :mod:`m2d2m.motion.representation.body_parts`) refuses such a Keep."""

    features: np.ndarray
    frames: np.ndarray
    dims: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.frames.shape != (len(self.features),) or self.frames.dtype != bool:
            raise ValueError(
                f"keep: one boolean per frame of the features ({len(self.features)}), "
                f"got {self.frames.dtype} of shape {self.frames.shape}"
            )
        if self.dims is not None and (
            self.dims.shape not in (self.features.shape[1:], self.features.shape) or self.dims.dtype != bool
        ):
            raise ValueError(
                f"keep: one boolean per feature dimension ({self.features.shape[1]}), on every frame or "
                f"frame by frame, got {self.dims.dtype} of shape {self.dims.shape}"
            )

    @property
    def entries(self) -> np.ndarray:
        """(F, D) every kept entry: a kept frame's kept dimensions."""
        dims = np.ones(self.features.shape, dtype=bool) if self.dims is None else self.dims
        return self.frames[:, None] & np.broadcast_to(dims, self.features.shape)

    @property
    def whole_frames(self) -> bool:
        """Whether every dimension of a kept frame is kept."""
        return self.dims is None or bool(self.dims.all())


def keep_part(features: np.ndarray, skeleton: Skeleton, part: str) -> Keep:
    """A :class:`Keep` of body part ``part`` of ``features`` on every frame, the rest of the body
    to generate (MMM's upper-body editing keeps ``lower``)."""
    return Keep(features, np.ones(len(features), dtype=bool), part_mask(skeleton, part))


def keep_spans(motion: Motion, spans: Sequence[tuple[float, float]]) -> Keep:
    """A :class:`Keep` of ``motion``'s frames inside the time spans ``spans`` (seconds)."""
    frames = np.zeros(len(motion.features), dtype=bool)
    for start, end in spans:
        frames[max(0, int(np.floor(start * motion.fps))) : int(np.ceil(end * motion.fps))] = True
    return Keep(motion.features, frames)


class MotionGenerator(ABC):
    """A loaded model that turns requests into motions: the only view of a model that generation,
    evaluation and sweeps have. Subclasses set the class attributes and implement the methods."""

    model: ClassVar[str]  # the registry's name of the model
    # its knobs, multi-action methods and presets (its own ``<model>_options.py``, which the
    # registry names too, so that the command line reads them without loading torch)
    sampling: ClassVar[Sampling]
    # None for a model that generates from text alone; else what every request must keep, said as
    # an instruction (an editor: MMM's upper-body editor keeps a lower body), so that evaluation,
    # which asks for text alone, refuses it up front
    needs_keep: ClassVar[str | None] = None
    # the editing-table tasks it can do (m2d2m.evaluation.measurements.EDITS: inbetween, upper)
    edits: ClassVar[tuple[str, ...]] = ()
    # the multi-action method an edit of several actions is sampled with, None for its default: a
    # model whose default decodes actions together cannot keep frames across them (MMM's transition
    # tokens) and edits with one that samples each action with its own kept tokens
    edit_method: ClassVar[str | None] = None
    # whether it answers :meth:`generate_parts` (one sentence per body part: MotionDiffuse's eq. 10)
    part_control: ClassVar[bool] = False

    source: Path  # the model file it was loaded from
    _precision: str | None = None  # what use_precision chose; None until first asked

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Every model's sampling runs in its generator's :attr:`precision`: the calls that sample
        (``generate``, ``generate_parts``, ``reconstruct``) a subclass defines are wrapped in
        its autocast, so no model can forget it and none repeats it."""
        super().__init_subclass__(**kwargs)
        for name in _SAMPLING_CALLS:
            if name in cls.__dict__:
                setattr(cls, name, _in_precision(cls.__dict__[name]))

    @property
    def precision(self) -> str:
        """``bf16`` or ``fp32``: what its networks sample in (:mod:`m2d2m.precision`): bf16 on a
        GPU that has it, unless ``M2D2M_PRECISION`` or :meth:`use_precision` says otherwise."""
        if self._precision is None:
            self._precision = resolve(None, self.device)
        return self._precision

    def use_precision(self, precision: str | None) -> MotionGenerator:
        """Sample in ``precision`` (auto, bf16 or fp32; None: ``M2D2M_PRECISION``, else auto) from now on."""
        self._precision = resolve(precision, self.device)
        return self

    # -------------------------------------------------------------------------- what it is
    @property
    @abstractmethod
    def skeleton(self) -> Skeleton:
        """The skeleton its motions are on (their frame rate is the skeleton's)."""

    @property
    @abstractmethod
    def feature_dim(self) -> int:
        """The width of its motion features (263 for HumanML3D's skeleton, 251 for KIT-ML's)."""

    @property
    @abstractmethod
    def device(self) -> torch.device:
        """Where it computes (an evaluator working beside it goes there too)."""

    @property
    def data_dir(self) -> Path | None:
        """The processed dataset it was trained on, when it knows (the default test set's home)."""
        return None

    @property
    def fps(self) -> float:
        return self.skeleton.fps

    @property
    def frame_step(self) -> int:
        """Its granularity in frames: every length it generates is a multiple of this."""
        return 1

    def round_frames(self, frames: int) -> int:
        """The length it generates when ``frames`` are asked for: whole steps, at least one."""
        return max(1, int(frames) // self.frame_step) * self.frame_step

    @abstractmethod
    def typical_frames(self, verb: str | None) -> int:
        """A length for an action with this verb when the user gives none (the corpus's median)."""

    @property
    @abstractmethod
    def longest_frames(self) -> int:
        """The longest action it was trained on, in frames."""

    @property
    def known_verbs(self) -> tuple[str, ...]:
        """The verbs of its single-action training captions (its length prior's): the actions it
        was shown alone, and so the ones it can be asked for by name (empty: it does not say)."""
        return ()

    @property
    def text_encoder(self) -> TextEncoder | None:
        """What reads its prompts (None: it does not say)."""
        return None

    def unknown_words(self, sentence: str) -> list[str]:
        """The words of ``sentence`` its text encoder never saw in training and reads as unknown
        (none for CLIP, which reads any English): what the motion cannot follow."""
        return [] if self.text_encoder is None else self.text_encoder.unknown_words(sentence)

    @property
    def model_defaults(self) -> dict[str, Any]:
        """Knob values its model file chose for every preset (M2D2M: its config's ``sampling``
        section, :func:`m2d2m.generators.options.Sampling.defaults`); none by default."""
        return {}

    # --------------------------------------------------------------------------- its options
    def preset(self, name: str) -> Any:
        """The options of preset ``name`` (:data:`SINGLE`, :data:`MULTI`) for this model file: the
        declared ones with what the model file chose in their place (:attr:`model_defaults`)."""
        if name not in self.sampling.presets:
            raise ValueError(f"unknown preset {name!r}: choose one of {', '.join(self.sampling.presets)}")
        return replace(self.sampling.presets[name], **self.model_defaults)

    def options(self, preset: str = MULTI, **changes: Any) -> Any:
        """The options of ``preset`` with ``changes``; ValueError names an unknown or bad knob."""
        options = self.sampling.changed(self.preset(preset), **changes)
        self.check_options(options)
        return options

    def check_options(self, options: Any) -> None:
        """Raise ValueError naming the first setting this model cannot sample with."""

    @abstractmethod
    def describe(self, options: Any) -> str:
        """The options in the paper's words for a table's notes, e.g. ``T_s = 90 of T = 100, η = 0.25, s = 2``."""

    def reconstruct(self, segments: Sequence[Sequence[np.ndarray]]) -> list[Motion] | None:
        """For a model that generates through a motion codec (a VQ-VAE): each sequence's ground-truth
        feature segments encoded, joined in the codec's space and decoded together, one Motion
        per sequence with the segments' ranges: the ceiling of every method of that model, the
        evaluation tables' reconstruction row. None (the default) for a model without a codec."""
        return None

    # ----------------------------------------------------------------------------- the call
    @abstractmethod
    def generate(
        self,
        actions: Sequence[Sequence[str]],
        frames: Sequence[Sequence[int]],
        options: Any,
        seeds: Sequence[int],
        keep: Sequence[Keep | None] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """One motion per sequence: ``actions[i]`` in order, action j about ``frames[i][j]`` frames
        long (rounded by :meth:`round_frames`), drawn with ``seeds[i]``; ``keep[i]`` holds frames
        to keep. An empty sentence asks for the action without text: the model's null condition
        (editing "w/o text", MMM Table 3). A sequence's result does not depend on the others in the call. ValueError for a
        request it cannot serve. A model that works in steps may call ``progress`` with the
        fraction done, for a progress bar on long generations."""

    def generate_parts(
        self,
        parts: Sequence[Mapping[str, str]],
        frames: Sequence[int],
        options: Any,
        seeds: Sequence[int],
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """One motion per request in which every body part (:data:`m2d2m.motion.representation.body_parts.PARTS`)
        does its own sentence, ``parts[i]`` mapping part → sentence, ``frames[i]`` long, drawn with
        ``seeds[i]``. ValueError for a model without body-part control (:attr:`part_control`)."""
        raise ValueError(f"{self.model} has no body-part control")


_SAMPLING_CALLS = ("generate", "generate_parts", "reconstruct")


def _in_precision(call: Callable[..., Any]) -> Callable[..., Any]:
    """``call`` (a generator's method) run inside its generator's autocast."""

    @functools.wraps(call)
    def in_precision(self: MotionGenerator, *args: Any, **kwargs: Any) -> Any:
        with autocast(self.precision, self.device):
            return call(self, *args, **kwargs)

    return in_precision
