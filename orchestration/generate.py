"""Text to motion for people: `m2d2m generate` with any registered model.

:func:`load_generator` finds a model file (``latest``, a file, a run directory or name, an MLflow
run id) and loads the model's generator. In front of the generator's protocol call sit the
optional steps a person's prompts need: splitting free text into action sentences with the
dataset's tagger (as the corpus was split), giving each action a length (the seconds asked for,
or the corpus's typical length for its verb) under a cap on the whole, and putting the decoded
joints on one rigid skeleton so that every file of a generation shows the same body.
:func:`plan_output` checks where the files go and in which formats before anything is loaded, as
:func:`check_prompted`, :func:`plan_parts` and :func:`length_cap` check what is asked;
:func:`save_generation` writes them into a run folder whose ``run.json`` says how it ended, or,
inside :func:`staged`, into a temporary folder moved into place when the command ends: a target that
holds an earlier result is refused (:func:`check_free`) or, with ``--overwrite``, replaced whole.
Each generation is recorded in MLflow.
"""

from __future__ import annotations

import math
import re
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.atomic import atomic_files, atomic_folder
from m2d2m.generators.protocol import MotionGenerator, keep_part, keep_spans
from m2d2m.layout import NLP, recorded_path
from m2d2m.motion.body_parts import PARTS
from m2d2m.motion.clip import Motion
from m2d2m.motion.delivery import Delivery
from m2d2m.motion.formats import DEFAULT_FORMATS, FORMATS, formats_named, on_rig, spoken, suffixes
from m2d2m.progress import progress
from orchestration.errors import UserError
from orchestration.registry import DEFAULT_MODEL, model, models
from orchestration.runs import new_run_dir, run_file, write_run_info
from orchestration.tracking import experiment_name, tracked_run, unreachable

GENERATE_STAGE = "generate"
# a suffix that names a kind of file (.fbx, .glb, .json), not a folder name like "v1.2": --out with
# one that is not a format is refused rather than made into a folder of that name
FILE_SUFFIX = re.compile(r"\.[A-Za-z][A-Za-z0-9]{0,4}")
# A 590-s clip took 293 s and a 182-MB GIF: a minute is several actions, and seconds to make.
DEFAULT_MAX_SECONDS = 60.0


@dataclass(frozen=True)
class Output:
    """Where a generation's files go: ``directory`` (None: a new run folder, made when the motion
    is ready), the file stem ``name``, the ``formats``, and how the clip is delivered (its feet,
    frame rate, loop, root motion, bind pose and rig: :class:`~m2d2m.motion.delivery.Delivery`).
    ``one_file``: ``--out`` named a file, so the files of ``name`` in ``directory`` are the target,
    not the folder; ``overwrite``: an earlier result there is replaced; ``staging``: the temporary
    folder the files are written into until :func:`staged` moves them into ``directory``."""

    directory: Path | None
    name: str
    formats: tuple[str, ...]
    delivery: Delivery = Delivery()
    overwrite: bool = False
    one_file: bool = False
    staging: Path | None = None


