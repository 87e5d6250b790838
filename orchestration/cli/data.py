"""The data verbs: `m2d2m synthesize` (the embedded corpus), `data` (a corpus into WebDataset
shards) and `tokenize` (every motion into VQ tokens), each with its ``--check`` against its manifest.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from orchestration.cli.arguments import add_ray_address, positive_int
from orchestration.errors import UserError


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


def add_synthesize(verbs) -> None:
    synth = verbs.add_parser("synthesize", help="generate the embedded synthetic motion-language corpus")
    synth.add_argument("--out", default="data/raw/synthetic", help="corpus directory (HumanML3D raw layout)")
    synth.add_argument("--clips", type=positive_int, default=2000)
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--families", help="comma-separated action families (default: all)")
    synth.add_argument("--workers", type=positive_int, default=2, help="processes to generate with")
    synth.add_argument("--force", action="store_true", help="rebuild even if the corpus exists")
    synth.set_defaults(run=_synthesize)


def add_data(verbs) -> None:
    data = verbs.add_parser("data", help="preprocess a corpus into WebDataset shards with Ray Data")
    data.add_argument(
        "--dataset", default="synthetic", help="synthetic, humanml3d, kit, or a corpus a plugin registers"
    )
    data.add_argument("--raw", help="raw corpus directory (default data/raw/<dataset>)")
    data.add_argument("--out", help="output directory (default data/<dataset>)")
    data.add_argument("--workers", type=positive_int, default=2, help="Ray tasks in parallel")
    add_ray_address(data)
    data.add_argument("--samples-per-shard", type=positive_int, default=500)
    data.add_argument("--min-frames", type=positive_int, help="keep clips with at least this many feature frames")
    data.add_argument("--max-frames", type=positive_int, help="keep clips with fewer feature frames than this")
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


def add_tokenize(verbs) -> None:
    tokenize = verbs.add_parser("tokenize", help="encode every motion into VQ tokens (Ray Data)")
    tokenize.add_argument(
        "--vq", help="vq.pt, a checkpoint, a run directory or name, or an MLflow run id (default: latest)"
    )
    tokenize.add_argument("--dataset", default="synthetic", help="whose latest VQ run to use by default")
    tokenize.add_argument("--data", help="processed dataset directory (default: the one the VQ-VAE was trained on)")
    tokenize.add_argument("--workers", type=positive_int, default=2)
    add_ray_address(tokenize)
    tokenize.add_argument("--check", metavar="DIR", help="verify a token set against its manifest and exit")
    tokenize.set_defaults(run=_tokenize)
