"""The evaluation verbs: `m2d2m testset` (the N-action test set), `evaluate` (the paper's tables,
its options made from the fields of :class:`~orchestration.evaluate.request.EvalRequest`) and `sweep`
(Ray Tune over sampling or training settings).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import fields
from typing import Any, get_args, get_origin, get_type_hints

from orchestration.cli.arguments import add_ray_address, escaped, positive_int
from orchestration.cli.sampling import add_sampling_knobs, sampling_help, sampling_options


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


def add_testset(verbs) -> None:
    testset = verbs.add_parser("testset", help="build the N-action test set of the multi-motion evaluation")
    testset.add_argument("--n", type=positive_int, default=4, help="actions per instance (default 4, the paper's)")
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
        type=positive_int,
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


def add_evaluate(verbs) -> None:
    evaluate = verbs.add_parser(
        "evaluate",
        help="the paper's multi-motion (single-motion, editing) tables and Fig. 5",
        epilog=sampling_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_request(evaluate)
    evaluate.add_argument(
        "--batch-size", type=positive_int, default=64, help="sequences generated at once (default 64)"
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
            add_sampling_knobs(parser)
            continue
        flag, kind = declared.metadata[FLAG], kinds[declared.name]
        if kind is bool:
            reading: dict[str, Any] = {"action": argparse.BooleanOptionalAction}
        elif get_origin(kind) is Sequence:
            reading = {"action": "append"}
        elif int in (kind, *get_args(kind)):
            reading = {"type": positive_int if flag.positive else int}
        else:
            reading = {}
        parser.add_argument(
            flag.name,
            dest=declared.name,
            metavar=flag.metavar,
            default=argparse.SUPPRESS,
            help=escaped(flag.text()),
            **reading,
        )


def _given_request(args: argparse.Namespace) -> dict[str, Any]:
    """The fields of evaluate's request the command line gave (the sampling options when any is)."""
    from orchestration.evaluate.request import FLAG, EvalRequest

    given = {}
    for declared in fields(EvalRequest):
        if FLAG not in declared.metadata:
            options = sampling_options(args)
            if options:
                given[declared.name] = options
        elif hasattr(args, declared.name):
            given[declared.name] = getattr(args, declared.name)
    return given


def add_sweep(verbs) -> None:
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
    add_ray_address(sweep)
    sweep.set_defaults(run=_sweep)
