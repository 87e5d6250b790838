"""The machinery of a training run: a config in, a run directory, an MLflow run and a model file
out. :func:`open_run` resolves and checks the config and opens (or, with ``resume``, reopens) the
run directory; :func:`fit` trains with Lightning; :func:`export_snapshots` and :func:`finish`
write the model files and mark the run as its stage's ``latest``. Every model file the project
trains, the VQ-VAE's and the evaluator's included, is made by one recipe built from these pieces
(:func:`orchestration.recipe.run_recipe`).

Several processes may train one run (DDP). Lightning's own launcher (``trainer.devices: 2``, or
more GPUs) starts every rank after the first by re-running the command; those processes find the
run in :data:`JOIN_RUN` and join it instead of opening another. Ray Train workers
(:func:`orchestration.recipe.train_on_workers`) are handed the run directory. Only global rank 0
writes run files, MLflow params and model files.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import signal
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import yaml

from m2d2m.generators.options import COMPILE
from m2d2m.layout import relative_to_project
from m2d2m.precision import fast_bf16
from orchestration.config import flatten, is_number, load_config
from orchestration.errors import UserError
from orchestration.runs import (
    exclusive,
    find_run,
    mark_latest,
    new_run_dir,
    newest_run,
    read_run_info,
    write_run_info,
)
from orchestration.tracking import artifact_location, ensure_experiment, experiment_name, tracking_uri

SNAPSHOTS = "snapshots"  # a run's folder of weights at chosen steps (trainer.snapshots)
# Trainer settings every training config may leave out: off unless asked for (see fit)
TRAINING_DEFAULTS = {"trainer": {"ema": 0.0, "snapshots": [], "compile": "off"}}
JOIN_RUN = "M2D2M_JOIN_RUN"  # environment: the run directory a DDP rank started by Lightning joins


def lightning_precision(setting: str) -> str:
    """``auto``: bf16 mixed precision where a GPU supports it, full precision on a CPU."""
    if setting != "auto":
        return setting
    return "bf16-mixed" if torch.cuda.is_available() and fast_bf16("cuda") else "32-true"


def validation_interval(trainer_cfg: dict[str, Any]) -> int:
    """Steps between validations, and so the DataModules' epoch length: ``val_every_steps``, or
    ``max_steps`` when that is shorter, so that even a short smoke run validates once, at its
    end, and leaves a best checkpoint and a model file."""
    return min(trainer_cfg["val_every_steps"], trainer_cfg["max_steps"])


ACCELERATORS = ("auto", "cpu", "gpu", "cuda", "mps", "tpu")  # Lightning's accelerator names


def _is_count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def _check_settings(config: dict[str, Any]) -> None:
    """Refuse, before a run directory exists, settings no training can run with: step counts,
    where to run, and the optimiser's numbers (which torch would only refuse mid-way)."""
    trainer_cfg, optim = config["trainer"], config["optim"]
    for key in ("max_steps", "val_every_steps"):
        if not _is_count(trainer_cfg[key]):
            raise UserError(f"trainer.{key} must be a whole number of steps >= 1, got {trainer_cfg[key]!r}")
    ema = trainer_cfg.get("ema") or 0.0
    if not (_is_finite_number(ema) and 0.0 <= ema < 1.0):
        raise UserError(f"trainer.ema must be a decay in [0, 1) (0: off), got {ema!r}")
    snapshots = trainer_cfg.get("snapshots") or []
    if not isinstance(snapshots, list) or not all(
        _is_count(step) and step <= trainer_cfg["max_steps"] for step in snapshots
    ):
        raise UserError(
            f"trainer.snapshots must be a list of steps from 1 to trainer.max_steps "
            f"({trainer_cfg['max_steps']}), got {snapshots!r}"
        )
    compile_setting(trainer_cfg["compile"])
    if trainer_cfg["accelerator"] not in ACCELERATORS:
        raise UserError(
            f"trainer.accelerator must be one of {', '.join(ACCELERATORS)}, got {trainer_cfg['accelerator']!r}"
        )
    devices = trainer_cfg["devices"]
    if not (
        devices in ("auto", -1)
        or _is_count(devices)
        or (isinstance(devices, list) and devices and all(isinstance(d, int) and d >= 0 for d in devices))
    ):
        raise UserError(f"trainer.devices must be auto, -1, a count >= 1 or a list of device indices, got {devices!r}")
    if not _is_finite_number(optim["lr"]) or not optim["lr"] > 0:
        raise UserError(f"optim.lr must be a number > 0, got {optim['lr']!r}")
    if not (optim.get("grad_clip") is None or (_is_finite_number(optim["grad_clip"]) and optim["grad_clip"] > 0)):
        raise UserError(f"optim.grad_clip must be null (off) or a number > 0, got {optim['grad_clip']!r}")
    if "batch_size" in config.get("data", {}) and not _is_count(config["data"]["batch_size"]):
        raise UserError(f"data.batch_size must be a whole number >= 1, got {config['data']['batch_size']!r}")


