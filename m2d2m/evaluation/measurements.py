"""The measurements behind the paper's tables (M2D2M §5.1–5.3, Tables 1–3, Fig. 5) for any
generator: what the test set contributes whatever the method (:class:`Reference`), and one
repeat of one method on it (:class:`Evaluation`).

Per method and repeat r, every test instance is generated (lengths: the ground-truth items') and
measured with the text–motion evaluator:

- individual motion: each action's frames of the generated sequence against the item's caption
  (R-Top3, MM-Dist), against the ground-truth segments (FID), and among themselves (Diversity);
- transition: the :data:`WINDOW` frames around each boundary against "ground truth (single)"
  windows, the middle :data:`WINDOW` frames of every ground-truth item (FID), among themselves
  (Diversity), the paper's Jerk (eq. 10) of the joints there, time measured in frames, and
  FlowMDM's Peak Jerk and AUJ of the full windows' mean jerk curve, AUJ against the test set's
  ground-truth mean frame jerk (:func:`m2d2m.evaluation.metrics.peak_jerk_and_auj`);
- body: the spread of bone lengths of the decoded joints (each bone's standard deviation over a
  sequence's frames, mean over bones, in mm; :func:`m2d2m.motion.representation.rigid.bone_length_spread`),
  0 for one rigid skeleton: how far a generator's bodies are from the corpus's one skeleton.

Reference rows: "ground truth (single)" measures the ground-truth segments and their middle
windows the same way; "ground truth (concat)" is the Jerk at the boundaries of each instance's
ground-truth segments joined by :func:`m2d2m.motion.transforms.joining.slerp_join` with no window (aligned,
not blended); "VQ-VAE reconstruction", for a model with a codec
(:meth:`~m2d2m.generators.protocol.MotionGenerator.reconstruct`), measures each instance's
ground-truth segments encoded, concatenated in tokens and decoded together like a method's
output — the ceiling of every sampler over those tokens, and the floor of decoding noise under
any transition effect (in the single-motion table: each item encoded and decoded alone). The seeds of repeat r are the same for every method. docs/evaluation.md explains
each choice.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
import torch
from torch.nn.utils.rnn import pad_sequence

from m2d2m.evaluation.evaluator import TextMotionEvaluator
from m2d2m.evaluation.metrics import (
    DEFAULT_MIN_STEP,
    diversity,
    fid,
    frame_jerk,
    jerk,
    mean_frame_jerk,
    mm_dist,
    multimodality,
    peak_jerk_and_auj,
    r_precision,
    transition_windows,
)
from m2d2m.evaluation.sequence_metrics import measure_sequences
from m2d2m.generators.edits import Timeline, apply_edit, margin_frames, regenerate_action
from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.generators.protocol import Keep, MotionGenerator, keep_part
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.features import features_to_joints, joints_to_features
from m2d2m.motion.representation.rigid import bone_length_spread
from m2d2m.motion.transforms.feet import fix_feet
from m2d2m.motion.transforms.joining import slerp_join

WINDOW = 40  # transition frames around a boundary (paper §5.1, after PriorMDM)
JERK_FPS = 1.0  # time in frames: the scale of the paper's Jerk column (ground truth ≈ 1.19)
R_PRECISION_BATCH = 32  # Guo's: each caption against 31 other motions
DIVERSITY_PAIRS = 300
MM_PROMPTS, MM_GENERATIONS = 100, 10  # MModality: prompts, generations per prompt
EMBED_CHUNK = 256  # clips per evaluator call


def _rng(repeat: int, purpose: str) -> np.random.Generator:
    """One stream per repeat and purpose: the seeds of repeat r are the same for every method,
    and do not depend on which other repeats or tables run."""
    return np.random.default_rng([repeat, zlib.crc32(purpose.encode())])


def _seeds(repeat: int, purpose: str, count: int) -> list[int]:
    return [int(s) for s in _rng(repeat, purpose).integers(0, 2**31 - 1, count)]


def _pairs(count: int) -> int:
    """Diversity pairs: Guo's 300, or fewer for a small set (a pair must not need more samples)."""
    return min(DIVERSITY_PAIRS, count - 1)


