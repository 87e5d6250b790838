"""The ``m2d2m`` command line: one sub-command per stage of the flow.

Every user error (bad path, bad value, missing file) ends in one line on stderr and exit
status 2; anything else is a bug and keeps its traceback. Each verb is an ``_add_<verb>``
function that declares its options beside a handler that parses nothing and decides nothing:
the work is in the modules the handler calls. The training verbs of the generators' models come
from the model registry, so a new model brings its own verb.
"""

from __future__ import annotations

import argparse
import errno
import gc
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any, NoReturn, get_args, get_origin, get_type_hints

from m2d2m.motion.formats import DEFAULT_FORMATS, FORMATS, animations, exported, on_rig, spoken, suffixes
from orchestration.errors import NotInProject, UserError
from orchestration.project import is_project, outside_project, require_project
from orchestration.registry import DEFAULT_MODEL, methods_of_models, models


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad command line as one line, like every other user error,
    instead of a usage block: the usage is one ``--help`` away."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, 0 or more, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer, 0 or more, got {text}")
    return value


def _pose_reference(value: str) -> tuple[str, int]:
    """POSE@FRAME: a result's .npy and one of its frames (at the model's rate)."""
    path, at, frame = value.rpartition("@")
    if not at or not path or not frame.isdigit():
        raise argparse.ArgumentTypeError(f"expected POSE@FRAME (a .npy and a frame number), got {value!r}")
    return path, int(frame)


def _span(value: str) -> tuple[float, float]:
    """START:END seconds, START before END."""
    start, colon, end = value.partition(":")
    try:
        span = float(start), float(end)
    except ValueError:
        span = None
    if not colon or span is None or not 0 <= span[0] < span[1]:
        raise argparse.ArgumentTypeError(f"expected START:END in seconds, START before END, got {value!r}")
    return span


def _positive_float(text: str) -> float:
    """A finite number above zero (frames per second: 0 divides by zero, -1 writes a BVH
    whose frame time is negative)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _port(text: str) -> int:
    """A TCP port number, 1 to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number from 1 to 65535, got {text}")
    return value