def compile_setting(value: Any) -> str:
    """``trainer.compile`` as one of off, auto, on (training/step.py). YAML reads a bare ``off`` or
    ``on`` — in a config or a ``--set`` — as a boolean, so those are taken for the words."""
    choice = ("on" if value else "off") if isinstance(value, bool) else value
    if choice not in COMPILE:
        raise UserError(f"trainer.compile must be one of {', '.join(COMPILE)}, got {value!r}")
    return choice


def _is_finite_number(value: Any) -> bool:
    return is_number(value) and math.isfinite(value)


# the runs opened by the stage calls in progress, innermost last, each with the lock this process
# holds on it while it trains (a second command resuming it refuses; docs/reliability.md)
_opened: list[tuple[Path, contextlib.ExitStack]] = []


def records_failure(stage: Callable[..., Path]) -> Callable[..., Path]:
    """Decorate a training stage so that, when it raises, the run it opened says so in its
    ``run.json`` (``failed``, or ``interrupted`` for Ctrl-C; both resumable) instead of
    ``running``; a bad model setting (:class:`~m2d2m.networks.config.ConfigError`) becomes a
    one-line error. Only a SIGKILL leaves ``running`` behind, and ``--resume`` continues that."""
    from m2d2m.networks.config import ConfigError

    @functools.wraps(stage)
    def recorded(*args: Any, **kwargs: Any) -> Path:
        depth = len(_opened)
        try:
            return stage(*args, **kwargs)
        except BaseException as error:
            for run_dir, _ in _opened[depth:]:
                if read_run_info(run_dir).get("status") == "running":
                    write_run_info(
                        run_dir,
                        status="interrupted" if isinstance(error, KeyboardInterrupt) else "failed",
                        error=f"{type(error).__name__}: {error}"[:1000],
                    )
            if isinstance(error, ConfigError):
                raise UserError(str(error)) from error
            raise
        finally:
            for _, lock in _opened[depth:]:
                lock.close()
            del _opened[depth:]

    return recorded


@dataclass(frozen=True)
class OpenedRun:
    """A run being trained: its stage, directory, config, MLflow run id (None for a new run) and
    whether it resumes (``True``, or the run it was asked for by name)."""

    stage: str
    run_dir: Path
    config: dict[str, Any]
    run_id: str | None
    resume: bool | str


