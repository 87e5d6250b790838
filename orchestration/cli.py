"""The ``m2d2m`` command line: one sub-command per stage of the flow.

Every user error (bad path, bad value, missing file) ends in one line on stderr and exit
status 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from orchestration.errors import UserError


def _positive_int(text: str) -> int:
    value = int(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _synthesize(args: argparse.Namespace) -> None:
    from pipelines.synthetic import FAMILIES, generate_corpus

    families = args.families.split(",") if args.families else None
    unknown = sorted(set(families or ()) - set(FAMILIES))
    if unknown:
        raise UserError(f"unknown famil{'ies' if len(unknown) > 1 else 'y'} {', '.join(unknown)}; choose from {', '.join(FAMILIES)}")
    out = Path(args.out)
    marker = out / "corpus.json"
    if marker.exists() and not args.force:
        existing = json.loads(marker.read_text())
        wanted = {"clips": args.clips, "seed": args.seed, "families": list(families or FAMILIES)}
        if all(existing.get(key) == value for key, value in wanted.items()):
            print(f"{out}: the corpus is already there (seed {args.seed}, {args.clips} clips); --force rebuilds it")
            return
        raise UserError(f"{out} holds a different corpus ({marker}); use another --out or --force")
    started = time.perf_counter()
    summary = generate_corpus(
        out, clips=args.clips, seed=args.seed, families=families, workers=args.workers, progress=True
    )
    splits = summary["splits"]
    print(
        f"wrote {summary['clips']} clips to {out} in {time.perf_counter() - started:.1f} s: "
        f"{splits['train']}/{splits['val']}/{splits['test']} train/val/test, {summary['captions']} captions "
        f"({summary['multi_verb_share']:.0%} with several verbs), {summary['hours']:.2f} h of motion, "
        f"{len(summary['families'])} action families"
    )


def _check_data(directory: Path) -> None:
    from pipelines.dataset import check_dataset

    problems = check_dataset(directory)
    for problem in problems:
        print(problem)
    if problems:
        raise UserError(f"{directory}: {len(problems)} problem(s) against its manifest")
    print(f"{directory}: OK (counts, checksums and schema match the manifest)")


def _data(args: argparse.Namespace) -> None:
    if args.check:
        _check_data(Path(args.check))
        return
    from pipelines.corpora import CORPUS_SKELETONS
    from pipelines.features import DataConfig, build_dataset, print_summary

    if args.dataset not in CORPUS_SKELETONS:
        raise UserError(f"unknown dataset {args.dataset!r}; choose one of {', '.join(CORPUS_SKELETONS)}")
    raw = Path(args.raw or f"data/raw/{args.dataset}")
    out = Path(args.out or f"data/{args.dataset}")
    if not raw.exists():
        if args.dataset != "synthetic":
            raise UserError(f"{raw}: no such corpus; pass --raw /path/to/{args.dataset} (HumanML3D layout)")
        _synthesize(argparse.Namespace(out=str(raw), clips=2000, seed=0, families=None, workers=args.workers, force=False))
    config = DataConfig(
        dataset=args.dataset, raw=str(raw), out=str(out), samples_per_shard=args.samples_per_shard,
        min_frames=args.min_frames, max_frames=args.max_frames, workers=args.workers, ray_address=args.ray_address,
    )
    manifest_path = out / "manifest.json"
    if manifest_path.exists() and not args.force:
        existing = json.loads(manifest_path.read_text(encoding="utf-8"))
        if existing.get("config") == config.recorded():
            print(f"{out}: already built from {raw} with this config; reusing it (--force rebuilds)")
            print_summary(existing, out)
            return
        print(f"{out}: built with another config; rebuilding")
    try:
        manifest = build_dataset(config)
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    print_summary(manifest, out)
    print(f"wrote {out} ({sum(len(v) for v in manifest['shards'].values())} shards); verify with: m2d2m data --check {out}")


def _render(args: argparse.Namespace) -> None:
    from m2d2m.render import render_motion
    from orchestration.viewing import load_motion

    out = Path(args.out)
    if out.suffix.lower() not in (".gif", ".mp4"):
        raise UserError(f"{out}: the animation format comes from the suffix; use .gif or .mp4")
    motion = load_motion(args.source, args.id, args.skeleton)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        render_motion(
            motion.joints, out, skeleton=motion.skeleton, fps=args.fps, segments=motion.segments or None,
            title=motion.caption,
        )
    except RuntimeError as error:  # no MP4 encoder on this machine, or the encoder failed
        raise UserError(str(error)) from error
    print(f"wrote {out}")


def _export(args: argparse.Namespace) -> None:
    from m2d2m.export import save_bvh, save_motion_npy
    from orchestration.viewing import load_motion

    out = Path(args.out)
    suffix = out.suffix.lower()
    if suffix not in (".bvh", ".npy"):
        raise UserError(f"{out}: export writes .bvh or .npy (with a .json sidecar)")
    motion = load_motion(args.source, args.id, args.skeleton)
    out.parent.mkdir(parents=True, exist_ok=True)
    fps = args.fps or motion.skeleton.fps
    if suffix == ".bvh":
        save_bvh(out, motion.joints, skeleton=motion.skeleton, fps=fps)
    else:
        save_motion_npy(out, motion.joints, fps=fps, skeleton=motion.skeleton, segments=motion.segments or None)
    print(f"wrote {out}")


def _add_motion_source(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", help="a .npy of joints (T, J, 3) or features (T, D), or a raw corpus directory")
    parser.add_argument("--id", help="clip id when SOURCE is a corpus directory")
    parser.add_argument("--skeleton", default="t2m", choices=["t2m", "kit"])
    parser.add_argument("--fps", type=float, help="frames per second (default: the skeleton's)")
    parser.add_argument("--out", required=True, help="output file; its suffix chooses the format")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="m2d2m", description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    synth = verbs.add_parser("synthesize", help="generate the embedded synthetic motion-language corpus")
    synth.add_argument("--out", default="data/raw/synthetic", help="corpus directory (HumanML3D raw layout)")
    synth.add_argument("--clips", type=_positive_int, default=2000)
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--families", help="comma-separated action families (default: all)")
    synth.add_argument("--workers", type=_positive_int, default=2, help="processes to generate with")
    synth.add_argument("--force", action="store_true", help="rebuild even if the corpus exists")
    synth.set_defaults(run=_synthesize)

    data = verbs.add_parser("data", help="preprocess a corpus into WebDataset shards with Ray Data")
    data.add_argument("--dataset", default="synthetic", help="synthetic, humanml3d or kit")
    data.add_argument("--raw", help="raw corpus directory (default data/raw/<dataset>)")
    data.add_argument("--out", help="output directory (default data/<dataset>)")
    data.add_argument("--workers", type=_positive_int, default=2, help="Ray tasks in parallel")
    data.add_argument("--ray-address", help="join a Ray cluster (default: a local Ray; also RAY_ADDRESS)")
    data.add_argument("--samples-per-shard", type=_positive_int, default=500)
    data.add_argument("--min-frames", type=_positive_int, help="keep clips with at least this many feature frames")
    data.add_argument("--max-frames", type=_positive_int, help="keep clips with fewer feature frames than this")
    data.add_argument("--force", action="store_true", help="rebuild even if an identical dataset exists")
    data.add_argument("--check", metavar="DIR", help="verify a processed dataset against its manifest and exit")
    data.set_defaults(run=_data)

    render = verbs.add_parser("render", help="draw a motion as a stick-figure GIF or MP4")
    _add_motion_source(render)
    render.set_defaults(run=_render)

    export = verbs.add_parser("export", help="write a motion as BVH (for Blender, game engines) or npy + json")
    _add_motion_source(export)
    export.set_defaults(run=_export)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.run(args)
    except UserError as error:
        print(f"m2d2m {args.verb}: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
