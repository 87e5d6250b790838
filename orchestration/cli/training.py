"""The training verbs: one per registered model (its entry names the verb), and the VQ-VAE's and
the evaluator's, which every model shares; each takes a config, overrides and ``--resume``.
"""

from __future__ import annotations

import argparse

from orchestration.registry import models


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


def add_training_verbs(verbs) -> None:
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