def open_run(
    stage: str | Callable[[dict[str, Any]], str],
    configs: str,
    config_name: str,
    overrides: list[str],
    resume: bool | str,
    join: Path | None = None,
    optional: Iterable[str] = (),
    check: Callable[[dict[str, Any]], None] | None = None,
) -> OpenedRun:
    """The run of ``stage`` to train, new or resumed, with its config (``configs/<configs>/<config_name>.yaml``
    with the overrides; the dotted keys ``optional`` a file may leave out); ``stage`` may depend on
    the config (a function of it: a part tokenizer's stage is ``vq-upper``). Every check,
    the model's own ``check`` (ValueError) among them, comes before a new run's directory exists:
    a run that could never start is not left behind for ``--resume`` to pick. A new run's config
    is written before training, so processes that ``join`` it (or find it in :data:`JOIN_RUN`)
    train the same thing."""
    join = join or (Path(os.environ[JOIN_RUN]) if os.environ.get(JOIN_RUN) else None)
    if join is not None:
        info = read_run_info(join)
        return _recorded(info["stage"], join, info, resume)
    config = load_config(configs, config_name, overrides, TRAINING_DEFAULTS, optional)
    if callable(stage):
        stage = stage(config)
    _check_settings(config)
    try:
        if check is not None:
            check(config)
    except ValueError as error:
        raise UserError(str(error)) from error
    if not resume:
        run_dir = new_run_dir(config["dataset"], stage)
        lock = _hold(run_dir, stage)
        (run_dir / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
        write_run_info(run_dir, stage=stage, dataset=config["dataset"], status="running", config=config)
        _opened.append((run_dir, lock))
        return OpenedRun(stage, run_dir, config, None, resume)
    if overrides:
        raise UserError("--set cannot change a run being resumed; resume as it was, or start a new run")
    # a named run (a bench resuming the run it started), else the newest one of the stage
    dataset = config["dataset"]
    run_dir = find_run(resume, dataset, stage) if isinstance(resume, str) else newest_run(dataset, stage)
    info = read_run_info(run_dir)
    if info.get("stage", stage) != stage:
        raise UserError(f"{run_dir} is a {info['stage']} run, not a {stage} run")
    if info.get("status") == "finished":
        raise UserError(f"{run_dir} already finished; start a new run instead of --resume")
    lock = _hold(run_dir, stage)  # before anything is written: a run another command trains refuses here
    write_run_info(run_dir, status="running")
    _opened.append((run_dir, lock))
    return _recorded(stage, run_dir, info, resume)


def _hold(run_dir: Path, stage: str) -> contextlib.ExitStack:
    """This process's hold on a run it trains, released when its stage call ends (or the process does)."""
    lock = contextlib.ExitStack()
    lock.enter_context(
        exclusive(run_dir / ".lock", f"{run_dir} is being trained by another command; let it finish first")
    )
    return lock


def _recorded(stage: str, run_dir: Path, info: dict[str, Any], resume: bool | str) -> OpenedRun:
    """A run that exists, with the config its run.json (``info``) records (for the process that
    resumes it and every rank that joins it)."""
    return OpenedRun(stage, run_dir, info["config"], info.get("mlflow_run_id"), resume)


def _mlflow_logger(dataset: str, stage: str, run_dir: Path, run_id: str | None):
    from lightning.pytorch.loggers import MLFlowLogger

    experiment = experiment_name(dataset, stage)
    ensure_experiment(experiment)
    return MLFlowLogger(
        experiment_name=experiment,
        tracking_uri=tracking_uri(),
        run_name=run_dir.name,
        run_id=run_id,
        tags={"dataset": dataset, "stage": stage, "run_dir": relative_to_project(run_dir)},
        artifact_location=artifact_location(experiment),
    )


@dataclass
class _Fitted:
    trainer: Any
    checkpoints: Any
    logger: Any
    last: Path

    @property
    def primary(self) -> bool:
        """Global rank 0: the process that writes the run's files."""
        return self.trainer.is_global_zero


def _placement(trainer_cfg: dict[str, Any], ray_train: bool) -> dict[str, Any]:
    """Trainer arguments that say where it runs: the config's accelerator and devices (several
    devices mean DDP, Lightning launching the other ranks), or one device per Ray Train worker."""
    if not ray_train:
        return {"accelerator": trainer_cfg["accelerator"], "devices": trainer_cfg["devices"]}
    from ray.train.lightning import RayDDPStrategy, RayLightningEnvironment

    return {
        "accelerator": trainer_cfg["accelerator"],
        "devices": "auto",
        "strategy": RayDDPStrategy(),
        "plugins": [RayLightningEnvironment()],
    }


@contextlib.contextmanager
def _joinable(run_dir: Path) -> Iterator[None]:
    """While training, processes Lightning starts for the other DDP ranks inherit the run to join."""
    before = os.environ.get(JOIN_RUN)
    os.environ[JOIN_RUN] = str(run_dir.resolve())
    try:
        yield
    finally:
        if before is None:
            del os.environ[JOIN_RUN]
        else:
            os.environ[JOIN_RUN] = before


def fit(run: OpenedRun, module, datamodule, monitor: str, callbacks: list, ray_train: bool = False) -> _Fitted:
    """What every training stage shares: the MLflow run and its params, best and last
    checkpoints, the trainer (DDP when it has several devices or Ray Train workers), resume, the
    NaN stop, an exponential moving average of the weights (``trainer.ema``), snapshots at chosen
    steps (``trainer.snapshots``), compiled training steps (``trainer.compile``), and reloading
    the best weights."""
    import lightning.pytorch as pl
    from lightning.pytorch.callbacks import EMAWeightAveraging, LearningRateMonitor, ModelCheckpoint

    from m2d2m.progress import on_terminal
    from training.callbacks import PlainProgress, StepProgressBar, StepSnapshots
    from training.losses import NonFiniteLossError

    config, run_dir = run.config, run.run_dir
    trainer_cfg = config["trainer"]
    if trainer_cfg.get("ema"):
        # validation, checkpoints (best, last, snapshots) and so the model file see the averaged weights
        callbacks = [*callbacks, EMAWeightAveraging(decay=trainer_cfg["ema"], use_buffers=False)]
    if trainer_cfg.get("snapshots"):
        callbacks = [*callbacks, StepSnapshots(run_dir / SNAPSHOTS, trainer_cfg["snapshots"])]
    module.compile_steps = compile_setting(trainer_cfg["compile"])
    logger = _mlflow_logger(config["dataset"], run.stage, run_dir, run.run_id)
    checkpoints = ModelCheckpoint(
        dirpath=run_dir / "checkpoints", filename="best", monitor=monitor, mode="min", save_last=True, save_top_k=1
    )
    trainer = pl.Trainer(
        **_placement(trainer_cfg, ray_train),
        max_steps=trainer_cfg["max_steps"],
        precision=lightning_precision(trainer_cfg["precision"]),
        logger=logger,
        # a bar on a terminal; plain lines in a log, where a bar's redraws show nothing or garbage
        callbacks=[checkpoints, LearningRateMonitor(logging_interval="step"), *callbacks]
        + [StepProgressBar() if on_terminal() else PlainProgress()],
        enable_progress_bar=on_terminal(),
        gradient_clip_val=config["optim"]["grad_clip"],
        limit_val_batches=trainer_cfg["val_batches"],
        log_every_n_steps=min(50, validation_interval(trainer_cfg)),
        default_root_dir=run_dir,
        num_sanity_val_steps=0,
    )
    if ray_train:
        from ray.train.lightning import prepare_trainer

        trainer = prepare_trainer(trainer)
    fitted = _Fitted(trainer, checkpoints, logger, run_dir / "checkpoints" / "last.ckpt")
    if fitted.primary:
        write_run_info(run_dir, mlflow_run_id=logger.run_id, world_size=trainer.world_size)
        if run.run_id is None:
            logger.log_hyperparams({**flatten(config), "world_size": trainer.world_size})
    resume_from = fitted.last if run.resume and fitted.last.exists() else None
    if run.resume and resume_from is None and fitted.primary:
        print(f"{run_dir} has no checkpoint yet: it trains again from step 0", file=sys.stderr)
    try:
        with _joinable(run_dir):
            trainer.fit(module, datamodule=datamodule, ckpt_path=resume_from)
    except SystemExit as error:
        if not trainer.interrupted:
            raise
        # Lightning ends a Ctrl-C inside fit with exit(1) after its own shutdown, and ignores SIGINT
        # from then on (lightning/pytorch/trainer/call.py): give the command its Ctrl-C back, so the
        # run is recorded interrupted and the command exits 130 (orchestration/cli/__init__.py)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        raise KeyboardInterrupt from error
    except NonFiniteLossError as error:
        if fitted.primary:
            write_run_info(run_dir, status="failed", error=str(error))
        raise UserError(
            f"{error}; training stopped. The last good checkpoint is {fitted.last} "
            "(lower optim.lr or set optim.grad_clip, then start a new run)"
        ) from error
    if fitted.primary:
        best = torch.load(checkpoints.best_model_path, map_location="cpu", weights_only=True)
        module.load_state_dict(best["state_dict"])
    return fitted


def export_snapshots(run_dir: Path, module, save: Callable[[Path], Path]) -> list[Path]:
    """Each snapshot of the run (``trainer.snapshots``: the weights after those steps) written by
    ``save(path)`` as ``snapshots/model-step<N>.pt`` beside its checkpoint, from the module's own
    weights replaced by the snapshot's; call it after the run's model file is written. Only the
    snapshots whose seconds were recorded count (a snapshot cut short by a kill is not)."""
    from training.callbacks import StepSnapshots

    directory = run_dir / SNAPSHOTS
    steps = sorted(int(step) for step in StepSnapshots.recorded(directory))
    written = []
    for step in steps:
        snapshot = torch.load(directory / f"step-{step}.ckpt", map_location="cpu", weights_only=True)
        module.load_state_dict(snapshot["state_dict"])
        written.append(save(directory / f"model-step{step}.pt"))
    return written


def finish(run_dir: Path, fitted: _Fitted, artifacts: list[Path], **info: Any) -> None:
    """Log the run's files to MLflow, record its final validation metrics, mark it ``latest``."""
    for path in artifacts:
        fitted.logger.experiment.log_artifact(fitted.logger.run_id, str(path), artifact_path="model")
    final = {name: float(value) for name, value in fitted.trainer.callback_metrics.items() if name.startswith("val/")}
    write_run_info(run_dir, status="finished", final_validation=final, **info)
    mark_latest(run_dir)