def plan_output(
    out: str | Path | None,
    name: str,
    formats: Sequence[str] | None,
    delivery: Delivery = Delivery(),
    overwrite: bool = False,
) -> Output:
    """Check ``--out``, ``--name`` and ``--formats`` before anything is loaded or sampled.

    ``out`` ending in a format's suffix (``clip.gif``) is one file, as for ``m2d2m render`` and
    ``export``: its stem is the name and its suffix the format (``formats`` may only repeat it);
    any other ``out`` is a folder, which must not be an existing file; none is a new run folder.
    A target holding an earlier result is refused unless ``overwrite`` (:func:`check_free`).
    MP4 needs an encoder here and FBX Blender, found up front.
    """
    chosen = tuple(dict.fromkeys(formats or ()))
    one_file = False
    try:
        formats_named(chosen)
    except ValueError as error:
        raise UserError(str(error)) from error
    directory = None if out is None else Path(out)
    if directory is not None and directory.suffix.lower().lstrip(".") in FORMATS:
        suffix = directory.suffix.lower().lstrip(".")
        if chosen and chosen != (suffix,):
            raise UserError(
                f"--out {out} names one .{suffix} file; drop --formats, or give a folder as --out "
                f"to write {', '.join(chosen)}"
            )
        if directory.is_dir():
            raise UserError(
                f"--out {out} is a folder; give a new file name, or --out {directory.parent} "
                f"--name {directory.stem} --formats {suffix}"
            )
        directory, name, chosen, one_file = directory.parent, directory.stem, (suffix,), True
    elif directory is not None and directory.exists() and not directory.is_dir():
        raise UserError(
            f"--out {out} is an existing file, not a folder; give a folder, or a file name "
            f"ending in {suffixes(FORMATS.values())}"
        )
    elif directory is not None and not directory.exists() and FILE_SUFFIX.fullmatch(directory.suffix):
        raise UserError(
            f"--out {out} names a .{directory.suffix[1:]} file, a format m2d2m does not write "
            f"({suffixes(FORMATS.values())}); for a folder of that name, make it first"
        )
    if not name or Path(name).name != name:
        raise UserError(f"--name must be a plain file name, got {name!r}")
    chosen = chosen or DEFAULT_FORMATS
    if delivery.rig is not None and not any(FORMATS[kind].on_rig for kind in chosen):
        raise UserError(
            f"--rig goes with a {spoken(on_rig())}, the formats written on a rig: add one "
            f"to --formats, or --out {spoken(f'x.{fmt.suffix}' for fmt in on_rig())}"
        )
    for kind in chosen:
        lacking = FORMATS[kind].lacking()
        if lacking is not None:
            raise UserError(lacking)
    output = Output(directory, name, chosen, delivery, overwrite, one_file)
    check_free(output)
    return output


def check_free(output: Output) -> None:
    """Refuse, in one line, a target that holds an earlier result unless ``overwrite`` is set, so
    that one folder never holds two clips' files: a folder ``--out`` with files in it (replaced
    whole with ``overwrite``: :func:`staged`), or, for a file ``--out``, any file of its name (a
    ``.npy``'s sidecar, features and root track included). A folder holding folders, or the
    working directory, is no earlier result: it is never replaced."""
    directory = output.directory
    if directory is None:
        return
    if output.one_file:
        taken = [
            n for kind in output.formats for n in FORMATS[kind].file_names(output.name) if (directory / n).exists()
        ]
        if taken and not output.overwrite:
            raise UserError(f"{directory / taken[0]} exists; give another name, or --overwrite to replace it")
        return
    if not directory.is_dir() or not any(directory.iterdir()):
        return
    folders = sorted(entry.name for entry in directory.iterdir() if entry.is_dir())
    if folders:
        raise UserError(
            f"--out {directory} holds folders ({', '.join(folders[:3])}), not an earlier result's files; "
            "give a new folder"
        )
    if Path.cwd().resolve().is_relative_to(directory.resolve()):
        raise UserError(f"--out {directory} is the working folder; give a new folder")
    if not output.overwrite:
        count = sum(1 for _ in directory.iterdir())
        raise UserError(
            f"--out {directory} holds an earlier result ({count} file{'s' if count > 1 else ''}); give a new "
            "folder, or --overwrite to replace the folder and every file in it"
        )


def variations(output: Output, seed: int, count: int) -> list[tuple[int, Output]]:
    """``--variations N``: the seeds to sample (``seed``, ``seed + 1``, …) and where each sample
    goes (in a folder or file named, ``<name>-seed<seed>``; without one each in its own run folder);
    the files of a file ``--out`` so named are checked free (:func:`check_free`)."""
    if count == 1:
        return [(seed, output)]
    named = output.directory is not None
    planned = [
        (variation, replace(output, name=f"{output.name}-seed{variation}") if named else output)
        for variation in range(seed, seed + count)
    ]
    for _, variation in planned:
        if variation.one_file:
            check_free(variation)
    return planned


