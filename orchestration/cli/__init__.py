"""The ``m2d2m`` command line: one sub-command per stage of the flow.

Every user error (bad path, bad value, missing file) ends in one line on stderr and exit
status 2; anything else is a bug and keeps its traceback. Each verb is an ``add_<verb>``
function that declares its options beside a handler that parses nothing and decides nothing:
the work is in the modules the handler calls. The verbs sit in one module per job: ``data``
(synthesize, data, tokenize), ``training`` (the training verbs, from the model registry, so a new
model brings its own verb), ``generating`` with ``editing`` and ``results`` (generate),
``exporting`` (render, export, rig), ``evaluating`` (testset, evaluate, sweep) and ``serving``
(models, ui, serve); ``arguments``, ``sampling`` and ``delivery`` hold the options several share.
"""

from __future__ import annotations

import argparse
import errno
import gc
import sys
from pathlib import Path
from typing import NoReturn

from orchestration.cli.data import add_data, add_synthesize, add_tokenize
from orchestration.cli.evaluating import add_evaluate, add_sweep, add_testset
from orchestration.cli.exporting import add_rig, add_viewers
from orchestration.cli.generating import add_generate
from orchestration.cli.serving import add_models, add_serve, add_ui
from orchestration.cli.training import add_training_verbs
from orchestration.errors import NotInProject, UserError
from orchestration.project import is_project, outside_project


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad command line as one line, like every other user error,
    instead of a usage block: the usage is one ``--help`` away."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="m2d2m", description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for add in (
        add_synthesize,
        add_data,
        add_training_verbs,
        add_tokenize,
        add_generate,
        add_models,
        add_testset,
        add_evaluate,
        add_sweep,
        add_ui,
        add_serve,
        add_viewers,
        add_rig,
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
