"""`m2d2m testset` and `m2d2m evaluate`: the paper's multi-motion table (§5.2, Tables 1–2), its
single-motion table (§5.3, Table 3), the editing table (MMM Table 3) and Fig. 5, for model files
of any registered models on one N-action test set.

The measurements are the library's (:mod:`m2d2m.evaluation.measurements`), the reports
:mod:`orchestration.reports`'; this package holds what makes them a run, one job a module:
``testsets`` (building, opening, the reference measurements), ``request`` (what the command line
asks, declared once; it loads without torch, so the package imports nothing here and each name is
imported from its module), ``options`` (the request's per-model methods, knobs and checkpoints
checked against the models), ``settings`` (fixed for the run, read back from older records),
``jobs`` (a result file per finished job, so ``--resume`` recomputes nothing that is done),
``records`` (the run directory and MLflow runs), ``table`` (the table and figure rebuilt from the
result files) and ``run`` (:func:`orchestration.evaluate.run.evaluate`).
"""