def _nanmean(values: Sequence[float]) -> float:
    """Mean over the defined values (a window where nothing moves has no Jerk); NaN if none is."""
    kept = np.asarray(values, dtype=np.float64)
    kept = kept[~np.isnan(kept)]
    return float(kept.mean()) if len(kept) else float("nan")


def embed_clips(evaluator: TextMotionEvaluator, clips: Sequence[np.ndarray]) -> np.ndarray:
    """Motion embeddings (len(clips), E) of un-normalised feature clips of any lengths."""
    parts = []
    with torch.no_grad():
        for start in range(0, len(clips), EMBED_CHUNK):
            chunk = [torch.as_tensor(np.asarray(c), dtype=torch.float32) for c in clips[start : start + EMBED_CHUNK]]
            lengths = torch.tensor([len(c) for c in chunk])
            padded = pad_sequence(chunk, batch_first=True).to(evaluator.device)
            parts.append(evaluator.embed_motion(padded, lengths).cpu().numpy())
    return np.concatenate(parts)


def embed_captions(evaluator: TextMotionEvaluator, captions: Sequence[Sequence[str]]) -> np.ndarray:
    with torch.no_grad():
        return np.concatenate(
            [
                evaluator.embed_text(captions[start : start + EMBED_CHUNK]).cpu().numpy()
                for start in range(0, len(captions), EMBED_CHUNK)
            ]
        )


def full_windows(joints: np.ndarray, boundaries: Sequence[int]) -> list[np.ndarray]:
    """The ``WINDOW``-frame windows around the boundaries, clipped ones (at a sequence's ends)
    left out so that every curve drawn from them has the same frames."""
    return [frames for frames in transition_windows(joints, boundaries, WINDOW) if len(frames) == WINDOW]


def flowmdm_jerk(curves: list[np.ndarray], reference: float) -> dict[str, float]:
    """``peak_jerk`` and ``auj`` of the :func:`~m2d2m.evaluation.metrics.frame_jerk` curves of
    full windows; NaN when no window is full."""
    if not curves:
        return {"peak_jerk": float("nan"), "auj": float("nan")}
    peak, area = peak_jerk_and_auj(np.stack(curves), reference)
    return {"peak_jerk": peak, "auj": area}