@contextmanager
def staged(planned: Sequence[tuple[int, Output]]) -> Iterator[list[tuple[int, Output]]]:
    """The seeds and outputs of one command (:func:`variations`, all in one place), written into a
    temporary folder and moved into place when the block ends without an error, all or nothing
    (:mod:`m2d2m.atomic`): a folder ``--out`` becomes the new folder whole, the old one's files
    all gone; a file ``--out`` its files, none of an earlier write of its name left beside them.
    If the block raises, nothing there changes. A new run folder (no ``directory``) is fresh
    already and written in place."""
    output = planned[0][1]
    if output.directory is None:
        yield list(planned)
        return
    if output.one_file:
        owned = [name for _, each in planned for kind in each.formats for name in FORMATS[kind].file_names(each.name)]
        writing = atomic_files(output.directory, output.name, owned)
    else:
        writing = atomic_folder(output.directory)
    with writing as staging:
        yield [(seed, replace(each, staging=staging)) for seed, each in planned]


def resolve_model_file(name: str, reference: str | Path, dataset: str) -> Path:
    """The model file of model ``name`` from a path, a run directory, ``latest``, a run name or an
    MLflow run id."""
    entry = model(name)
    return run_file(reference, dataset, entry.stage, entry.model_file, f"make {entry.train_verb}")


