"""A sweep's progress in a log: where stderr is not a terminal, one plain line per finished trial
(``sweep demo: 3/6 trial (50 %), ..., eta=0.25 ts=90 done``) beside Ray Tune's status table
(m2d2m/progress.py, docs/reliability.md).

Tune pickles its callbacks with the experiment and hands them back to a restored one, so this one
settles what it prints when each run of the driver starts (:meth:`TrialLines.setup`), not when the
sweep was first made: a sweep restored from a killed driver counts the trials it had finished and
prints to the log it now writes to.
"""

from __future__ import annotations

from typing import Any

from ray import tune

from m2d2m.progress import ProgressLines, on_terminal


class TrialLines(tune.Callback):
    """Counts finished trials (``total`` in all) of the sweep ``name`` over ``knobs``."""

    def __init__(self, name: str, knobs: list[str], total: int) -> None:
        self.name, self.knobs, self.total = name, knobs, total
        self.printing = False
        self.lines: ProgressLines | None = None

    def setup(self, **info: Any) -> None:
        self.printing, self.lines = not on_terminal(), None

    def on_step_begin(self, iteration: int, trials: list, **info: Any) -> None:
        if self.printing and self.lines is None:  # the first step: restored trials are all there
            done = sum(trial.status == trial.TERMINATED for trial in trials)
            self.lines = ProgressLines(total=self.total, desc=f"sweep {self.name}", unit="trial", initial=done)

    def _finished(self, trial: Any, outcome: str) -> None:
        if self.lines is None:
            return
        knobs = " ".join(f"{k}={trial.config[k]}" for k in self.knobs if k in trial.config)
        self.lines.set_postfix_str(f"{knobs} {outcome}")
        self.lines.update()

    def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self._finished(trial, "done")

    def on_trial_error(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self._finished(trial, "failed")

    def on_experiment_end(self, trials: list, **info: Any) -> None:
        if self.lines is not None:  # the last count, when the sweep took long enough to print any
            self.lines.close()