def transition_profiles(joints: np.ndarray, boundaries: Sequence[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Fig. 5's curves for each full ``WINDOW``-frame window around a boundary: the mean joint
    speed per frame step (metres per frame, ``WINDOW − 1`` values) and the mean jerk magnitude
    normalised by each joint's peak speed in the window (per frame², ``WINDOW − 3`` values)."""
    profiles = []
    for frames in full_windows(joints, boundaries):
        steps = np.linalg.norm(np.diff(frames, axis=0), axis=-1)  # (WINDOW − 1, J) metres per frame
        third = np.linalg.norm(np.diff(frames, n=3, axis=0), axis=-1)  # (WINDOW − 3, J)
        peak = np.maximum(steps.max(0), DEFAULT_MIN_STEP)  # a still joint must not blow up the ratio
        profiles.append((steps.mean(1), (third / peak).mean(1)))
    return profiles


def mean_profile(profiles: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, Any]:
    if not profiles:
        return {"velocity": None, "jerk": None, "windows": 0}
    return {
        "velocity": np.mean([p[0] for p in profiles], 0).tolist(),
        "jerk": np.mean([p[1] for p in profiles], 0).tolist(),
        "windows": len(profiles),
    }


@dataclass
class MultiMeasures:
    """What a set of multi-action motions gives before a repeat's draws: the embeddings of their
    segments and transition windows, their transition jerks, curves and bodies."""

    segments: list[np.ndarray] = field(default_factory=list)  # per batch of motions
    windows: list[np.ndarray] = field(default_factory=list)
    jerks: list[float] = field(default_factory=list)
    curves: list[np.ndarray] = field(default_factory=list)  # frame_jerk of each full window
    profiles: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    bones: list[float] = field(default_factory=list)
    registered: dict[str, list[float]] = field(default_factory=dict)  # per metric of sequence_metrics()

    def add(self, motions: Sequence[Motion], evaluator: TextMotionEvaluator, skeleton: Any) -> None:
        self.segments.append(embed_clips(evaluator, [m.features[a:b] for m in motions for a, b in m.ranges]))
        self.windows.append(
            embed_clips(evaluator, [w for m in motions for w in transition_windows(m.features, m.boundaries, WINDOW)])
        )
        self.jerks += [jerk(m.joints, JERK_FPS, m.boundaries, WINDOW) for m in motions]
        self.curves += [frame_jerk(w) for m in motions for w in full_windows(m.joints, m.boundaries)]
        self.profiles += [p for m in motions for p in transition_profiles(m.joints, m.boundaries)]
        self.bones += [bone_length_spread(m.joints, skeleton)["mean"] for m in motions]
        for name, values in measure_sequences([(m.joints, m.boundaries) for m in motions], skeleton).items():
            self.registered.setdefault(name, []).extend(values)

    def metrics(self, reference: Reference, repeat: int) -> dict[str, float]:
        """The multi-motion table's row for repeat ``repeat`` (its shuffle and diversity draws)."""
        segment_emb, window_emb = np.concatenate(self.segments), np.concatenate(self.windows)
        order = _rng(repeat, "order").permutation(reference.items)
        return {
            **_matching(reference.text, segment_emb, order, reference.rp_batch),
            "fid": fid(segment_emb, reference.segments),
            "diversity": diversity(segment_emb, _pairs(len(segment_emb)), seed=repeat),
            "transition_fid": fid(window_emb, reference.windows),
            "transition_diversity": diversity(window_emb, _pairs(len(window_emb)), seed=repeat),
            "jerk": _nanmean(self.jerks),
            **flowmdm_jerk(self.curves, reference.frame_jerk_mean),
            "bone_std": _nanmean(self.bones),
            **{name: _nanmean(values) for name, values in self.registered.items()},
        }


@dataclass
class RegeneratedMeasures:
    """What one action of each sequence and its joins give (the timeline-editing table): the
    action's caption index, the embeddings of its frames and of the windows at its joins, the
    paper's Jerk there."""

    items: list[int] = field(default_factory=list)
    segments: list[np.ndarray] = field(default_factory=list)
    windows: list[np.ndarray] = field(default_factory=list)
    jerks: list[float] = field(default_factory=list)

    def add(self, motions: Sequence[Motion], index: int, items: Sequence[int], evaluator: TextMotionEvaluator) -> None:
        """Action ``index`` of each motion, which is test item ``items[i]`` of the reference."""
        joins = [[m.boundaries[i] for i in (index - 1, index) if 0 <= i < len(m.boundaries)] for m in motions]
        self.items += list(items)
        self.segments.append(embed_clips(evaluator, [m.features[slice(*m.ranges[index])] for m in motions]))
        self.windows.append(
            embed_clips(
                evaluator, [w for m, at in zip(motions, joins) for w in transition_windows(m.features, at, WINDOW)]
            )
        )
        self.jerks += [jerk(m.joints, JERK_FPS, at, WINDOW) for m, at in zip(motions, joins)]

    def metrics(self, reference: Reference, repeat: int) -> dict[str, float]:
        """R-Top3 of the action against its caption (groups of up to R_PRECISION_BATCH of these
        actions) and FID against every ground-truth segment; transition FID and Jerk at its joins."""
        segments = np.concatenate(self.segments)
        order = _rng(repeat, "order").permutation(len(segments))
        return {
            **_matching(reference.text[self.items], segments, order, min(R_PRECISION_BATCH, len(segments))),
            "fid": fid(segments, reference.segments),
            "transition_fid": fid(np.concatenate(self.windows), reference.windows),
            "jerk": _nanmean(self.jerks),
        }


def _single_metrics(reference: Reference, embedded: np.ndarray, order: np.ndarray, repeat: int) -> dict[str, float]:
    """The single-motion table's columns but MModality, for items embedded in test-set order."""
    return {
        **_matching(reference.text, embedded, order, reference.rp_batch),
        "fid": fid(embedded, reference.segments),
        "diversity": diversity(embedded, _pairs(len(embedded)), seed=repeat),
    }


def _matching(text: np.ndarray, motion: np.ndarray, order: np.ndarray, batch: int) -> dict[str, float]:
    """R-Top1..3 over consecutive groups of ``batch`` in the repeat's shuffled order (Guo
    shuffles; the incomplete group is dropped), and MM-Dist over the same rows."""
    used = order[: len(order) // batch * batch]
    precision = r_precision(text[used], motion[used], top_k=3, batch=batch)
    return {
        **{f"r_top{k + 1}": float(p) for k, p in enumerate(precision)},
        "mm_dist": mm_dist(text[used], motion[used]),
    }


@dataclass
class Reconstruction:
    """The test set through one codec: its instances decoded together, its items alone (their
    embeddings), and the decoded sequences, to recognise the same codec in another model."""

    measures: MultiMeasures
    items: np.ndarray  # (items, E)
    sequences: list[np.ndarray]


@dataclass
class Reference:
    """What the test set contributes whatever the method: its requests, the caption embeddings,
    the ground-truth segment and middle-window embeddings, and the ground-truth Jerk values."""

    actions: list[list[str]]  # per instance
    frames: list[list[int]]  # per instance, each action's length as the generator makes it
    text: np.ndarray  # (items, E)
    segments: np.ndarray  # (items, E)
    windows: np.ndarray  # (items, E): the middle WINDOW frames of each item
    jerk_single: float
    jerk_concat: float
    frame_jerk_mean: float  # AUJ's constant: the ground-truth items' mean frame jerk (m / frame³)
    flowmdm_single: dict[str, float]  # PJ and AUJ of the items' middle windows
    flowmdm_concat: dict[str, float]  # PJ and AUJ at the boundaries of the concatenated items
    concat_profile: dict[str, Any]
    bone_std: float  # mm, of the ground-truth segments' joints as recovered from their features
    registered_concat: dict[str, float]  # each registered sequence metric of the concatenated items
    registered_single: dict[str, float]  # each registered sequence metric of the items, alone
    features: list[list[np.ndarray]] = field(default_factory=list)  # each segment cut to its generated length
    reconstructions: dict[str, Reconstruction] = field(default_factory=dict)  # by the models sharing a codec

    @property
    def items(self) -> int:
        return len(self.text)

    @property
    def item_features(self) -> list[np.ndarray]:
        """Every item's ground-truth features as generated for it, in item order."""
        return [clip for clips in self.features for clip in clips]

    @property
    def rp_batch(self) -> int:
        """R-precision's group size: Guo's 32, or every item of a smaller test set."""
        return min(R_PRECISION_BATCH, self.items)

    @classmethod
    def build(
        cls,
        actions: list[list[str]],
        segments: list[list[np.ndarray]],
        captions: list[list[str]],
        evaluator: TextMotionEvaluator,
        skeleton: Any,
        frame_step: int = 1,
    ) -> Reference:
        """From each instance's action sentences and ground-truth feature segments, and each
        item's caption as ``word/POS`` tokens (items in instance order). Every length is cut to
        a multiple of ``frame_step`` (whole tokens of a token model, as Guo's loader crops), the
        coarsest step of the generators measured against it, so that all get the same requests."""
        frames = [[max(1, len(clip) // frame_step) * frame_step for clip in clips] for clips in segments]
        features = [[clip[:n] for clip, n in zip(clips, lengths)] for clips, lengths in zip(segments, frames)]
        flat = [clip for clips in features for clip in clips]
        middles = [transition_windows(clip, [len(clip) // 2], WINDOW)[0] for clip in flat]
        joints = [[features_to_joints(clip, skeleton) for clip in clips] for clips in features]
        single = [jerk(j, JERK_FPS, [len(j) // 2], WINDOW) for clips in joints for j in clips]
        # joined with no transition window: each clip turned and moved to where the previous ended
        concat = [
            (joined, [first for first, _ in ranges[1:]])
            for joined, ranges in (slerp_join(clips, 0, skeleton) for clips in joints)
        ]
        constant = mean_frame_jerk([j for clips in joints for j in clips if len(j) >= 4])
        middle_curves = [frame_jerk(w) for clips in joints for j in clips for w in full_windows(j, [len(j) // 2])]
        concat_curves = [frame_jerk(w) for j, b in concat for w in full_windows(j, b)]
        reference = cls(
            actions=actions,
            frames=frames,
            text=embed_captions(evaluator, captions),
            segments=embed_clips(evaluator, flat),
            windows=embed_clips(evaluator, middles),
            jerk_single=_nanmean(single),
            jerk_concat=_nanmean([jerk(j, JERK_FPS, b, WINDOW) for j, b in concat]),
            frame_jerk_mean=constant,
            flowmdm_single=flowmdm_jerk(middle_curves, constant),
            flowmdm_concat=flowmdm_jerk(concat_curves, constant),
            concat_profile=mean_profile([p for j, b in concat for p in transition_profiles(j, b)]),
            bone_std=_nanmean([bone_length_spread(j, skeleton)["mean"] for clips in joints for j in clips]),
            registered_concat={name: _nanmean(values) for name, values in measure_sequences(concat, skeleton).items()},
            registered_single={
                name: _nanmean(values)
                for name, values in measure_sequences([(j, []) for clips in joints for j in clips], skeleton).items()
            },
            features=features,
        )
        return reference

    def add_reconstruction(self, label: str, generator: MotionGenerator, evaluator: TextMotionEvaluator) -> str | None:
        """Measure the test set through ``generator``'s codec, if it has one, under ``label``; a
        codec that reconstructs exactly as one measured before (models sharing a VQ-VAE) is not
        measured twice. Returns the label its rows are under, or None for a model without a codec."""
        reconstructed = generator.reconstruct(self.features)
        if reconstructed is None:
            return None
        for known, earlier in self.reconstructions.items():
            if len(earlier.sequences) == len(reconstructed) and all(
                np.array_equal(a, m.features) for a, m in zip(earlier.sequences, reconstructed)
            ):
                return known
        measures = MultiMeasures()
        measures.add(reconstructed, evaluator, generator.skeleton)
        items = embed_clips(
            evaluator, [m.features for m in generator.reconstruct([[clip] for clip in self.item_features])]
        )
        self.reconstructions[label] = Reconstruction(measures, items, [m.features for m in reconstructed])
        return label

    def measure(self, repeat: int) -> dict[str, float]:
        """The "ground truth (single)" row for one repeat (its shuffle and diversity draws)."""
        order = _rng(repeat, "order").permutation(self.items)
        return {
            **_matching(self.text, self.segments, order, self.rp_batch),
            "diversity": diversity(self.segments, _pairs(self.items), seed=repeat),
            "transition_diversity": diversity(self.windows, _pairs(self.items), seed=repeat),
            "jerk": self.jerk_single,
            **self.flowmdm_single,
            "bone_std": self.bone_std,
            **self.registered_single,
        }

    def reconstruction_rows(self, label: str, repeat: int) -> tuple[dict[str, float], dict[str, float]]:
        """The "VQ-VAE reconstruction" rows of the multi- and single-motion tables for one
        repeat, of the codec measured under ``label``."""
        reconstruction = self.reconstructions[label]
        order = _rng(repeat, "order").permutation(self.items)
        return (
            reconstruction.measures.metrics(self, repeat),
            _single_metrics(self, reconstruction.items, order, repeat),
        )

    def concat_row(self) -> dict[str, float]:
        """The "ground truth (concat)" row: its transition jerks, the same in every repeat."""
        return {"jerk": self.jerk_concat, **self.flowmdm_concat, **self.registered_concat}


class FinishedBatches(Protocol):
    """Where the generated batches of the job in progress are kept, so that a job stopped midway
    continues from its last finished batch (orchestration/evaluate/run.py keeps them on disk).
    ``part`` names the set of requests, ``start`` and ``size`` the batch within it."""

    def load(self, part: str, start: int, size: int) -> list[Motion] | None: ...

    def save(self, part: str, start: int, size: int, motions: list[Motion]) -> None: ...


class Evaluation:
    """The measurements of one run: a loaded generator and evaluator, the test set's
    :class:`Reference`, the knobs that differ from the generator's presets (the user's: they
    change every table, so ``steps=100`` makes MotionDiffuse's single-motion rows quick too), and
    a progress callback called after each generated batch, and where finished batches are kept
    (``finished``; none: every batch is generated)."""

    def __init__(
        self,
        generator: MotionGenerator,
        evaluator: TextMotionEvaluator,
        reference: Reference,
        knobs: dict[str, Any],
        batch_size: int,
        progress: Callable[[str], None],
    ) -> None:
        self.generator = generator
        self.evaluator = evaluator
        self.reference = reference
        self.knobs = knobs
        self.batch_size = batch_size
        self.progress = progress
        self.finished: FinishedBatches | None = None

    def _generate(
        self,
        actions: list[list[str]],
        frames: list[list[int]],
        options: Any,
        seeds: list[int],
        label: str,
        part: str,
        keep: list[Keep] | None = None,
    ) -> Iterator[list[Motion]]:
        """The motions of the requests, one batch at a time (a whole repeat would not fit in
        memory on a real test set); a batch kept from an interrupted attempt is read, not
        generated again (every sequence is drawn from its own seed, so it is the same)."""
        for start in range(0, len(actions), self.batch_size):
            window = slice(start, start + self.batch_size)
            kept = self.finished.load(part, start, self.batch_size) if self.finished else None
            if kept is None:
                kept = self.generator.generate(
                    actions[window], frames[window], options, seeds[window], None if keep is None else keep[window]
                )
                if self.finished:
                    self.finished.save(part, start, self.batch_size, kept)
            yield kept
            self.progress(label)

    def multi(self, method: str, repeat: int) -> dict[str, Any]:
        """One repeat of one method on the multi-motion test set: the metrics and Fig. 5's curves."""
        reference = self.reference
        options = self.generator.options(MULTI, method=method, **self.knobs)
        seeds = _seeds(repeat, "multi", len(reference.actions))
        skeleton = self.generator.skeleton
        measures = {variant: MultiMeasures() for variant in ("raw", *FEET_VARIANTS)}
        label = f"{method} r{repeat}"
        for motions in self._generate(reference.actions, reference.frames, options, seeds, label, "multi"):
            measures["raw"].add(motions, self.evaluator, skeleton)
            for variant, change in FEET_VARIANTS.items():
                measures[variant].add([change(m, skeleton) for m in motions], self.evaluator, skeleton)
        return {
            "method": method,
            "repeat": repeat,
            "metrics": measures["raw"].metrics(reference, repeat),
            **{f"metrics_{variant}": measures[variant].metrics(reference, repeat) for variant in FEET_VARIANTS},
            "profile": mean_profile(measures["raw"].profiles),
        }

    def single(self, repeat: int) -> dict[str, Any]:
        """One repeat of the single-motion table: every test item generated alone with the
        paper's single-motion settings, and MModality from ``MM_GENERATIONS`` generations of
        each of the first ``MM_PROMPTS`` items in the repeat's order."""
        reference = self.reference
        options = self.generator.options(SINGLE, **self.knobs)
        actions = [[action] for instance in reference.actions for action in instance]
        frames = [[n] for instance in reference.frames for n in instance]
        order = _rng(repeat, "order").permutation(reference.items)
        label = f"single r{repeat}"
        embedded = self._embed_generated(
            actions, frames, options, _seeds(repeat, "single", len(actions)), label, "single"
        )
        prompts = order[: min(MM_PROMPTS, reference.items)]
        repeated = [p for p in prompts for _ in range(MM_GENERATIONS)]
        again = self._embed_generated(
            [actions[p] for p in repeated],
            [frames[p] for p in repeated],
            options,
            _seeds(repeat, "mmodality", len(repeated)),
            label,
            "mmodality",
        )
        metrics = {
            **_single_metrics(reference, embedded, order, repeat),
            "mmodality": multimodality(
                again.reshape(len(prompts), MM_GENERATIONS, -1), pairs=MM_GENERATIONS, seed=repeat
            ),
        }
        return {"repeat": repeat, "metrics": metrics}

    def edit(self, task: str, text: bool, repeat: int) -> dict[str, Any]:
        """One repeat of one row of the editing table (MMM Table 3): every test item regenerated
        with the single-action settings, keeping what ``task`` keeps of its ground truth, under
        its sentence (``text``) or the empty sentence, the null condition; measured as the
        single-motion table measures (against the items' captions and ground-truth segments)."""
        reference = self.reference
        flat = reference.item_features
        actions = [[action if text else ""] for instance in reference.actions for action in instance]
        frames = [[len(clip)] for clip in flat]
        keep = [EDITS[task](clip, self.generator.skeleton) for clip in flat]
        order = _rng(repeat, "order").permutation(reference.items)
        label = f"{task} {'with' if text else 'without'} text r{repeat}"
        embedded = self._embed_generated(
            actions,
            frames,
            self.generator.options(SINGLE, **self.knobs),
            _seeds(repeat, f"edit-{task}", len(actions)),
            label,
            "edit",
            keep,
        )
        return {
            "task": task,
            "text": text,
            "repeat": repeat,
            "metrics": _single_metrics(reference, embedded, order, repeat),
        }

    def regenerate(self, method: str, edit_method: str, action: int, repeat: int) -> dict[str, Any]:
        """One repeat of the timeline-editing table (issue 41; docs/evaluation.md, "Editing on the
        timeline"): each test instance generated by ``method`` as the multi-motion table generates
        it, then its ``action``-th action (from 1) sampled again by an edit that keeps the rest
        (:func:`~m2d2m.generators.edits.regenerate_action`, sampled with ``edit_method``), against
        the whole sequence sampled again by ``method``; the edit and the whole sequence are drawn
        from the same new seeds. Both measured on that action and its joins
        (:class:`RegeneratedMeasures`)."""
        reference, generator = self.reference, self.generator
        index = action - 1
        shortest = min(len(instance) for instance in reference.actions)
        if not 0 <= index < shortest:
            raise ValueError(f"action {action} of a test set whose instances have {shortest} action(s)")
        offsets = np.cumsum([0, *(len(instance) for instance in reference.actions)])[:-1]
        count = len(reference.actions)
        first_seeds, new_seeds = _seeds(repeat, "multi", count), _seeds(repeat, "regenerate", count)
        options = generator.options(MULTI, method=method, **self.knobs)
        editing = generator.options(MULTI, method=edit_method, **self.knobs)
        margin = margin_frames(generator)
        label = f"regenerate {action} r{repeat}"
        measures = {"edit": RegeneratedMeasures(), "whole": RegeneratedMeasures()}
        sources = self._generate(reference.actions, reference.frames, options, first_seeds, label, "source")
        wholes = self._generate(reference.actions, reference.frames, options, new_seeds, label, "whole")
        for start, (motions, again) in zip(range(0, count, self.batch_size), zip(sources, wholes)):
            window = slice(start, start + len(motions))
            edits = [
                regenerate_action(Timeline(m.features, m.actions, [a for a, _ in m.ranges]), index, margin)
                for m in motions
            ]
            (sampled,) = list(
                self._generate(
                    [e.actions for e in edits],
                    [e.frames for e in edits],
                    editing,
                    new_seeds[window],
                    label,
                    f"edit{start}",
                    [e.keep for e in edits],
                )
            )
            edited = [apply_edit(e, m, generator.skeleton) for e, m in zip(edits, sampled)]
            items = offsets[window] + index
            measures["edit"].add(edited, index, items, self.evaluator)
            measures["whole"].add(again, index, items, self.evaluator)
        return {
            "method": method,
            "edit_method": edit_method,
            "action": action,
            "repeat": repeat,
            "metrics": measures["edit"].metrics(reference, repeat),
            "metrics_whole": measures["whole"].metrics(reference, repeat),
        }

    def _embed_generated(
        self,
        actions: list[list[str]],
        frames: list[list[int]],
        options: Any,
        seeds: list[int],
        label: str,
        part: str,
        keep: list[Keep] | None = None,
    ) -> np.ndarray:
        return np.concatenate(
            [
                embed_clips(self.evaluator, [m.features for m in motions])
                for motions in self._generate(actions, frames, options, seeds, label, part, keep)
            ]
        )


def with_planted_feet(motion: Motion, skeleton: Any) -> Motion:
    """``motion`` with its feet planted where the model's own contact channels say they touch
    down, checked against its joints, as a delivery plants them (one function for both:
    :func:`m2d2m.motion.transforms.feet.fix_feet`), and its features
    changed by exactly what the fix changed: the model's features plus the difference between
    the features of the planted joints and those of the generated joints, both derived alike.

    Why not the planted joints' features alone: the evaluator then judges the round trip from
    features to joints and back as well as the fix, and on the demo's models the round trip
    alone moved FID from 0.3–1.5 to 2.6–20 (docs/evaluation.md, "Feet that stay planted"). The
    contact channels stay the model's: the fix moves feet, not where they touch."""
    planted = fix_feet(motion.joints, skeleton, motion.fps, motion.features)
    change = joints_to_features(planted, skeleton) - joints_to_features(motion.joints, skeleton)
    features = motion.features + np.concatenate([change, change[-1:]])
    features[:, -4:] = motion.features[:, -4:]
    return replace(motion, joints=planted, features=features.astype(np.float32))


# The rows each multi-motion row gets beside it (issue 40 §3): its motions changed by each of these.
FEET_VARIANTS: dict[str, Callable[[Motion, Any], Motion]] = {"planted": with_planted_feet}


def inbetween_keep(features: np.ndarray, skeleton: Any) -> Keep:
    """In-betweening as MMM's Table 3 evaluates it: the first and last 25 % of the frames kept,
    the middle 50 % generated."""
    frames = np.zeros(len(features), dtype=bool)
    quarter = len(features) // 4
    frames[:quarter] = True
    frames[len(features) - quarter :] = True
    return Keep(features, frames)


def upper_body_keep(features: np.ndarray, skeleton: Any) -> Keep:
    """Upper-body editing as MMM's Table 3 evaluates it: the lower body kept on every frame, the
    upper body generated (:mod:`m2d2m.motion.representation.body_parts`)."""
    return keep_part(features, skeleton, "lower")


# editing tasks of the editing table: what each keeps of a ground-truth item
EDITS: dict[str, Callable[[np.ndarray, Any], Keep]] = {"inbetween": inbetween_keep, "upper": upper_body_keep}
