"""The one exception type the command line turns into a one-line message and exit status 2."""


class UserError(Exception):
    """Bad input from the user (a path, a value, a missing file): says what is wrong and how to
    fix it, in one line."""
