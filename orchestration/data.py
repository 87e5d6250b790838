"""`m2d2m synthesize` and `m2d2m data`: what the command line asks for, made a corpus and a
processed dataset (docs/data.md). The synthetic corpus is made once for its parameters; a corpus
to build defaults to the project's ``data/raw/<dataset>`` (the synthetic one made there when
missing) and is built into ``data/<dataset>``; the options a corpus's layout takes are checked and
their paths made absolute (Ray tasks may run elsewhere); a dataset built before from the same corpus
with the same config is reused (building it again would give the same bytes)."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from m2d2m.layout import MANIFEST
from m2d2m.motion.rigs.joint_map import AUTO, PRESETS
from m2d2m.plugins import plugins_for_workers
from orchestration.errors import UserError
from orchestration.project import require_project
from orchestration.registry import load_plugins
from pipelines.corpora import CorpusLayout, corpus
from pipelines.features import DataConfig, build_dataset, require_replaceable, reusable_dataset
from pipelines.synthetic import FAMILIES, existing_corpus, generate_corpus

SYNTHETIC_CLIPS, SYNTHETIC_SEED = 2000, 0  # `m2d2m synthesize`'s defaults, and the corpus `m2d2m data` makes

# The options of `m2d2m data` that a corpus's layout takes (CorpusLayout.options), by their flags.
LAYOUT_OPTIONS = {
    "bvh": "--bvh",
    "joint_map": "--joint-map",
    "units": "--units",
    "subset": "--subset",
    "annotations": "--annotations",
}


def synthesize(
    out: str | Path, clips: int, seed: int, families: Sequence[str] | None, workers: int, force: bool
) -> str:
    """The synthetic corpus at ``out`` (``families``: all when None), generated unless it is there
    with these parameters and not ``force``d; the line that says which, and what it holds."""
    if Path(out).exists() and not Path(out).is_dir():
        raise UserError(f"{out}: a file, not a folder; choose another --out")
    unknown = sorted(set(families or ()) - set(FAMILIES))
    if unknown:
        raise UserError(
            f"unknown famil{'ies' if len(unknown) > 1 else 'y'} {', '.join(unknown)}; choose from {', '.join(FAMILIES)}"
        )
    try:
        if not force and existing_corpus(out, clips, seed, families):
            return f"{out}: the corpus is already there (seed {seed}, {clips} clips); --force rebuilds it"
    except ValueError as error:
        raise UserError(str(error)) from error
    started = time.perf_counter()
    summary = generate_corpus(out, clips=clips, seed=seed, families=families, workers=workers, progress=True)
    splits = summary["splits"]
    return (
        f"wrote {summary['clips']} clips to {out} in {time.perf_counter() - started:.1f} s: "
        f"{splits['train']}/{splits['val']}/{splits['test']} train/val/test, {summary['captions']} captions "
        f"({summary['multi_verb_share']:.0%} with several verbs), {summary['hours']:.2f} h of motion, "
        f"{len(summary['families'])} action families"
    )


def data_config(
    dataset: str,
    raw: str | None,
    out: str | None,
    workers: int,
    layout_options: Mapping[str, str | None],
    **settings: Any,
) -> DataConfig:
    """The build `m2d2m data --dataset` asks for: ``raw`` and ``out`` the project's
    ``data/raw/<dataset>`` and ``data/<dataset>`` when not given (the synthetic corpus made there
    when missing), ``layout_options`` the options given (None: not given) of those the corpus's
    layout takes; ``settings``: the rest of the :class:`~pipelines.features.DataConfig`."""
    if out is None:
        require_project()  # data/<dataset> is the project's
    load_plugins()  # a plugin may register the corpus
    try:
        layout = corpus(dataset).layout
    except ValueError as error:
        raise UserError(str(error)) from error
    raw_dir = Path(raw or f"data/raw/{dataset}")
    if not raw_dir.exists():
        if dataset != "synthetic":
            raise UserError(f"{raw_dir}: no such corpus; pass --raw /path/to/{dataset} ({layout.name} layout)")
        print(synthesize(raw_dir, SYNTHETIC_CLIPS, SYNTHETIC_SEED, None, workers, force=False))
    return DataConfig(
        dataset=dataset,
        raw=str(raw_dir),
        out=str(Path(out or f"data/{dataset}")),
        workers=workers,
        plugins=plugins_for_workers(),
        layout_options=_layout_options(dataset, layout, layout_options),
        **settings,
    )


def _layout_options(dataset: str, layout: CorpusLayout, given: Mapping[str, str | None]) -> dict[str, str]:
    """The layout options given, paths made absolute; one line naming an option the corpus does not take."""
    chosen = {name: value for name, value in given.items() if value is not None}
    for name in chosen.keys() - set(layout.options):
        takes = ", ".join(LAYOUT_OPTIONS[o] for o in layout.options) or "none"
        raise UserError(f"{LAYOUT_OPTIONS[name]}: the {dataset} corpus does not take it (it takes {takes})")
    for path_option in ("bvh", "annotations"):
        if path_option in chosen:
            chosen[path_option] = str(Path(chosen[path_option]).resolve())
    if "joint_map" in chosen and chosen["joint_map"] not in (*PRESETS, AUTO):
        if not Path(chosen["joint_map"]).is_file():
            raise UserError(
                f"--joint-map: {chosen['joint_map']} is neither a preset ({', '.join(PRESETS)}), {AUTO}, nor a file"
            )
        chosen["joint_map"] = str(Path(chosen["joint_map"]).resolve())
    return chosen


def build(config: DataConfig, force: bool, replace_other: bool) -> tuple[dict[str, Any], bool]:
    """The dataset ``config`` asks for: its manifest, and whether it was built now (False: one built
    before with the same config, reused unless ``force``d). Replacing what ``config.out`` holds
    when it is not a dataset of the same corpus needs ``replace_other``."""
    existing = None if force else reusable_dataset(config)
    if existing is not None:
        return existing, False
    try:
        require_replaceable(config, replace_other)
        if (Path(config.out) / MANIFEST).exists():
            print(
                f"{config.out}: built with another config; building the new one beside it (the old one stays until "
                "the new one is complete)"
            )
        return build_dataset(config, replace_other=replace_other), True
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