def _option(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of a sampling option, the value read as YAML (numbers, null, lists)."""
    from orchestration.config import parse_override

    path, value = parse_override(text)
    return ".".join(path), value


def _body_part(text: str) -> tuple[str, str]:
    """``PART=TEXT`` of ``generate --part``."""
    part, separator, sentence = text.partition("=")
    if not separator or not part.strip() or not sentence.strip():
        raise argparse.ArgumentTypeError(f'expected PART=TEXT, e.g. upper="a person waves", got {text!r}')
    return part.strip(), sentence.strip()


# ------------------------------------------------------------------------------------ handlers
def _synthesize(args: argparse.Namespace) -> None:
    from orchestration.data import synthesize

    families = args.families.split(",") if args.families else None
    print(synthesize(args.out, args.clips, args.seed, families, args.workers, args.force))


def _report_problems(directory: Path, problems: list[str], what: str) -> None:
    for problem in problems:
        print(problem)
    if problems:
        raise UserError(f"{directory}: {len(problems)} problem(s) against its manifest")
    print(f"{directory}: OK ({what} match the manifest)")


def _data(args: argparse.Namespace) -> None:
    from orchestration.data import LAYOUT_OPTIONS, build, data_config
    from pipelines.dataset import check_dataset
    from pipelines.features import print_summary

    if args.check:
        _report_problems(Path(args.check), check_dataset(Path(args.check)), "counts, checksums and schema")
        return
    config = data_config(
        args.dataset,
        args.raw,
        args.out,
        args.workers,
        {name: getattr(args, name) for name in LAYOUT_OPTIONS},
        samples_per_shard=args.samples_per_shard,
        min_frames=args.min_frames,
        max_frames=args.max_frames,
        ray_address=args.ray_address,
    )
    manifest, built = build(config, args.force, args.replace)
    if not built:
        print(f"{config.out}: already built from {config.raw} with this config; reusing it (--force rebuilds)")
        print_summary(manifest, config.out)
        return
    print_summary(manifest, config.out)
    print(
        f"wrote {config.out} ({sum(len(v) for v in manifest['shards'].values())} shards); "
        f"verify with: m2d2m data --check {config.out}"
    )


def _train(args: argparse.Namespace) -> None:
    """Every training verb: ``args.trains`` is a registered model's name, ``vq`` or ``evaluator``."""
    from orchestration.recipe import Trainable, train
    from orchestration.registry import model
    from orchestration.runs import EVALUATOR_STAGE, VQ_STAGE

    if args.trains == VQ_STAGE:
        from orchestration.recipes.vq import VQ_TRAINING as trainable
    elif args.trains == EVALUATOR_STAGE:
        from orchestration.recipes.evaluator import EVALUATOR_TRAINING as trainable
    else:
        trainable = Trainable.of_model(model(args.trains))
    run_dir = train(trainable, args.config, args.set, args.resume)
    print(f"finished {run_dir}; model file {run_dir / trainable.model_file}; its metrics and previews: `make ui`")


def _tokenize(args: argparse.Namespace) -> None:
    from orchestration.runs import vq_file
    from pipelines.token_sets import token_set
    from pipelines.tokenize import check_tokens, current_tokens, tokenize_dataset

    if args.check:
        _report_problems(Path(args.check), check_tokens(args.check), "counts, checksums, schema and codebook")
        return
    vq_path = vq_file(args.vq or "latest", args.dataset)
    try:
        data_dir, out = token_set(vq_path, args.data)
        if current_tokens(data_dir, vq_path, out) is not None:
            print(f"{out}: tokens of this dataset with this VQ-VAE are already there; reusing them")
        manifest = tokenize_dataset(data_dir, vq_path, out, workers=args.workers, ray_address=args.ray_address)
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    counts = ", ".join(f"{split} {c['samples']}" for split, c in manifest["splits"].items())
    print(f"tokens of {data_dir} with {vq_path}: {out} ({counts} sequences)")


def _render(args: argparse.Namespace) -> None:
    from m2d2m.motion.render import render_motion
    from orchestration.viewing import load_motion

    out = Path(args.out)
    if out.suffix.lower().lstrip(".") not in {fmt.suffix for fmt in animations()}:
        raise UserError(
            f"{out}: the animation format comes from the suffix; use {spoken(f'.{fmt.suffix}' for fmt in animations())}"
        )
    if out.exists() and not args.overwrite:
        raise UserError(f"{out} exists; give another name, or --overwrite to replace it")
    motion = load_motion(args.source, args.id, args.skeleton)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        render_motion(
            motion.joints,
            out,
            skeleton=motion.skeleton,
            fps=args.fps or motion.fps,
            segments=motion.segments or None,
            title=motion.caption,
        )
    except RuntimeError as error:  # no MP4 encoder on this machine, or the encoder failed
        raise UserError(str(error)) from error
    print(f"wrote {out}")


def _export(args: argparse.Namespace) -> None:
    import numpy as np

    from m2d2m.motion.clip import Motion
    from orchestration.generate import plan_output, staged
    from orchestration.viewing import load_motion

    out = Path(args.out)
    if out.suffix.lower().lstrip(".") not in {fmt.suffix for fmt in exported()}:
        raise UserError(f"{out}: export writes {suffixes(exported())} (the suffix is the format)")
    output = plan_output(out, "motion", None, _delivery(args), args.overwrite)
    shown = load_motion(args.source, args.id, args.skeleton)
    fps, said = _source_rate(args.source_fps, shown)
    print(f"{args.source}: read at {fps:g} fps ({said})")
    # a recording without text has no actions: not one nameless span (Motion.segments would call it a transition)
    segments = shown.segments or ([(0, len(shown.joints), shown.caption)] if shown.caption else [])
    motion = _delivered(
        Motion(
            np.zeros((len(shown.joints), 0), np.float32),  # no features: contacts come from the joints
            shown.joints,
            fps,
            shown.skeleton.name,
            [text for _, _, text in segments],
            [(first, end) for first, end, _ in segments],
            loop=shown.loop,  # a loop's files close it again (its GLB's closing key)
        ),
        output.delivery,
        recorded=True,  # a file's motion: its feet are fixed only on --foot-fix
    )
    try:
        with staged([(0, output)]) as [(_, output)]:
            motion.save(output.staging, output.name, output.formats, delivery=output.delivery)
    except (OSError, RuntimeError, ValueError) as error:  # Blender failed, or a rig it cannot read
        raise UserError(str(error)) from error
    print(f"wrote {out}")
    _delivery_notes({output.formats[0]: out}, motion, output.delivery)


def _source_rate(given: float | None, shown: Any) -> tuple[float, str]:
    """The rate a motion to export was made at, and where it comes from: ``--source-fps``, else
    its sidecar's, else its skeleton's (assumed, and said, so a clip is never played at a rate
    no one chose without a word)."""
    if given:
        return given, "--source-fps"
    if shown.fps:
        return shown.fps, "its sidecar's"
    return shown.skeleton.fps, f"the {shown.skeleton.name} skeleton's; --source-fps for another"


def _rig(args: argparse.Namespace) -> None:
    from m2d2m.motion.bvh_reader import BvhError
    from m2d2m.motion.joint_map import rig_mapping
    from m2d2m.motion.retarget import read_rig, target_of

    rig = Path(args.file)
    if not rig.is_file():
        raise UserError(f"{rig}: no such file (a BVH, or a GLB or glTF character with a skin)")
    try:
        clip = read_rig(rig)
        mapping = rig_mapping(clip, args.joint_map)
    except (BvhError, ValueError) as error:  # a file that is no rig, a YAML that is no map
        raise UserError(str(error)) from error
    print(f"{rig}: {len(clip.names)} joints; joint map {mapping.name}")
    print("\n".join(mapping.lines()))
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(mapping.yaml(rig.name), encoding="utf-8")
        print(f"wrote {out}: correct it and give it back with --joint-map {out}")
    try:
        target = target_of(clip, mapping.joint_map(), rest_frame=args.rest_frame)
    except (BvhError, ValueError) as error:  # joints not found, or a rig our motion cannot go onto
        print("can receive motion: no")
        raise UserError(str(error)) from error
    bind = target.bind
    posed = "its rest pose" if bind.frame is None else f"frame {bind.frame} of its file"
    turned = ", turned to stand Y-up (written back in its own axes)" if bind.turned else ""
    print(f"can receive motion: yes ({target.metres_per_unit:g} m a unit; aimed from {posed}{turned})")


def _delivery(args: argparse.Namespace) -> Any:
    """The delivery the command line asks for (``--fps``, ``--root``, ``--loop``, ``--foot-fix``
    or ``--no-foot-fix``, ``--rest``, ``--rig``, ``--joint-map``), checked in one line before anything runs."""
    from m2d2m.motion.delivery import Delivery

    try:
        return Delivery(
            fps=args.fps,
            root=args.root,
            loop=args.loop,
            plant_feet=args.foot_fix,  # None: Delivery.plants_feet's rule for what is delivered
            rest_pose=args.rest,
            rig=None if args.rig is None else str(Path(args.rig).resolve()),
            joint_map=args.joint_map,
            rest_frame=args.rest_frame,
        )
    except ValueError as error:
        raise UserError(str(error)) from error


def _delivered(motion: Any, delivery: Any, recorded: bool = False) -> Any:
    """``motion`` delivered as asked (``recorded``: a file's motion, not a generation); a clip the
    delivery cannot take (a loop of a clip shorter than its cross-fade) is one line."""
    try:
        return motion.delivered(delivery, recorded)
    except ValueError as error:
        raise UserError(str(error)) from error


def _delivery_notes(files: dict[str, Path], motion: Any, delivery: Any) -> None:
    """What an animator must know of the files written: a BVH's rate and bind pose, an in-place
    clip's root track (where the files keep it), a loop's travel."""
    if "bvh" in files:
        print(bvh_note(files["bvh"], motion.fps, delivery.rest_pose, delivery.rig))
    if motion.root_track is not None:
        written = [FORMATS[kind] for kind in files]
        # a file on a rig has no such track: its root is the rig's own
        kept = [fmt.root_motion for fmt in written if fmt.root_motion and not (fmt.on_rig and delivery.rig)]
        lacking = spoken([fmt for fmt in FORMATS.values() if not fmt.root_motion], "and")
        where = f"kept in {' and '.join(kept)}" if kept else f"not kept: {lacking} have no place for it"
        print(f"root motion: taken out of the clip (in place); {where}")
    if motion.loop:
        print(f"loop: one cycle of {motion.seconds:.2f} s, travelling {motion.quality['loop_travel_m']:.2f} m a cycle")


def bvh_note(path: Path, fps: float, rest_pose: str, rig: str | None = None) -> str:
    """What an animator must know to import a BVH: its rate (Blender keeps its scene's 24 fps
    unless told) and its bind pose."""
    if rig is not None:
        rest = f"the rig's own ({Path(rig).name})"
    else:
        rest = "a T-pose" if rest_pose == "tpose" else "HumanML3D's (arms down; --rest tpose for a T-pose)"
    return (
        f"{path.name}: {fps:g} fps (Frame Time {1 / fps:.4f} s; in Blender's BVH import tick "
        f"'Update Scene FPS' or it plays at the scene's rate), rest pose {rest}"
    )


def _sampling_options(args: argparse.Namespace) -> dict[str, Any]:
    """The sampling knobs given on the command line: every ``--option`` and the shortcuts."""
    options = dict(args.option or [])
    for name in args.shortcuts:
        if getattr(args, _SHORTCUT + name) is not None:
            options[name] = getattr(args, _SHORTCUT + name)
    return options


def _generate(args: argparse.Namespace) -> None:
    from orchestration.generate import check_prompted, edit_part, generate, length_cap, load_generator, staged
    from orchestration.viewing import load_features

    timeline_flags = _edit_flags(args)
    if timeline_flags and (args.edit is None or args.keep_body is not None or args.part):
        raise UserError(
            f"{timeline_flags[0]} edits a result on its timeline: it goes with --edit SOURCE, "
            "not with --keep-body or --part"
        )
    if args.part:
        return _generate_parts(args)
    if args.edit is not None and args.keep_body is None:
        return _edit_timeline(args)
    check_prompted(args.prompts, args.seconds, args.edit, args.keep_body)
    planned = _planned_outputs(args)
    generator = load_generator(args.model, args.checkpoint, args.dataset)
    options = _sampling_options(args)
    if args.method is not None:
        options["method"] = args.method
    with staged(planned) as planned:
        for seed, variation in planned:
            if args.edit is not None:
                motion = edit_part(
                    generator,
                    load_features(args.edit, generator.skeleton),
                    args.prompts,
                    args.keep_body,
                    seed=seed,
                    split=not args.no_split,
                    max_seconds=length_cap(args.max_seconds),
                    **options,
                )
            else:
                motion = generate(
                    generator,
                    args.prompts,
                    seconds=args.seconds,
                    seed=seed,
                    split=not args.no_split,
                    max_seconds=length_cap(args.max_seconds),
                    **options,
                )
            _report(motion, variation, args.prompts, args)


def _edit_timeline(args: argparse.Namespace) -> None:
    """``generate --edit SOURCE`` with a timeline operation (orchestration/edit_operations.py)."""
    from m2d2m.layout import relative_to_project
    from orchestration.edit_operations import plan_edit
    from orchestration.editing import read_result, sample_edit
    from orchestration.generate import check_length, length_cap, load_generator, staged

    chosen = _chosen_operation(args)
    planned = _planned_outputs(args)
    generator = load_generator(args.model, args.checkpoint, args.dataset)
    operation = _edit_operation(args, chosen, lambda path: read_result(path, generator))
    edit, said = plan_edit(generator, read_result(args.edit, generator), operation)
    check_length(edit.frames, generator.fps, length_cap(args.max_seconds))  # the cap of a new generation
    print(f"{args.edit}: {said}")
    options = _sampling_options(args)
    if args.method is not None:
        options["method"] = args.method
    with staged(planned) as planned:
        for seed, variation in planned:
            motion = sample_edit(generator, edit, seed, f"{relative_to_project(args.edit)}: {said}", **options)
            _report(motion, variation, edit.result_actions, args)
            if "pin_error_m" in motion.quality:
                print(f"  the pose is met within {motion.quality['pin_error_m'] * 1000:.0f} mm (its farthest joint)")


# `generate --edit`'s timeline operations by flag (each its dest), and the flags that serve one of them
_OPERATION_FLAGS = {
    "--regenerate": "regenerate",
    "--fill-to": "fill_to",
    "--pin": "pin",
    "--continue": "extend",
    "--layer": "layer",
}
_SERVING_FLAGS = {"--at": ("at", "--pin"), "--span": ("span", "--layer")}


def _edit_flags(args: argparse.Namespace) -> list[str]:
    """The timeline operations' flags given, in the order of the help."""
    dests = {**_OPERATION_FLAGS, **{flag: dest for flag, (dest, _) in _SERVING_FLAGS.items()}}
    given = {flag: getattr(args, dest) for flag, dest in dests.items()}
    return [flag for flag, value in given.items() if value is not None and value is not False]


def _chosen_operation(args: argparse.Namespace) -> str:
    """The flag of the one timeline operation `generate --edit` asks for, checked before a model
    loads: none or two, or a flag that serves another operation, is one line."""
    chosen = [flag for flag in _edit_flags(args) if flag in _OPERATION_FLAGS]
    if len(chosen) != 1:
        raise UserError(
            "an edit is one of: regenerate an action, fill to a second result, pin a pose, continue, "
            "lay a body part's action over a span (one at a time)"
        )
    for flag, (dest, owner) in _SERVING_FLAGS.items():
        if getattr(args, dest) is not None and chosen[0] != owner:
            raise UserError(f"{flag} goes with {owner}, not with {chosen[0]}")
    return chosen[0]


def _edit_operation(args: argparse.Namespace, chosen: str, read: Callable[[str], Any]) -> Any:
    """The operation of flag ``chosen`` (orchestration/edit_operations.py) from its flags, the
    prompts and ``--seconds`` (``read``: a result's file as a timeline): a text or length it does
    not take is one line."""
    from orchestration.edit_operations import Continue, Fill, Layer, Pin, Regenerate
    from orchestration.editing import pose_at

    texts, seconds = list(args.prompts), list(args.seconds or [])
    text, length, one_each = (texts or [None])[0], (seconds or [None])[0], len(texts) <= 1 and len(seconds) <= 1
    if chosen == "--regenerate":
        if not one_each:
            raise UserError("regenerating takes at most one text (the action's new one) and one length")
        return Regenerate(args.regenerate, text, length)
    if chosen == "--fill-to":
        if not one_each:
            raise UserError("filling takes at most one text (what happens in the gap) and one length (the gap's)")
        return Fill(read(args.fill_to), 1.0 if length is None else length, text or "")
    if chosen == "--pin":
        if args.at is None or texts or seconds:
            raise UserError("pinning a pose takes the time to pin it at (--at; the API's at) and no text or length")
        source, frame = args.pin
        return Pin(pose_at(read(source), frame, f"--pin: {source}"), args.at)
    if chosen == "--layer":
        if args.span is None or texts or seconds:
            raise UserError("laying a body part's action takes the span it lasts (--span; the API's span) alone")
        return Layer(*args.layer, args.span)
    lengths = seconds * len(texts) if len(seconds) == 1 else seconds or [None] * len(texts)
    return Continue(tuple(texts), tuple(lengths))


def _planned_output(args: argparse.Namespace) -> Any:
    """Where a generation's files go, checked before the model loads: ``--out``, and without it
    the project's generate runs' folder, made now (a file in its way is one line, not a lost
    sampling; outside a project nothing is made before the verb says where it runs)."""
    from orchestration.generate import GENERATE_STAGE, plan_output
    from orchestration.runs import ensure_stage_dir

    output = plan_output(args.out, args.name, args.formats, _delivery(args), args.overwrite)
    if output.directory is None and is_project(Path.cwd()):
        ensure_stage_dir(args.dataset, GENERATE_STAGE)
    return output


def _planned_outputs(args: argparse.Namespace) -> Any:
    """The seeds of ``--variations`` and where each one's files go, all checked before the model loads."""
    from orchestration.generate import variations

    return variations(_planned_output(args), args.seed, args.variations)


def _generate_parts(args: argparse.Namespace) -> None:
    """``generate --part PART=TEXT``: one sentence per body part; a prompt, if given, drives the parts
    not named."""
    from orchestration.generate import generate_parts, length_cap, load_generator, plan_parts, staged

    parts, seconds = plan_parts(args.part, args.prompts, args.seconds, editing=args.edit is not None)
    output = _planned_output(args)
    generator = load_generator(args.model, args.checkpoint, args.dataset)
    options = _sampling_options(args)
    motion = generate_parts(
        generator, parts, seconds=seconds, seed=args.seed, max_seconds=length_cap(args.max_seconds), **options
    )
    with staged([(args.seed, output)]) as [(_, output)]:
        _report(motion, output, [f"{part}: {text}" for part, text in parts.items()], args)


def _add_max_seconds(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--max-seconds", type=float, help=f"refuse, before sampling, {what} (default 60; 0 = no cap)")


def _report(motion: Any, output: Any, prompts: list[str], args: argparse.Namespace) -> None:
    """Deliver a generation as asked, save its files, log it, and say what was made."""
    from orchestration.generate import GENERATE_STAGE, save_generation

    motion = _delivered(motion, output.delivery)
    files, run_id = save_generation(motion, output, prompts, args.dataset, track=not args.no_track)
    for text, (first, end) in zip(motion.actions, motion.ranges):
        print(f"  {first / motion.fps:5.1f}–{end / motion.fps:5.1f} s  {text}")
    print(
        f"wrote {', '.join(str(path) for path in files.values())} ({motion.seconds:.1f} s, "
        f"{motion.settings['method']}; bone-length spread {motion.quality['bone_length_std_mm_mean']:.1f} mm "
        "before the rigid skeleton)"
    )
    _delivery_notes(files, motion, output.delivery)
    if run_id is not None:
        print(f"logged to MLflow run {run_id} (experiment {args.dataset}/{GENERATE_STAGE}); `make ui` to browse")


def _testset(args: argparse.Namespace) -> None:
    from orchestration.evaluate.testsets import TESTSET_STAGE, make_testset
    from pipelines.testset import describe

    summary = make_testset(args.data, args.dataset, args.n, args.seed, args.mirrors, args.force, args.first, args.split)
    print(describe(summary))
    print(f"logged to MLflow run {summary['mlflow_run_id']} (experiment {args.dataset}/{TESTSET_STAGE})")


def _evaluate(args: argparse.Namespace) -> None:
    from orchestration.evaluate.run import evaluate
    from orchestration.evaluate.settings import EVAL_STAGE, settings_to_run
    from orchestration.reports import TABLE_MD

    run_dir, settings = settings_to_run(args.dataset, _given_request(args), args.resume)
    run_dir, _ = evaluate(settings, args.dataset, run_dir, args.batch_size)
    print((run_dir / TABLE_MD).read_text(encoding="utf-8"))
    print(
        f"wrote {run_dir} (table.md, table.json, fig5.png, results/); logged to MLflow "
        f"(experiment {args.dataset}/{EVAL_STAGE}); `make ui` to browse"
    )


def _sweep(args: argparse.Namespace) -> None:
    from orchestration.sweep import SUMMARY_MD, sweep

    sweep_dir = sweep(args.config, args.set, args.ray_address, args.name, args.restart)
    print((sweep_dir / SUMMARY_MD).read_text(encoding="utf-8"))
    print(f"sweep {sweep_dir}: its trials are child runs of one MLflow parent run; compare them with `make ui`")


def _models(args: argparse.Namespace) -> None:
    from orchestration.model_summary import summary_lines

    print("\n".join(summary_lines(args.dataset)))


def _ui(args: argparse.Namespace) -> None:
    import os

    from orchestration.serving import check_port_free, serve
    from orchestration.tracking import tracking_uri, ui_command, ui_runs_page

    if os.environ.get("MLFLOW_TRACKING_URI", "").startswith("http"):
        print(f"the runs are on the tracking server: open {ui_runs_page(os.environ['MLFLOW_TRACKING_URI'])}")
        return
    require_project()  # elsewhere it would open, and so create, an empty store
    check_port_free(args.host, args.port)
    page = ui_runs_page(f"http://{args.host}:{args.port}")
    print(f"MLflow UI on {tracking_uri()}: {page}  (Ctrl-C stops it)", flush=True)
    status = serve(ui_command(args.host, args.port))
    if status:
        raise UserError(f"the MLflow UI stopped with status {status}; its messages are above")
    print("stopped the MLflow UI and everything it started")


def _serve(args: argparse.Namespace) -> None:
    from orchestration.generate import length_cap
    from orchestration.model_summary import also_trained
    from orchestration.serving import check_port_free
    from orchestration.web.app import ServeSettings
    from orchestration.web.server import serve, server_token

    require_project()  # elsewhere it would serve no model
    token = server_token(args.host, args.token)
    check_port_free(args.host, args.port)
    settings = ServeSettings(
        dataset=args.dataset,
        token=token,
        max_seconds=length_cap(args.max_seconds),
        queue=args.queue,
        max_batch=args.max_batch,
        device=args.device,
        track=not args.no_track,
        mlflow_ui=args.mlflow_ui,
        max_rig_bytes=args.max_rig_mb << 20,
    )
    host = f"[{args.host}]" if ":" in args.host else args.host
    print(
        f"m2d2m on http://{host}:{args.port}/ (the API's documentation: /docs); Ctrl-C or SIGTERM stops it",
        flush=True,
    )
    others = also_trained(args.dataset)
    if others:
        print(others, flush=True)
    serve(settings, args.host, args.port)
    print("stopped: the requests in flight were answered")


# ------------------------------------------------------------------------------------- parsers
def _add_synthesize(verbs) -> None:
    synth = verbs.add_parser("synthesize", help="generate the embedded synthetic motion-language corpus")
    synth.add_argument("--out", default="data/raw/synthetic", help="corpus directory (HumanML3D raw layout)")
    synth.add_argument("--clips", type=_positive_int, default=2000)
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--families", help="comma-separated action families (default: all)")
    synth.add_argument("--workers", type=_positive_int, default=2, help="processes to generate with")
    synth.add_argument("--force", action="store_true", help="rebuild even if the corpus exists")
    synth.set_defaults(run=_synthesize)


def _add_ray_address(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ray-address", help="join a Ray cluster (default: a local Ray; also RAY_ADDRESS)")


def _add_data(verbs) -> None:
    data = verbs.add_parser("data", help="preprocess a corpus into WebDataset shards with Ray Data")
    data.add_argument(
        "--dataset", default="synthetic", help="synthetic, humanml3d, kit, or a corpus a plugin registers"
    )
    data.add_argument("--raw", help="raw corpus directory (default data/raw/<dataset>)")
    data.add_argument("--out", help="output directory (default data/<dataset>)")
    data.add_argument("--workers", type=_positive_int, default=2, help="Ray tasks in parallel")
    _add_ray_address(data)
    data.add_argument("--samples-per-shard", type=_positive_int, default=500)
    data.add_argument("--min-frames", type=_positive_int, help="keep clips with at least this many feature frames")
    data.add_argument("--max-frames", type=_positive_int, help="keep clips with fewer feature frames than this")
    data.add_argument("--force", action="store_true", help="rebuild even if an identical dataset exists")
    data.add_argument(
        "--replace", action="store_true", help="replace an --out built from another raw corpus (or holding no dataset)"
    )
    data.add_argument("--check", metavar="DIR", help="verify a processed dataset against its manifest and exit")
    mocap = data.add_argument_group(
        "motion capture (the bvh, humanml3d-public, bandai-namco and cmu-kitml corpora; docs/data.md)"
    )
    mocap.add_argument("--bvh", metavar="DIR", help="humanml3d-public: a folder of CMU's BVH files")
    mocap.add_argument(
        "--joint-map",
        metavar="MAP",
        help="a preset (cmu, cmu-motionbuilder, bandai-namco…), auto, or a YAML of our joint → yours, all or some "
        "(default: the preset the file's joints fit, else auto; `m2d2m rig FILE` shows what it finds)",
    )
    mocap.add_argument(
        "--units",
        help="bvh: m, cm, mm, inch, cmu or metres per unit (default: the unit the rig stands a person's height in)",
    )
    mocap.add_argument("--subset", help="bandai-namco: dataset-1, dataset-2 or both (default both)")
    mocap.add_argument("--annotations", metavar="FILE", help="cmu-kitml: KIT-ML's annotations.json (Mathux/TMR)")
    data.set_defaults(run=_data)


def _add_training_verb(
    verbs, name: str, configs: str, description: str, example: str, trains: str | None = None
) -> None:
    """The options every training stage takes: a config, overrides, and resuming; ``trains``: the
    registered model it trains (else the stage of its ``configs``, ``vq`` or ``evaluator``)."""
    parser = verbs.add_parser(name, help=description)
    parser.add_argument("--config", default="demo", help=f"configs/{configs}/<name>.yaml or a path (default demo)")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=f"override a config value, e.g. --set {example} (repeatable)",
    )
    parser.add_argument(
        "--resume",
        nargs="?",
        const=True,
        default=False,
        metavar="RUN",
        help="continue the newest unfinished run of this config's dataset, or RUN (its directory, "
        "name or MLflow run id)",
    )
    parser.set_defaults(run=_train, trains=trains or configs)


def _add_training_verbs(verbs) -> None:
    _add_training_verb(
        verbs, "train-vq", "vq", "train the motion VQ-VAE (Lightning, tracked in MLflow)", "optim.lr=1e-4"
    )
    for entry in models().values():
        _add_training_verb(
            verbs, entry.train_verb, entry.configs, f"train {entry.summary}", "optim.lr=1e-4", trains=entry.name
        )
    _add_training_verb(
        verbs,
        "train-evaluator",
        "evaluator",
        "train the text-motion evaluator of Guo et al. for the paper's metrics",
        "optim.lr=1e-4",
    )


def _add_tokenize(verbs) -> None:
    tokenize = verbs.add_parser("tokenize", help="encode every motion into VQ tokens (Ray Data)")
    tokenize.add_argument(
        "--vq", help="vq.pt, a checkpoint, a run directory or name, or an MLflow run id (default: latest)"
    )
    tokenize.add_argument("--dataset", default="synthetic", help="whose latest VQ run to use by default")
    tokenize.add_argument("--data", help="processed dataset directory (default: the one the VQ-VAE was trained on)")
    tokenize.add_argument("--workers", type=_positive_int, default=2)
    _add_ray_address(tokenize)
    tokenize.add_argument("--check", metavar="DIR", help="verify a token set against its manifest and exit")
    tokenize.set_defaults(run=_tokenize)


def _add_model_choice(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model", default=DEFAULT_MODEL, help=f"a registered model: {', '.join(models())} (default {DEFAULT_MODEL})"
    )
    parser.add_argument(
        "--checkpoint",
        default="latest",
        help="the model's file, a run directory or name, or an MLflow run id (default: latest)",
    )


_SHORTCUT = "knob_"  # a shortcut's attribute: --eta is args.knob_eta, clear of every other option
_KINDS = {"int": int, "float": float, "str": str}


def _escaped(text: str) -> str:
    return text.replace("%", "%%")  # argparse %-formats help texts


def _knob_line(knob: Any, preset: Any) -> str:
    """One knob of the sampling help: its name, kind, bounds, the multi-action preset's value and what it does."""
    bounds = f", {knob.bounds}" if knob.bounds else ""
    value = getattr(preset, knob.name)
    return f"    {knob.name} ({knob.kind}{bounds}; preset {'none' if value is None else value}): {knob.help}"


def sampling_help() -> str:
    """Every model's methods and knobs, as the models declare them (m2d2m.generators.options):
    the closing section of ``generate --help`` and ``evaluate --help``."""
    from m2d2m.generators.options import MULTI

    lines = [
        "sampling options by model (--option KEY=VALUE). An unset one keeps the model's default: the",
        "multi-action preset shown here (the paper's), unless the model file chose its own (M2D2M: its",
        "config's sampling section); `m2d2m models` shows each trained model's own defaults.",
    ]
    for entry in models().values():
        sampling = entry.load("sampling")
        preset = sampling.presets[MULTI]
        lines.append(f"  {entry.name}: methods {', '.join(sampling.methods)} (default {preset.method})")
        lines += [_knob_line(knob, preset) for knob in sampling.knobs()]
    return "\n".join(lines)


def _add_sampling_knobs(parser: argparse.ArgumentParser) -> None:
    """``--option KEY=VALUE`` for any model's knob, and the flags the models' entries declare as
    shortcuts (M2D2M's ``--ts``, ``--eta``, ``--guidance``, ``--truncation``), each typed and
    explained as its knob declares it."""
    parser.add_argument(
        "--option",
        type=_option,
        action="append",
        metavar="KEY=VALUE",
        help="any sampling option of the model, e.g. --option steps=25 (repeatable; listed below)",
    )
    owners: dict[str, list[tuple[str, Any]]] = {}
    for name, entry in models().items():
        sampling = entry.load("sampling")
        for knob in entry.shortcuts:
            owners.setdefault(knob, []).append((name, sampling.knob(knob)))
    for name, declared in owners.items():
        explained = "; ".join(f"{model}: {knob.help}" for model, knob in declared)
        kind = declared[0][1].kind
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            dest=_SHORTCUT + name,
            type=_KINDS[kind],
            metavar=kind.upper(),
            help=_escaped(f"{explained}; short for --option {name}=…"),
        )
    parser.set_defaults(shortcuts=tuple(owners))


def _add_generate(verbs) -> None:
    generate = verbs.add_parser(
        "generate",
        help="text to motion: one sequence doing the prompts in order",
        epilog=sampling_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    generate.add_argument(
        "prompts", nargs="*", help='one or more prompts, e.g. "a person walks forward" "a person jumps"'
    )
    generate.add_argument(
        "--seconds",
        type=float,
        nargs="+",
        help="duration of each prompt, or one for all (default: the corpus's typical length per verb)",
    )
    generate.add_argument(
        "--method", help=f"the multi-action method ({methods_of_models()}; default: the model's first)"
    )
    _add_sampling_knobs(generate)
    generate.add_argument("--seed", type=int, default=0)
    _add_model_choice(generate)
    generate.add_argument("--dataset", default="synthetic", help="whose runs to look in (default synthetic)")
    generate.add_argument(
        "--out",
        help=f"a folder, or one file whose suffix ({suffixes(FORMATS.values())}) is its format "
        "(default: the folder runs/<dataset>/generate/<new run>)",
    )
    generate.add_argument("--name", default="motion", help="file name stem in the --out folder (default motion)")
    _add_overwrite(generate, "--out's folder (every file in it) or file")
    generate.add_argument(
        "--formats",
        nargs="+",
        metavar="FORMAT",
        help=f"any of {' '.join(FORMATS)} (default {' '.join(DEFAULT_FORMATS)}; docs/generation.md, 'Output formats')",
    )
    generate.add_argument(
        "--variations",
        type=_positive_int,
        default=1,
        metavar="N",
        help="N samples of the request, with seeds --seed, --seed + 1, …, to pick from (default 1)",
    )
    _add_delivery(generate)
    _add_max_seconds(generate, "a motion longer than this")
    generate.add_argument("--no-split", action="store_true", help="keep each prompt one action even with several verbs")
    generate.add_argument(
        "--edit",
        metavar="SOURCE",
        help="edit this motion instead: a .npy of features (the .features.npy generate writes) "
        "or joints; the prompts share its length (with --keep-body)",
    )
    generate.add_argument(
        "--regenerate",
        type=_positive_int,
        metavar="K",
        help="with --edit: sample action K again (a prompt: its new text; --seconds: its new length), "
        "the others kept outside a 0.4-s margin",
    )
    generate.add_argument(
        "--fill-to",
        metavar="SECOND",
        help="with --edit: join SOURCE to this second result by --seconds (default 1) of new motion "
        "(a prompt: what happens in it)",
    )
    generate.add_argument(
        "--pin",
        type=_pose_reference,
        metavar="POSE@FRAME",
        help="with --edit and --at: the motion passes through this pose (a result's .npy and its frame)",
    )
    generate.add_argument("--at", type=float, metavar="SECONDS", help="where --pin pins its pose")
    generate.add_argument(
        "--continue",
        dest="extend",
        action="store_true",
        help="with --edit: append the prompts to SOURCE (--seconds each), its end sampled again to lead into them",
    )
    generate.add_argument(
        "--layer",
        type=_body_part,
        metavar="PART=TEXT",
        help="with --edit and --span: this body part does TEXT over the span, the rest of the body as it was, "
        'e.g. upper="a person waves" (--model motiondiffuse)',
    )
    generate.add_argument("--span", type=_span, metavar="START:END", help="where --layer lays its action, in seconds")
    generate.add_argument(
        "--keep-body",
        metavar="PART",
        help="the body part (upper, lower) of --edit's motion to keep on every frame; the rest "
        "follows the prompts "
        "(--model mmm-body keeps lower: MMM's upper-body editing; --option lower_mask=0.25)",
    )
    generate.add_argument(
        "--part",
        type=_body_part,
        action="append",
        metavar="PART=TEXT",
        help="body-part control: this part (upper, lower) does TEXT, the prompt drives the other "
        'parts, e.g. "a person runs" --part upper="a person waves their hands" '
        "(--model motiondiffuse; repeatable)",
    )
    generate.add_argument("--no-track", action="store_true", help="do not log this generation to MLflow")
    generate.set_defaults(run=_generate)


def _add_overwrite(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--overwrite", action="store_true", help=f"replace {what} when it exists (default: refuse, in one line)"
    )


def _add_testset(verbs) -> None:
    testset = verbs.add_parser("testset", help="build the N-action test set of the multi-motion evaluation")
    testset.add_argument("--n", type=_positive_int, default=4, help="actions per instance (default 4, the paper's)")
    testset.add_argument("--seed", type=int, default=0)
    testset.add_argument("--dataset", default="synthetic", help="names the MLflow experiment <dataset>/testset")
    testset.add_argument("--data", help="processed dataset directory (default data/<dataset>)")
    testset.add_argument(
        "--mirrors",
        default="same",
        help="a mirrored clip counts as its original (same, default), as its own motion "
        "(distinct), or is left out (exclude)",
    )
    testset.add_argument(
        "--first",
        type=_positive_int,
        metavar="K",
        help="keep only the first K instances: a quick-look subset for sweeps (not the paper's)",
    )
    testset.add_argument(
        "--split",
        default="test",
        help="the clips it is drawn from: test (default) or val, where sampling settings are "
        "chosen (written to n<N>-seed<S>-val)",
    )
    testset.add_argument("--force", action="store_true", help="replace a test set built with other parameters")
    testset.set_defaults(run=_testset)


def _add_evaluate(verbs) -> None:
    evaluate = verbs.add_parser(
        "evaluate",
        help="the paper's multi-motion (single-motion, editing) tables and Fig. 5",
        epilog=sampling_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_request(evaluate)
    evaluate.add_argument(
        "--batch-size", type=_positive_int, default=64, help="sequences generated at once (default 64)"
    )
    evaluate.add_argument(
        "--resume", metavar="RUN", help="finish an evaluation run (directory, name or MLflow id) with its own settings"
    )
    evaluate.add_argument("--dataset", default="synthetic", help="whose runs to look in (default synthetic)")
    evaluate.set_defaults(run=_evaluate)


def _add_request(parser: argparse.ArgumentParser) -> None:
    """An option per field of evaluate's request, in its order, as its Flag declares it
    (orchestration/evaluate/request.py): a list repeatable, a switch with its --no- form, a number
    checked as it is read; the field without a flag is the sampling options. An option not given
    leaves no attribute, so the request keeps its default and --resume knows what was given."""
    from orchestration.evaluate.request import FLAG, EvalRequest

    kinds = get_type_hints(EvalRequest)
    for declared in fields(EvalRequest):
        if FLAG not in declared.metadata:
            _add_sampling_knobs(parser)
            continue
        flag, kind = declared.metadata[FLAG], kinds[declared.name]
        if kind is bool:
            reading: dict[str, Any] = {"action": argparse.BooleanOptionalAction}
        elif get_origin(kind) is Sequence:
            reading = {"action": "append"}
        elif int in (kind, *get_args(kind)):
            reading = {"type": _positive_int if flag.positive else int}
        else:
            reading = {}
        parser.add_argument(
            flag.name,
            dest=declared.name,
            metavar=flag.metavar,
            default=argparse.SUPPRESS,
            help=_escaped(flag.text()),
            **reading,
        )


def _given_request(args: argparse.Namespace) -> dict[str, Any]:
    """The fields of evaluate's request the command line gave (the sampling options when any is)."""
    from orchestration.evaluate.request import FLAG, EvalRequest

    given = {}
    for declared in fields(EvalRequest):
        if FLAG not in declared.metadata:
            options = _sampling_options(args)
            if options:
                given[declared.name] = options
        elif hasattr(args, declared.name):
            given[declared.name] = getattr(args, declared.name)
    return given


def _add_sweep(verbs) -> None:
    sweep = verbs.add_parser("sweep", help="a Ray Tune sweep over sampling or training settings, tracked in MLflow")
    sweep.add_argument("--config", default="demo", help="configs/sweep/<name>.yaml or a path (default demo)")
    sweep.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value, e.g. --set space.eta=[0.1,0.5] (repeatable)",
    )
    sweep.add_argument("--name", help="the sweep's folder and parent run name (default: the config's file name)")
    sweep.add_argument(
        "--restart",
        action="store_true",
        help="discard the sweep of this name (its Tune experiment and folder) and start it over",
    )
    _add_ray_address(sweep)
    sweep.set_defaults(run=_sweep)


def _add_models(verbs) -> None:
    listing = verbs.add_parser(
        "models", help="what each trained model knows: its actions, lengths, words, methods and defaults"
    )
    listing.add_argument("--dataset", help="whose runs to describe (default: every dataset with a trained model)")
    listing.set_defaults(run=_models)


def _add_ui(verbs) -> None:
    ui = verbs.add_parser("ui", help="the MLflow UI on the project's tracking store")
    ui.add_argument("--port", type=_port, default=5000)
    ui.add_argument("--host", default="127.0.0.1", help="127.0.0.1 (default) keeps it on this machine")
    ui.set_defaults(run=_ui)


def _add_serve(verbs) -> None:
    from orchestration.web.server import TOKEN_VARIABLE

    serve = verbs.add_parser("serve", help="a web page and an HTTP API for generating and comparing motions")
    serve.add_argument("--port", type=_port, default=8000)
    serve.add_argument(
        "--host", default="127.0.0.1", help="127.0.0.1 (default) keeps it on this machine; another needs a token"
    )
    serve.add_argument("--token", help=f"what every API call must carry (default: ${TOKEN_VARIABLE})")
    serve.add_argument("--dataset", default="synthetic", help="whose runs to serve (default synthetic)")
    _add_max_seconds(serve, "a request for more seconds of motion than this")
    serve.add_argument("--queue", type=_positive_int, default=64, help="requests that may wait (default 64)")
    serve.add_argument(
        "--max-batch", type=_positive_int, default=16, help="sequences sampled in one call at most (default 16)"
    )
    serve.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    serve.add_argument(
        "--max-rig-mb", type=_positive_int, default=64, help="the largest character's file one may upload (default 64)"
    )
    serve.add_argument("--mlflow-ui", help="the MLflow UI's address for links to runs (default: make ui's)")
    serve.add_argument("--no-track", action="store_true", help="do not log the generations to MLflow")
    serve.set_defaults(run=_serve)


def _add_viewers(verbs) -> None:
    render = verbs.add_parser("render", help=f"draw a motion as a stick-figure {spoken(animations())}")
    export = verbs.add_parser(
        "export",
        help=f"write a motion as {spoken(exported())} ({spoken(on_rig())} on your rig with --rig)",
    )
    for parser, run in ((render, _render), (export, _export)):
        parser.add_argument("source", help="a .npy of joints (T, J, 3) or features (T, D), or a raw corpus directory")
        parser.add_argument("--id", help="clip id when SOURCE is a corpus directory")
        parser.add_argument(
            "--skeleton", choices=["t2m", "kit"], help="the motion's skeleton (default: its sidecar's, else t2m)"
        )
        parser.add_argument("--out", required=True, help="output file; its suffix chooses the format")
        _add_overwrite(parser, "--out's file")
        parser.set_defaults(run=run)
    render.add_argument(
        "--fps",
        type=_positive_float,
        help="the motion's frames per second (default: its sidecar's, else the skeleton's)",
    )
    export.add_argument(
        "--source-fps",
        type=_positive_float,
        help="the source's frames per second (default: its sidecar's, else the skeleton's)",
    )
    _add_delivery(export, recorded=True)


# the presets are m2d2m.motion.joint_map.PRESETS, named here so that --help imports no model code
JOINT_MAP_HELP = (
    "the rig's joints for ours: a preset (cmu, cmu-motionbuilder, mixamo, smpl, bandai-namco), auto, or a YAML "
    "correcting some or all joints (`m2d2m rig FILE --out map.yaml` writes one); default: the preset the rig's "
    "joints fit, else auto"
)


REST_FRAME_HELP = (
    "the frame of the rig's BVH (0 the first) whose pose motions are aimed from, instead of its rest pose "
    "(default: the rest pose where it stands as the file's motion does, else frame 0)"
)


def _add_rig(verbs) -> None:
    rig = verbs.add_parser(
        "rig", help="which joints of a character's rig take ours: matched by name, guessed, derived or missing"
    )
    rig.add_argument("file", metavar="FILE", help="the rig: a BVH (its hierarchy and OFFSETs) or a skinned GLB/glTF")
    rig.add_argument(
        "--joint-map",
        metavar="MAP",
        help=JOINT_MAP_HELP,
    )
    rig.add_argument("--rest-frame", metavar="N", type=_non_negative_int, help=REST_FRAME_HELP)
    rig.add_argument("--out", metavar="YAML", help="also write the mapping as a YAML joint map to correct")
    rig.set_defaults(run=_rig)


def _add_delivery(parser: argparse.ArgumentParser, recorded: bool = False) -> None:
    """How a clip is delivered (docs/generation.md, "Delivering a clip"): one set of options for
    `m2d2m generate` and `m2d2m export` (``recorded``: its motion is a file's, whose feet are left
    as they are unless asked), as the API's fields and the page's menu."""
    from m2d2m.motion.pose import REST_POSES
    from m2d2m.motion.retime import ROOT_MODES

    group = parser.add_argument_group('delivery (docs/generation.md, "Delivering a clip")')
    group.add_argument(
        "--fps",
        type=_positive_float,
        help="the files' frame rate, resampled by slerp (24, 30, 60…; default: the model's)",
    )
    group.add_argument(
        "--root",
        choices=ROOT_MODES,
        default=ROOT_MODES[0],
        help="keep the root's path, take it out (in-place: the "
        f"{spoken([fmt for fmt in FORMATS.values() if fmt.root_motion], 'and')} keep it as a track), "
        "or ground the clip",
    )
    group.add_argument("--loop", action="store_true", help="one seamless cycle: the end blended into the start")
    feet = group.add_mutually_exclusive_group()
    feet.add_argument(
        "--foot-fix",
        dest="foot_fix",
        action="store_const",
        const=True,
        help="keep the feet from sliding where they touch down"
        + (" (default: the motion exactly as the file has it)" if recorded else " (the default)"),
    )
    feet.add_argument(
        "--no-foot-fix",
        dest="foot_fix",
        action="store_const",
        const=False,
        help="keep the feet as " + ("the file has them (the default)" if recorded else "generated"),
    )
    group.add_argument(
        "--rest",
        choices=REST_POSES,
        default=REST_POSES[0],
        help=f"the bind pose of the {spoken(on_rig(), 'and')}: skeleton (HumanML3D's: "
        "arms down, head bone forward; default) or "
        "tpose (arms out, head up: what retargeting tools expect); the motion is the same",
    )
    group.add_argument(
        "--rig",
        metavar="FILE",
        help=f"write the {spoken(on_rig(), 'and')} on this rig: a BVH (its hierarchy and "
        "OFFSETs) or a skinned GLB "
        "(whose GLB and FBX are the character itself, animated)",
    )
    group.add_argument(
        "--joint-map",
        metavar="MAP",
        help=JOINT_MAP_HELP,
    )
    group.add_argument("--rest-frame", metavar="N", type=_non_negative_int, help=REST_FRAME_HELP)


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="m2d2m", description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for add in (
        _add_synthesize,
        _add_data,
        _add_training_verbs,
        _add_tokenize,
        _add_generate,
        _add_models,
        _add_testset,
        _add_evaluate,
        _add_sweep,
        _add_ui,
        _add_serve,
        _add_viewers,
        _add_rig,
    ):
        add(verbs)
    return parser


# a folder or disk the user must fix, not a bug: read-only, another user's, full
UNWRITABLE = (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT)


def _unwritable(error: OSError) -> str:
    where = Path(error.filename or ".")
    if ".partial" in where.name:  # an atomic write's temporary file (m2d2m/atomic.py): its folder is the matter
        where = where.parent
    advice = "free some space" if error.errno in (errno.ENOSPC, errno.EDQUOT) else "check its permissions"
    return f"{where}: {error.strerror.lower()}; {advice}, or choose another place"


def command() -> int:
    """The ``m2d2m`` console script: :func:`main`, then every object the process holds frozen out
    of the garbage collector (:func:`gc.freeze`), so that the interpreter's last collections at
    exit do not walk torch's, Lightning's and MLflow's object graphs: that took 3 to 10 s after a
    training verb's last line on 2 CPU cores, for a process that is ending (BENCHMARKS.md, "From
    the last line to the exit"). Exit handlers (Ray's shutdown, MLflow's) still run."""
    code = main()
    gc.freeze()
    return code


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()  # imports the model plugins, which may fail
    except UserError as error:
        print(f"m2d2m: error: {error}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    try:
        args.run(args)
    except UserError as error:
        if isinstance(error, NotInProject) and not is_project(Path.cwd()):
            error = outside_project()  # the cause, rather than what a project would lack
        print(f"m2d2m {args.verb}: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        if error.errno not in UNWRITABLE:
            raise
        print(f"m2d2m {args.verb}: error: {_unwritable(error)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        again = f"; `m2d2m {args.verb} --resume` continues it" if hasattr(args, "resume") else ""
        print(f"m2d2m {args.verb}: interrupted{again}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
