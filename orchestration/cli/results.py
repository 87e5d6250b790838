"""A generation's results: where its files go, checked before a model loads, then delivered,
written, logged and said, for `m2d2m generate` and each of its ways (prompts, edits, body parts).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from orchestration.cli.delivery import delivered, delivery_asked, delivery_notes
from orchestration.project import is_project


def planned_output(args: argparse.Namespace) -> Any:
    """Where a generation's files go, checked before the model loads: ``--out``, and without it
    the project's generate runs' folder, made now (a file in its way is one line, not a lost
    sampling; outside a project nothing is made before the verb says where it runs)."""
    from orchestration.generate.outputs import plan_output
    from orchestration.generate.saving import GENERATE_STAGE
    from orchestration.runs import ensure_stage_dir

    output = plan_output(args.out, args.name, args.formats, delivery_asked(args), args.overwrite)
    if output.directory is None and is_project(Path.cwd()):
        ensure_stage_dir(args.dataset, GENERATE_STAGE)
    return output


def planned_outputs(args: argparse.Namespace) -> Any:
    """The seeds of ``--variations`` and where each one's files go, all checked before the model loads."""
    from orchestration.generate.outputs import variations

    return variations(planned_output(args), args.seed, args.variations)


def report(motion: Any, output: Any, prompts: list[str], args: argparse.Namespace) -> None:
    """Deliver a generation as asked, save its files, log it, and say what was made."""
    from orchestration.generate.saving import GENERATE_STAGE, save_generation

    motion = delivered(motion, output.delivery)
    files, run_id = save_generation(motion, output, prompts, args.dataset, track=not args.no_track)
    for text, (first, end) in zip(motion.actions, motion.ranges):
        print(f"  {first / motion.fps:5.1f}–{end / motion.fps:5.1f} s  {text}")
    print(
        f"wrote {', '.join(str(path) for path in files.values())} ({motion.seconds:.1f} s, "
        f"{motion.settings['method']}; bone-length spread {motion.quality['bone_length_std_mm_mean']:.1f} mm "
        "before the rigid skeleton)"
    )
    delivery_notes(files, motion, output.delivery)
    if run_id is not None:
        print(f"logged to MLflow run {run_id} (experiment {args.dataset}/{GENERATE_STAGE}); `make ui` to browse")
