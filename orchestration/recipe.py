"""One training recipe for every model file the project trains: :func:`run_recipe` does what all of
them share (the run directory and MLflow run, the settings check, seeding, the trainer with its
checkpoints, DDP and resume, the model file, its snapshots and the run's record); a
:class:`Recipe` says only how its config becomes data, a LightningModule and a model file
(docs/architecture.md, "How to add a model"). The registered generators' recipes are named by
their :class:`~orchestration.registry.ModelEntry`; the VQ-VAE's and the evaluator's
(:mod:`orchestration.recipes.vq`, :mod:`orchestration.recipes.evaluator`) by a :class:`Trainable`
of their own."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from m2d2m.layout import relative_to_project
from m2d2m.model_files import LengthPrior, ModelFileKind
from m2d2m.plugins import plugins_for_workers
from orchestration.errors import UserError
from orchestration.registry import ModelEntry, load_plugins, model
from orchestration.runs import enter_project, read_run_info
from orchestration.tracking import tracking_uri
from orchestration.train import OpenedRun, export_snapshots, finish, fit, open_run, records_failure, validation_interval


@dataclass
class TrainingData:
    """The data side of a run: its DataModule, the processed dataset it reads and the vocabulary of
    a learned text encoder (None for CLIP)."""

    datamodule: Any
    data_dir: Path
    vocabulary: list[str] | None

    @property
    def frames_per_unit(self) -> int:
        """The frames one unit of the model's sequences holds, the length prior's unit: 1 for a
        model on features, a token's frames for a model over tokens."""
        return 1

    @functools.cached_property
    def lengths(self) -> LengthPrior:
        """The length prior of the training captions (read once, for the model file and its snapshots)."""
        from training.data.tokens import length_prior

        return length_prior(self.datamodule.urls("train"), self.frames_per_unit)

    def records(self) -> dict[str, str]:
        """Where the run's inputs are, for its ``run.json`` and its model file's ``extra``."""
        return {"data": relative_to_project(self.data_dir)}

    def model_parts(self) -> dict[str, Any]:
        """The model file's parts that come from the data (the module gives its networks)."""
        return {"lengths": self.lengths}


class Recipe:
    """What one model's training differs in. Subclasses give :meth:`data`, :meth:`module` and
    their model file's ``model_format``; the rest have defaults that most models keep."""

    monitor = "val/loss"  # the validation metric whose minimum is the run's best checkpoint
    model_format: ClassVar[ModelFileKind]  # the kind of file a finished run holds
    optional: ClassVar[frozenset[str]] = frozenset()  # dotted keys a config may leave out (beside text's)

    @classmethod
    def optional_keys(cls) -> frozenset[str]:
        """The dotted keys this model's configs may leave out: its own and the text encoder's options."""
        from m2d2m.text import option_names

        return cls.optional | {f"text.{name}" for name in option_names()}

    @classmethod
    def load_config(cls, entry: ModelEntry, config_name: str) -> dict[str, Any]:
        """``configs/<model>/<config_name>.yaml`` (or a path) read and checked as this model's runs read it."""
        from orchestration.config import load_config
        from orchestration.train import TRAINING_DEFAULTS

        return load_config(entry.configs, config_name, [], TRAINING_DEFAULTS, cls.optional_keys())

    def prepare(self, config: dict[str, Any]) -> None:
        """What must exist before trials train in parallel (made once by a sweep's driver)."""

    def check(self, config: dict[str, Any]) -> None:
        """Refuse (ValueError) a setting this model cannot use, before any training."""

    def data(self, config: dict[str, Any]) -> TrainingData:
        """The run's data; FileNotFoundError or ValueError become one-line errors."""
        raise NotImplementedError

    def module(self, config: dict[str, Any], data: TrainingData) -> Any:
        """The LightningModule, built after seeding."""
        raise NotImplementedError

    def stage(self, stage: str, config: dict[str, Any]) -> str:
        """The stage a run of ``config`` is filed under: the trainable's own, unless the config says
        otherwise (a part tokenizer's ``vq-upper``)."""
        return stage

    def callbacks(self, run: OpenedRun, data: TrainingData) -> list:
        """The model's own trainer callbacks (sample previews, for instance)."""
        return []

    def artifacts(self, data: TrainingData) -> list[Path]:
        """Files the run's MLflow record keeps beside the model file and checkpoints."""
        return []

    def parts(self, config: dict[str, Any], data: TrainingData) -> dict[str, Any]:
        """The model file's parts beside the module's networks: the data's, and the config's own."""
        return data.model_parts()

    def save(self, path: Path, module: Any, config: dict[str, Any], data: TrainingData, extra: dict[str, Any]) -> Path:
        """Write the model file at ``path``: the module's networks as they are now
        (``module.model_parts()``), :meth:`parts`, and ``extra`` (where the run and its inputs are)."""
        return self.model_format.save(path, **module.model_parts(), **self.parts(config, data), extra=extra)


