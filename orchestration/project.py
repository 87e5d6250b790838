"""The project: the folder every verb runs in, with its configs/, data/, runs/ and mlflow.db, all
of which its files name relative to it (docs/reliability.md, "A project can move"); and the one
line of a verb that needs one but runs elsewhere."""

from __future__ import annotations

from pathlib import Path

from orchestration.errors import UserError

MARKERS = ("configs", "runs", "mlflow.db")  # what only an m2d2m project holds (data/ is too common a name)


def is_project(folder: Path) -> bool:
    """Whether ``folder`` is an m2d2m project: a clone of the repository, or a folder m2d2m has run in."""
    return any((folder / marker).exists() for marker in MARKERS)


def outside_project() -> UserError:
    """The error of a verb run outside a project, naming the project above the working directory
    when there is one (a verb run in ``runs/``, for instance)."""
    here = Path.cwd()
    above = next((folder for folder in here.parents if is_project(folder)), None)
    where = f"run it in {above}" if above else "cd to your project (the folder with configs/ and runs/) first"
    return UserError(f"{here} is not an m2d2m project (no configs/, runs/ or mlflow.db in it); {where}")


def require_project() -> None:
    """Refuse to run a verb outside a project, in one line."""
    if not is_project(Path.cwd()):
        raise outside_project()
