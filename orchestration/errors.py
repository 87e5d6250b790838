"""The one exception type the command line turns into a one-line message and exit status 2."""


class UserError(Exception):
    """Bad input from the user (a path, a value, a missing file): says what is wrong and how to
    fix it, in one line."""


class NotInProject(UserError):
    """Something a verb looks for in the project by default (a run, a config by name) is not there.
    Run outside any project, the command line says that instead (orchestration/project.py): there,
    "run `make train-vq` first" would send the user the wrong way."""