def load_generator(
    name: str = DEFAULT_MODEL, reference: str | Path = "latest", dataset: str = "synthetic", device: str = "auto"
) -> MotionGenerator:
    """Model ``name``'s generator from its model file (on a GPU when there is one, by default)."""
    path = resolve_model_file(name, reference, dataset)
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        return model(name).load("generator").load(path, device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(str(error)) from error


def require_words(prompt: str) -> None:
    """Refuse, in one line, a prompt of punctuation or emoji alone: the model would sample from no words."""
    if not re.search(r"[^\W_]", prompt):
        raise UserError(f"the prompt {prompt!r} has no words; describe an action, e.g. 'a person walks forward'")


class PromptPlanner:
    """Free-text prompts → action sentences and lengths in frames for one generator."""

    def __init__(self, generator: MotionGenerator) -> None:
        self.generator = generator
        self._tagger = None
        self._verbs: dict[str, str | None] = {}  # each action sentence split out so far → its verb

    def split(self, prompt: str) -> tuple[list[str], list[str | None]]:
        """Action sentences and their verbs, split as the corpus's captions were."""
        from pipelines.language import decompose, load_tagger

        require_words(prompt)
        if self._tagger is None:
            data_dir = self.generator.data_dir
            try:
                self._tagger = load_tagger(recorded_path(data_dir, self.generator.source) / NLP if data_dir else None)
            except FileNotFoundError as error:
                raise UserError(f"{error} (or pass --no-split)") from error
        parts = decompose(prompt, tagger=self._tagger)
        verbs: list[str | None] = (
            list(parts.verbs) if len(parts.verbs) == len(parts.actions) else [None] * len(parts.actions)
        )
        self._verbs.update(zip(parts.actions, verbs))
        return list(parts.actions), verbs

    def notices(self, actions: Sequence[str]) -> list[str]:
        """What the model does not know of ``actions``, one sentence each, to say before sampling:
        words its text encoder never read in training (it reads them as unknown), and the verb of
        a split action that it was never shown alone (not a light verb's, "does a cartwheel": its
        action is its object's). Nothing stops: it samples from the rest."""
        from pipelines.language import LIGHT_VERBS, action_verbs

        known = self.generator.known_verbs
        nameable = action_verbs(known)
        listed = ", ".join(nameable[:12]) + (", …" if len(nameable) > 12 else "")
        said = []
        for action in dict.fromkeys(actions):
            unknown = self.generator.unknown_words(action)
            if unknown:
                words = ", ".join(f"'{word}'" for word in unknown)
                were = "it were" if len(unknown) == 1 else "they were"
                said.append(f"{action!r}: the model never read {words} in training; it samples as if {were} not there")
            verb = self._verbs.get(action)
            if known and verb and verb not in known and verb not in LIGHT_VERBS:
                said.append(
                    f"{action!r}: the model was never shown '{verb}' alone; it knows {len(nameable)} actions "
                    f"({listed}; `m2d2m models` lists them)"
                )
        return said

    def plan(
        self, prompts: Sequence[str], seconds: Sequence[float] | None = None, split: bool = True
    ) -> tuple[list[str], list[int]]:
        """The action sentences and their lengths in frames for ``prompts``.

        With ``split`` a prompt with several verbs becomes several actions; a prompt's ``seconds``
        are then shared among its actions in proportion to their typical lengths. Without
        ``seconds`` every action gets the corpus's typical length for its verb.
        """
        prompts = list(prompts)
        if not prompts or any(not p.strip() for p in prompts):
            raise UserError("give at least one non-empty prompt")
        for prompt in prompts:
            require_words(prompt)
        if seconds is not None and len(seconds) not in (1, len(prompts)):
            raise UserError(f"give one duration per prompt ({len(prompts)}) or one for all, not {len(seconds)}")
        step = self.generator.frame_step
        actions: list[str] = []
        frames: list[int] = []
        for index, prompt in enumerate(prompts):
            parts, verbs = self.split(prompt) if split else ([" ".join(prompt.lower().split())], [None])
            typical = [self.generator.typical_frames(verb) // step for verb in verbs]
            if seconds is not None:
                wanted = float(seconds[0] if len(seconds) == 1 else seconds[index])
                check_seconds(self.generator, wanted, repr(prompt), actions=len(parts))
                typical = share(max(len(parts), round(wanted * self.generator.fps / step)), typical)
            actions.extend(parts)
            frames.extend(n * step for n in typical)
        return actions, frames


def seconds_range(generator: MotionGenerator) -> tuple[float, float]:
    """The shortest and longest action the model supports: one step of its granularity, and
    the longest clip it was trained on."""
    return generator.frame_step / generator.fps, generator.longest_frames / generator.fps


def check_seconds(generator: MotionGenerator, seconds: float, what: str, actions: int = 1) -> None:
    """The one refusal of a length no action of this model can have, for every way of asking
    (a prompt's ``--seconds``, an action of the API, an edit's new or re-timed action, a gap, an
    uploaded motion's action): ``what`` names it; a prompt split into ``actions`` may last as
    long as that many. Checked before the seconds become frames, so no length reaches arithmetic
    (a NaN, or 1e308 s, which is no number of frames)."""
    lo, hi = seconds_range(generator)
    if not lo <= seconds <= hi * actions:  # NaN fails too
        raise UserError(f"{seconds:g} s for {what} is outside what this model supports ({lo:g}–{hi:g} s per action)")


def action_frames(generator: MotionGenerator, seconds: float, what: str) -> int:
    """An action of ``seconds`` (:func:`check_seconds`) in the model's frames, whole steps."""
    check_seconds(generator, seconds, what)
    return generator.round_frames(round(seconds * generator.fps))


def share(total: int, typical: list[int]) -> list[int]:
    """Split ``total`` steps among actions in proportion to their typical lengths, at least one each."""
    weights = np.asarray(typical, dtype=np.float64)
    raw = np.maximum(1, np.floor(total * weights / weights.sum())).astype(int)
    raw[np.argmax(weights)] += total - int(raw.sum())
    return [int(n) for n in raw]


def length_cap(max_seconds: float | None) -> float | None:
    """The cap ``--max-seconds`` asks for: :data:`DEFAULT_MAX_SECONDS` when not given, none for 0."""
    if max_seconds is not None and not 0 <= max_seconds < math.inf:
        raise UserError(f"--max-seconds must be a positive number (0 for no cap), got {max_seconds:g}")
    return DEFAULT_MAX_SECONDS if max_seconds is None else max_seconds or None


def check_length(frames: Sequence[int], fps: float, max_seconds: float | None, remedy: str | None = None) -> None:
    """A one-line refusal, before sampling, of a generation longer than ``max_seconds`` (None: no
    cap): its time and its GIF grow with its length. ``remedy`` ends the line (default: the
    command line's flags; the API names its own fields)."""
    if max_seconds is not None and not 0 < max_seconds < math.inf:
        raise UserError(f"--max-seconds must be a positive number (0 for no cap), got {max_seconds:g}")
    total = sum(frames) / fps
    if max_seconds is not None and total > max_seconds:
        remedy = remedy or (
            f"give fewer or shorter prompts (--seconds), or --max-seconds {math.ceil(total)} to make it anyway"
        )
        raise UserError(
            f"the prompts make {total:.1f} s of motion in {len(frames)} action(s), over the "
            f"{max_seconds:g}-s cap; {remedy}"
        )


@contextmanager
def _progress(description: str) -> Iterator[Callable[[float], None]]:
    """A percentage bar on stderr for a generator's ``progress`` callback (the fraction done), plain
    lines when stderr is not a terminal (none for a generation of a few seconds)."""
    with progress(total=100, unit="%", desc=description, leave=False) as bar:
        yield lambda done: bar.update(round(100 * done) - bar.n)


def generate(
    generator: MotionGenerator,
    prompts: str | Sequence[str],
    seconds: float | Sequence[float] | None = None,
    seed: int = 0,
    split: bool = True,
    max_seconds: float | None = DEFAULT_MAX_SECONDS,
    **options: Any,
) -> Motion:
    """One motion doing ``prompts`` in order, with the generator's multi-action preset changed by
    ``options`` (for M2D2M: method, ts, eta, guidance, truncation), on one rigid skeleton
    (:meth:`Motion.on_rigid_skeleton`; the decoded spread of bone lengths is in ``quality``)."""
    prompts = [prompts] if isinstance(prompts, str) else list(prompts)
    seconds = [seconds] if isinstance(seconds, (int, float)) else seconds
    planner = PromptPlanner(generator)
    actions, frames = planner.plan(prompts, seconds, split)
    check_length(frames, generator.fps, max_seconds)
    notices = planner.notices(actions)

    def warn() -> None:
        """Say what the model does not know once sampling has begun: a request refused before
        that stays the one line of its error."""
        while notices:
            print(f"warning: {notices.pop(0)}", file=sys.stderr)

    try:
        settings = generator.options(**options)
        with _progress(f"sampling {len(actions)} action(s), {sum(frames) / generator.fps:.1f} s") as advance:
            motion = generator.generate(
                [actions], [frames], settings, [seed], progress=lambda done: (warn(), advance(done))
            )[0]
        warn()
        return motion.on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


def edit(
    generator: MotionGenerator,
    motion: Motion,
    keep: Sequence[tuple[float, float]],
    actions: Sequence[str] | None = None,
    seed: int = 0,
    **options: Any,
) -> Motion:
    """Regenerate ``motion`` except the time spans ``keep`` (seconds): keep the start and the end
    to in-between, the start alone to complete a prefix. ``actions`` may replace the texts of the
    motion's actions, one each; every action keeps its frames."""
    actions = list(motion.actions if actions is None else actions)
    if len(actions) != len(motion.actions):
        raise UserError(f"give one text per action of the motion ({len(motion.actions)})")
    starts = [first for first, _ in motion.ranges] + [len(motion.features)]
    frames = [end - start for start, end in zip(starts[:-1], starts[1:])]
    try:
        return generator.generate(
            [actions], [frames], generator.options(**options), [seed], [keep_spans(motion, keep)]
        )[0].on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


def edit_part(
    generator: MotionGenerator,
    features: np.ndarray,
    prompts: Sequence[str],
    part: str,
    seed: int = 0,
    split: bool = True,
    max_seconds: float | None = DEFAULT_MAX_SECONDS,
    **options: Any,
) -> Motion:
    """Keep body part ``part`` of ``features`` (F, D) on every frame and generate the rest of the
    body doing ``prompts`` (MMM's upper-body editing keeps ``lower``; docs/generation.md). The
    motion is cut to whole steps of the generator; its actions share its length in proportion to
    their typical lengths."""
    if generator.feature_dim != features.shape[-1]:
        raise UserError(f"the motion has {features.shape[-1]}-d features, the model {generator.feature_dim}-d ones")
    step = generator.frame_step
    features = features[: len(features) // step * step]
    if not len(features):
        raise UserError(f"the motion to edit is shorter than the model's step of {step} frames")
    actions, frames = PromptPlanner(generator).plan(prompts, [len(features) / generator.fps], split)
    check_length(frames, generator.fps, max_seconds)
    try:
        keep = keep_part(features, generator.skeleton, part)
        return generator.generate([actions], [frames], generator.options(**options), [seed], [keep])[
            0
        ].on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


def check_prompted(
    prompts: Sequence[str], seconds: Sequence[float] | None, source: str | None, keep_body: str | None
) -> None:
    """`generate`'s request from prompts, checked before a model loads: a new motion, or the
    ``source`` motion with its ``keep_body`` part kept, which is as long as the source."""
    if not prompts:
        raise UserError('give at least one prompt, e.g. m2d2m generate "a person walks forward" "a person jumps"')
    if keep_body is not None and source is None:
        raise UserError(
            "--keep-body PART goes with --edit SOURCE: the motion to edit and the body part of it "
            "to keep, e.g. --model mmm-body --edit motion.features.npy --keep-body lower"
        )
    if source is not None and seconds is not None:
        raise UserError("--seconds does not go with --keep-body: the edited motion is as long as the source")


def plan_parts(
    named: Sequence[tuple[str, str]], prompts: Sequence[str], seconds: Sequence[float] | None, editing: bool
) -> tuple[dict[str, str], float | None]:
    """`generate --part PART=TEXT`'s request, checked before a model loads: each body part's
    sentence (a part not ``named`` does the one prompt) and the one length in seconds (None: the
    corpus's typical). Body-part control generates the whole motion, so it edits none."""
    if editing:
        raise UserError("--part does not go with --edit: body-part control generates the whole motion")
    if len(prompts) > 1 or (seconds is not None and len(seconds) > 1):
        raise UserError("with --part give at most one prompt (for the parts not named) and one --seconds")
    parts = dict(named)
    if len(parts) != len(named):
        raise UserError("name each body part once with --part")
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        raise UserError(f"unknown body part {unknown[0]!r}: choose from {', '.join(PARTS)}")
    missing = [part for part in PARTS if part not in parts]
    if missing and not prompts:
        raise UserError(f"give a prompt for the parts not named ({', '.join(missing)}), or --part for each of them")
    parts.update({part: prompts[0] for part in missing})
    return parts, seconds[0] if seconds else None


def generate_parts(
    generator: MotionGenerator,
    parts: Mapping[str, str],
    seconds: float | None = None,
    seed: int = 0,
    max_seconds: float | None = DEFAULT_MAX_SECONDS,
    **options: Any,
) -> Motion:
    """One motion in which every body part does its own sentence (``parts``: part → sentence; the
    parts of :mod:`m2d2m.motion.body_parts`), ``seconds`` long or the corpus's median action, for
    a model with body-part control (MotionDiffuse's eq. 10; docs/generation.md)."""
    if not generator.part_control:
        able = [name for name, entry in models().items() if entry.load("generator").part_control]
        raise UserError(f"{generator.model} has no body-part control; use --model {' or '.join(able)}")
    if seconds is None:
        frames = generator.typical_frames(None)
    else:
        frames = action_frames(generator, seconds, "the body parts' motion")
    check_length([frames], generator.fps, max_seconds)
    try:
        settings = generator.options(**options)
        with _progress(f"sampling {len(parts)} body parts, {frames / generator.fps:.1f} s") as advance:
            motion = generator.generate_parts([dict(parts)], [frames], settings, [seed], progress=advance)[0]
        return motion.on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (``kill``, a scheduler) stops like Ctrl-C: temporary files are removed and the run
    is marked failed, where the default handler would end the process on the spot."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def save_generation(
    motion: Motion, output: Output, prompts: Sequence[str], dataset: str, track: bool = True
) -> tuple[dict[str, Path], str | None]:
    """Write ``motion``'s files (a progress bar on stderr while animations render) and, with
    ``track``, log them to MLflow; returns format → path and the MLflow run id.

    Without a ``directory`` the files go to a new run folder ``runs/<dataset>/generate/<id>/``
    whose ``run.json`` says ``running`` while they are written, then ``finished`` (with the
    files, the MLflow run id and the quality figures) or ``failed``, like a training run's. With
    a ``staging`` folder they are written (and logged) there; the paths returned are those they
    have in ``directory`` once :func:`staged` has moved them.
    """
    run_dir = output.directory is None
    directory = new_run_dir(dataset, GENERATE_STAGE) if run_dir else output.directory
    if run_dir:
        write_run_info(
            directory,
            stage=GENERATE_STAGE,
            dataset=dataset,
            status="running",
            prompts=list(prompts),
            actions=motion.actions,
            settings=motion.settings,
        )
    frames = len(motion.joints) * sum(FORMATS[kind].animation for kind in output.formats)
    try:
        with (
            _sigterm_as_interrupt(),
            progress(total=frames, unit="frame", desc="rendering", leave=False, disable=not frames) as bar,
        ):
            written = motion.save(
                output.staging or directory,
                output.name,
                output.formats,
                progress=lambda _: bar.update(),
                delivery=output.delivery,
            )
            run_id = _tracked(motion, prompts, written, dataset, directory) if track else None
    except BaseException as error:
        if run_dir:
            write_run_info(directory, status="failed", error=f"{type(error).__name__}: {error}")
        if isinstance(error, (ValueError, RuntimeError)):  # ffmpeg failed, or a file could not be written
            raise UserError(str(error)) from error
        raise
    files = {kind: directory / path.name for kind, path in written.items()}
    if run_dir:
        write_run_info(
            directory,
            status="finished",
            files={k: str(v) for k, v in files.items()},
            mlflow_run_id=run_id,
            quality=motion.quality,
        )
    return files, run_id


def _tracked(motion: Motion, prompts: Sequence[str], files: dict[str, Path], dataset: str, folder: Path) -> str | None:
    """:func:`log_generation`, or, when the tracking store cannot take it, one warning line naming
    the ``folder`` the files end in and None: the files are written already, and a dead server
    must neither hold them nor lose them."""
    problem = unreachable()
    if problem is None:
        try:
            return log_generation(motion, prompts, files, dataset)
        except Exception as error:  # MLflow's errors have no common base (HTTP, SQL, file store)
            problem = f"MLflow could not record it ({type(error).__name__}: {str(error).splitlines()[0][:200]})"
    print(f"warning: {problem}; the generation is not tracked, its files are in {folder}", file=sys.stderr)
    return None


def log_generation(motion: Motion, prompts: Sequence[str], files: dict[str, Path], dataset: str) -> str:
    """Record one generation in MLflow (experiment ``<dataset>/generate``): prompts, actions,
    settings as params, the quality figures as metrics, each file once as an artifact; returns
    the MLflow run id."""
    params = {
        **{k: str(v) for k, v in motion.settings.items()},
        "prompts": " | ".join(prompts)[:500],
        "actions": " | ".join(motion.actions)[:500],
        "seconds": f"{motion.seconds:.2f}",
    }
    tags = {
        "dataset": dataset,
        "stage": GENERATE_STAGE,
        "model": str(motion.settings.get("model")),
        "method": str(motion.settings.get("method")),
    }
    if "edit_parent_run" in motion.settings:  # an edit of a served generation: nested under it in the MLflow UI
        tags["mlflow.parentRunId"] = str(motion.settings["edit_parent_run"])
    with tracked_run(experiment_name(dataset, GENERATE_STAGE), tags=tags, params=params) as (client, run_id):
        for name, value in motion.quality.items():
            client.log_metric(run_id, name, value)
        for kind, path in files.items():  # each file with those its format wrote beside it (the npy's sidecar, ...)
            stem = path.name.removesuffix(f".{kind}")
            for name in FORMATS[kind].file_names(stem):
                if (path.parent / name).is_file():
                    client.log_artifact(run_id, str(path.parent / name), artifact_path="motion")
    return run_id
