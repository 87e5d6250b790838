"""How long each training verb takes from its last line (``finished …``) to its exit, in a
project that has the demo's data (after `make data`; issue 54 §2: no verb more than 3 s). Each
verb trains ``--steps`` steps of its demo config with one validation, run as a user runs it (the
``m2d2m`` console script in this checkout's .venv); the first, `train-vq`, also makes the VQ-VAE
the others' tokens come from, and `--retokenize` removes the tokens first so that
`train-diffusion` tokenizes (with Ray) before training.

    python bench/exit_time.py [--project .] [--steps 4] [--retokenize] [--verbs train-vq …]

Prints Markdown for BENCHMARKS.md: the run's total seconds and the seconds from its last line to
its exit, per verb.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VERBS = ("train-vq", "train-diffusion", "train-mmm", "train-motiondiffuse", "train-evaluator")


@dataclass
class Timed:
    """A command's run: its total seconds, the seconds from its ``finished`` line to its exit
    (None when it printed none), its exit code, and each line it printed with the seconds since
    its start at which it arrived."""

    total: float
    after_finished: float | None
    returncode: int
    lines: list[tuple[float, str]] = field(default_factory=list)


def from_this_checkout(*arguments: str) -> tuple[list[str], dict[str, str]]:
    """``m2d2m <arguments>`` run on this checkout's code in a child process: the command and an
    environment with the checkout first on PYTHONPATH, what was on it kept after (a carried site,
    a sitecustomize)."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    return [sys.executable, "-m", "orchestration.cli", *arguments], {**os.environ, "PYTHONPATH": path}


def timed(command: list[str], cwd: Path, env: dict[str, str] | None = None) -> Timed:
    """Run ``command`` in ``cwd``, its output read line by line as it comes."""
    start = time.monotonic()
    finished = None
    lines = []
    with subprocess.Popen(
        command, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    ) as process:
        assert process.stdout is not None
        for line in process.stdout:
            now = time.monotonic()
            lines.append((now - start, line.rstrip("\n")))
            if line.startswith("finished ") and finished is None:
                finished = now
    end = time.monotonic()
    return Timed(end - start, None if finished is None else end - finished, process.returncode, lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--project", type=Path, default=Path.cwd())
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--retokenize", action="store_true")
    parser.add_argument("--verbs", nargs="+", default=list(VERBS), choices=VERBS)
    args = parser.parse_args()
    m2d2m = str(ROOT / ".venv" / "bin" / "m2d2m")
    steps = [f"--set=trainer.max_steps={args.steps}", f"--set=trainer.val_every_steps={args.steps}"]
    print(f"    python bench/exit_time.py --steps {args.steps}{' --retokenize' if args.retokenize else ''}\n")
    print("| verb | total (s) | last line → exit (s) |\n|---|---|---|")
    for verb in args.verbs:
        if verb == "train-diffusion" and args.retokenize:
            for tokens in args.project.glob("data/*/tokens"):
                shutil.rmtree(tokens)
        run = timed([m2d2m, verb, "--config", "demo", *steps], args.project)
        if run.returncode != 0:
            sys.exit(f"{verb} exited {run.returncode}")
        after = "-" if run.after_finished is None else f"{run.after_finished:.2f}"
        print(f"| `m2d2m {verb}` | {run.total:.1f} | {after} |", flush=True)


if __name__ == "__main__":
    main()