@dataclass(frozen=True)
class Trainable:
    """What :func:`run_recipe` trains: a recipe, the stage its runs are filed under
    (``runs/<dataset>/<stage>/``, an MLflow experiment), its configs (``configs/<configs>/``) and
    the model file a finished run holds."""

    stage: str
    configs: str
    model_file: str
    recipe: Recipe

    @classmethod
    def of_model(cls, entry: ModelEntry) -> Trainable:
        """A registered model's training."""
        return cls(entry.stage, entry.configs, entry.model_file, entry.load("recipe"))

    def stage_of(self, config: dict[str, Any]) -> str:
        """The stage a run of ``config`` is filed under (:meth:`Recipe.stage`)."""
        return self.recipe.stage(self.stage, config)


def caption_vocabulary(
    config: dict[str, Any], datamodule: Any, sentences: Callable[[dict[str, Any]], Iterable[str]]
) -> list[str] | None:
    """The words of a learned text encoder: those of ``sentences(caption)`` over the train captions
    (None when the config's text encoder is not a learned one)."""
    from m2d2m.text import LearnedTextEncoder
    from training.data.shards import clip_metas

    if config["text"]["kind"] != "learned":
        return None
    return LearnedTextEncoder.build_vocabulary(
        text
        for meta in clip_metas(datamodule.urls("train"))
        for caption in meta["captions"]
        for text in sentences(caption)
    )


def run_recipe(
    trainable: Trainable,
    config_name: str = "demo",
    overrides: list[str] | None = None,
    resume: bool | str = False,
    extra_callbacks: list | None = None,
    join: Path | None = None,
    ray_train: bool = False,
) -> Path:
    """Train with ``trainable``'s recipe; returns the run directory (with the model file on
    success). ``join``: a run another process opened (its config is used, ``config_name`` and
    ``overrides`` are not); ``ray_train``: this process is a Ray Train worker; ``extra_callbacks``
    join the trainer's (a sweep's reporting callback, a test's kill switch)."""
    import lightning.pytorch as pl

    recipe = trainable.recipe
    run = open_run(
        trainable.stage_of,
        trainable.configs,
        config_name,
        overrides or [],
        resume,
        join,
        recipe.optional_keys(),
        recipe.check,  # before the run exists, and before hours of training, not at their end
    )
    config = run.config
    try:
        data = recipe.data(config)
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = recipe.module(config, data)
    fitted = fit(
        run,
        module,
        data.datamodule,
        recipe.monitor,
        [*recipe.callbacks(run, data), *(extra_callbacks or [])],
        ray_train=ray_train,
    )
    if not fitted.primary:
        return run.run_dir
    extra = {
        "run": run.run_dir.name,
        "mlflow_run_id": fitted.logger.run_id,
        "dataset": config["dataset"],
        "data_dir": relative_to_project(data.data_dir),
        **data.records(),
        f"best_{recipe.monitor.replace('/', '_')}": float(fitted.checkpoints.best_model_score),
    }
    model_file = run.run_dir / trainable.model_file
    recipe.save(model_file, module, config, data, extra)
    export_snapshots(run.run_dir, module, lambda path: recipe.save(path, module, config, data, extra))
    finish(
        run.run_dir,
        fitted,
        [
            model_file,
            Path(fitted.checkpoints.best_model_path),
            fitted.last,
            run.run_dir / "config.yaml",
            *recipe.artifacts(data),
        ],
        model=relative_to_project(model_file),
        **data.records(),
    )
    return run.run_dir


