"""Where a generation's files go, checked before anything is loaded or sampled.

:func:`plan_output` reads ``--out``, ``--name`` and ``--formats`` (a folder, one file whose suffix
is its format, or a new run folder) and refuses a target that holds an earlier result
(:func:`check_free`) unless asked to replace it; :func:`variations` gives each seed of
``--variations`` its own name; :func:`staged` writes one command's files into a temporary folder
moved into place when the command ends, all or nothing.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

from m2d2m.atomic import atomic_files, atomic_folder
from m2d2m.motion.files.formats import DEFAULT_FORMATS, FORMATS, formats_named, on_rig, spoken, suffixes
from m2d2m.motion.transforms.delivery import Delivery
from orchestration.errors import UserError

# a suffix that names a kind of file (.fbx, .glb, .json), not a folder name like "v1.2": --out with
# one that is not a format is refused rather than made into a folder of that name
FILE_SUFFIX = re.compile(r"\.[A-Za-z][A-Za-z0-9]{0,4}")


@dataclass(frozen=True)
class Output:
    """Where a generation's files go: ``directory`` (None: a new run folder, made when the motion
    is ready), the file stem ``name``, the ``formats``, and how the clip is delivered (its feet,
    frame rate, loop, root motion, bind pose and rig: :class:`~m2d2m.motion.transforms.delivery.Delivery`).
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
