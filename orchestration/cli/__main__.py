"""``python -m orchestration.cli``: the command line without its console script (the tests and
bench/ run it so, with the interpreter they run under)."""

import sys

from orchestration.cli import main

sys.exit(main())