@records_failure
def train(
    what: Trainable | str,
    config_name: str = "demo",
    overrides: list[str] | None = None,
    resume: bool | str = False,
    extra_callbacks: list | None = None,
) -> Path:
    """A training command (``m2d2m train-vq``, ``train-diffusion``, ...): :func:`run_recipe` of
    ``what`` (a :class:`Trainable`, or the name of a registered model) in this process, the run
    recorded failed or interrupted when it raises; returns the run directory."""
    trainable = Trainable.of_model(model(what)) if isinstance(what, str) else what
    return run_recipe(trainable, config_name, overrides, resume, extra_callbacks)


def caption_motion_data(config: dict[str, Any], bucket: bool) -> Any:
    """The caption/motion pairs of a run's dataset as Guo et al.'s loader draws them (a random
    caption per clip, its segment, cut to a multiple of 4 frames): the evaluator's data and
    MotionDiffuse's. ``bucket``: batches of similar lengths unless ``data.bucket`` says otherwise."""
    from training.evaluator_module import CaptionMotionDataModule

    data = config["data"]
    return CaptionMotionDataModule(
        data["dir"],
        batch_size=data["batch_size"],
        num_workers=data["num_workers"],
        steps_per_epoch=validation_interval(config["trainer"]),
        min_frames=data["min_frames"],
        max_frames=data["max_frames"],
        seed=config["seed"],
        bucket=data.get("bucket", bucket),
    )


def train_on_workers(
    name: str,
    config_name: str,
    overrides: list[str],
    workers: int,
    use_gpu: bool,
    cpus_per_worker: float,
    storage: Path,
) -> Path:
    """A registered model trained in DDP by ``workers`` Ray Train workers, one device each (the
    GPUs of one node or of several); returns the run directory, whose files rank 0 wrote.
    ``storage``, where Ray Train keeps its state, and the project directory must be seen by every
    node alike."""
    from ray.train import RunConfig, ScalingConfig
    from ray.train.torch import TorchTrainer

    trainable = Trainable.of_model(model(name))
    run_dir = open_run(
        trainable.stage_of,
        trainable.configs,
        config_name,
        overrides,
        resume=False,
        optional=trainable.recipe.optional_keys(),
    ).run_dir
    trainer = TorchTrainer(
        _ray_train_worker,
        train_loop_config={
            "project": str(Path.cwd().resolve()),
            "run_dir": str(run_dir.resolve()),
            "tracking_uri": tracking_uri(),
            "cpus": cpus_per_worker,
            "model": name,
            "plugins": plugins_for_workers(),
        },
        scaling_config=ScalingConfig(
            num_workers=workers, use_gpu=use_gpu, resources_per_worker={"CPU": cpus_per_worker}
        ),
        run_config=RunConfig(name=f"{trainable.stage}-{run_dir.name}", storage_path=str(storage.resolve())),
    )
    trainer.fit()
    if read_run_info(run_dir).get("status") != "finished":
        raise UserError(f"{run_dir}: the Ray Train workers stopped before rank 0 finished the run")
    return run_dir


def _ray_train_worker(config: dict[str, Any]) -> None:
    """One Ray Train worker: joins the run in the project directory and trains its DDP rank."""
    enter_project(config["project"], config["tracking_uri"], config["cpus"])
    load_plugins(**config["plugins"])
    run_recipe(Trainable.of_model(model(config["model"])), join=Path(config["run_dir"]), ray_train=True)
