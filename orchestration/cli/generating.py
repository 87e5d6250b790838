"""`m2d2m generate`: text to motion from prompts, an edit of a motion (orchestration.cli.editing
for the timeline's), or body-part control, each checked before its model loads.
"""

from __future__ import annotations

import argparse

from m2d2m.motion.files.formats import DEFAULT_FORMATS, FORMATS, suffixes
from orchestration.cli.arguments import add_max_seconds, add_overwrite, body_part, positive_int
from orchestration.cli.delivery import add_delivery
from orchestration.cli.editing import add_edit_options, edit_flags, edit_timeline
from orchestration.cli.results import planned_output, planned_outputs, report
from orchestration.cli.sampling import add_sampling_knobs, sampling_help, sampling_options
from orchestration.errors import UserError
from orchestration.registry import DEFAULT_MODEL, methods_of_models, models


def _generate(args: argparse.Namespace) -> None:
    from orchestration.generate.loading import load_generator
    from orchestration.generate.outputs import staged
    from orchestration.generate.prompts import check_prompted, length_cap
    from orchestration.generate.sampling import edit_part, generate
    from orchestration.viewing import load_features

    timeline_flags = edit_flags(args)
    if timeline_flags and (args.edit is None or args.keep_body is not None or args.part):
        raise UserError(
            f"{timeline_flags[0]} edits a result on its timeline: it goes with --edit SOURCE, "
            "not with --keep-body or --part"
        )
    if args.part:
        return _generate_parts(args)
    if args.edit is not None and args.keep_body is None:
        return edit_timeline(args)
    check_prompted(args.prompts, args.seconds, args.edit, args.keep_body)
    planned = planned_outputs(args)
    generator = load_generator(args.model, args.checkpoint, args.dataset)
    options = sampling_options(args)
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
            report(motion, variation, args.prompts, args)


def _generate_parts(args: argparse.Namespace) -> None:
    """``generate --part PART=TEXT``: one sentence per body part; a prompt, if given, drives the parts
    not named."""
    from orchestration.generate.loading import load_generator
    from orchestration.generate.outputs import staged
    from orchestration.generate.prompts import length_cap, plan_parts
    from orchestration.generate.sampling import generate_parts

    parts, seconds = plan_parts(args.part, args.prompts, args.seconds, editing=args.edit is not None)
    output = planned_output(args)
    generator = load_generator(args.model, args.checkpoint, args.dataset)
    options = sampling_options(args)
    motion = generate_parts(
        generator, parts, seconds=seconds, seed=args.seed, max_seconds=length_cap(args.max_seconds), **options
    )
    with staged([(args.seed, output)]) as [(_, output)]:
        report(motion, output, [f"{part}: {text}" for part, text in parts.items()], args)


def _add_model_choice(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model", default=DEFAULT_MODEL, help=f"a registered model: {', '.join(models())} (default {DEFAULT_MODEL})"
    )
    parser.add_argument(
        "--checkpoint",
        default="latest",
        help="the model's file, a run directory or name, or an MLflow run id (default: latest)",
    )


def add_generate(verbs) -> None:
    generate = verbs.add_parser(
        "generate",
        help="text to motion: one sequence doing the prompts in order",
        epilog=sampling_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_prompt_options(generate)
    _add_output_options(generate)
    add_delivery(generate)
    add_max_seconds(generate, "a motion longer than this")
    generate.add_argument("--no-split", action="store_true", help="keep each prompt one action even with several verbs")
    add_edit_options(generate)
    generate.add_argument(
        "--part",
        type=body_part,
        action="append",
        metavar="PART=TEXT",
        help="body-part control: this part (upper, lower) does TEXT, the prompt drives the other "
        'parts, e.g. "a person runs" --part upper="a person waves their hands" '
        "(--model motiondiffuse; repeatable)",
    )
    generate.add_argument("--no-track", action="store_true", help="do not log this generation to MLflow")
    generate.set_defaults(run=_generate)


def _add_prompt_options(parser: argparse.ArgumentParser) -> None:
    """What to generate and with which model: the prompts, their lengths, the method, the sampling
    options and seed, the model file."""
    parser.add_argument(
        "prompts", nargs="*", help='one or more prompts, e.g. "a person walks forward" "a person jumps"'
    )
    parser.add_argument(
        "--seconds",
        type=float,
        nargs="+",
        help="duration of each prompt, or one for all (default: the corpus's typical length per verb)",
    )
    parser.add_argument("--method", help=f"the multi-action method ({methods_of_models()}; default: the model's first)")
    add_sampling_knobs(parser)
    parser.add_argument("--seed", type=int, default=0)
    _add_model_choice(parser)
    parser.add_argument("--dataset", default="synthetic", help="whose runs to look in (default synthetic)")


def _add_output_options(parser: argparse.ArgumentParser) -> None:
    """Where the files go, in which formats, and how many samples of the request."""
    parser.add_argument(
        "--out",
        help=f"a folder, or one file whose suffix ({suffixes(FORMATS.values())}) is its format "
        "(default: the folder runs/<dataset>/generate/<new run>)",
    )
    parser.add_argument("--name", default="motion", help="file name stem in the --out folder (default motion)")
    add_overwrite(parser, "--out's folder (every file in it) or file")
    parser.add_argument(
        "--formats",
        nargs="+",
        metavar="FORMAT",
        help=f"any of {' '.join(FORMATS)} (default {' '.join(DEFAULT_FORMATS)}; docs/generation.md, 'Output formats')",
    )
    parser.add_argument(
        "--variations",
        type=positive_int,
        default=1,
        metavar="N",
        help="N samples of the request, with seeds --seed, --seed + 1, …, to pick from (default 1)",
    )
