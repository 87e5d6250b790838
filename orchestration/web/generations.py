"""The server's generations by id: each one a generate run folder (``runs/<dataset>/generate/<id>/``,
as `m2d2m generate` writes) and an MLflow run, its files downloaded by id and name.

The joints ``.npy`` with its JSON sidecar, the features and the BVH are written with the motion;
the GIF and MP4 take seconds to draw, so each is drawn when it is first asked for and then added
to the run's artifacts. Only names from :data:`FILES` are served, looked up among the files of a
generation this server made: no request value becomes a path.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.motion.clip import Motion
from m2d2m.motion.files.formats import FORMATS, on_rig, spoken
from m2d2m.motion.representation.pose import REST_POSES
from m2d2m.motion.transforms.delivery import Delivery
from orchestration.errors import UserError
from orchestration.generate import GENERATE_STAGE, Output, save_generation
from orchestration.runs import write_run_info
from orchestration.tracking import client, ensure_experiment, experiment_name, tracking_uri, ui_runs_page
from orchestration.web.catalog import NotFound
from orchestration.web.rigs import UploadedRig

STEM = "motion"
WRITTEN = tuple(kind for kind, fmt in FORMATS.items() if not fmt.slow)  # with the motion; the rest when first asked for
# a generation's files: the key of each in the API's answer → its suffix and the format that makes
# it (a format's companions, such as the npy's sidecar, come with it). Listed as a person takes them:
# the files for a rig and an engine, then the data, then the drawings
FILE_KINDS = {
    key: (suffix, fmt.suffix)
    for fmt in sorted(FORMATS.values(), key=lambda fmt: (not fmt.on_rig, fmt.animation))
    for key, suffix in {fmt.suffix: fmt.suffix, **fmt.companions}.items()
}
FILES = {f"{STEM}.{suffix}": made_by for suffix, made_by in FILE_KINDS.values()}  # the names served


@dataclass
class Generation:
    """One served generation: the motion, where its files are, how it was made."""

    id: str
    directory: Path
    motion: Motion
    model: str
    run: str
    seed: int
    describe: str
    mlflow_run_id: str | None
    experiment_id: str | None
    delivery: Delivery = Delivery()
    drawing: threading.Lock = field(default_factory=threading.Lock)


def mlflow_ui_base(given: str | None) -> str | None:
    """Where a person opens an MLflow run: ``given``, else the tracking server when there is one,
    else `make ui`'s address."""
    if given is not None:
        return given.rstrip("/") or None
    uri = tracking_uri()
    return uri.rstrip("/") if uri.startswith("http") else "http://127.0.0.1:5000"


class Generations:
    """The generations this server made, the newest ``capacity`` kept for download (older ones stay
    in their run folders and in MLflow)."""

    def __init__(self, dataset: str, track: bool = True, capacity: int = 1000, mlflow_ui: str | None = None) -> None:
        self.dataset = dataset
        self.track = track
        self.capacity = capacity
        self.mlflow_ui = mlflow_ui_base(mlflow_ui) if track else None
        self._kept: OrderedDict[str, Generation] = OrderedDict()
        self._lock = threading.Lock()
        self._experiment_id: str | None = None

    def record(
        self,
        motion: Motion,
        prompts: Sequence[str],
        model: str,
        run: str,
        seed: int,
        describe: str,
        delivery: Delivery = Delivery(),
    ) -> Generation:
        """Write the (delivered) motion's files into a new generate run and log it to MLflow (a
        blocking call)."""
        output = Output(None, STEM, WRITTEN, delivery)
        files, mlflow_run_id = save_generation(motion, output, prompts, self.dataset, self.track)
        directory = files["npy"].parent
        if mlflow_run_id is not None and self._experiment_id is None:
            self._experiment_id = ensure_experiment(experiment_name(self.dataset, GENERATE_STAGE))
        generation = Generation(
            directory.name, directory, motion, model, run, seed, describe, mlflow_run_id, self._experiment_id, delivery
        )
        with self._lock:
            self._kept[generation.id] = generation
            while len(self._kept) > self.capacity:
                self._kept.popitem(last=False)
        return generation

    def get(self, generation_id: str) -> Generation:
        with self._lock:
            if generation_id not in self._kept:
                raise NotFound(f"no generation {generation_id!r} on this server")
            return self._kept[generation_id]

    def file(
        self, generation_id: str, name: str, rest_pose: str = REST_POSES[0], rig: UploadedRig | None = None
    ) -> Path:
        """The path of file ``name`` (one of :data:`FILES`) of a generation; an animation, a file of
        a format a rig takes (BVH, GLB, FBX) on another bind pose (``rest_pose``) or on an uploaded
        ``rig`` (read once, when it was uploaded), is made on first request (a blocking call) and
        logged to the generation's MLflow run."""
        generation = self.get(generation_id)
        if name not in FILES:
            raise NotFound(f"no file {name!r}; a generation has {', '.join(FILES)}")
        if rest_pose not in REST_POSES:
            raise UserError(f"rest must be one of {', '.join(REST_POSES)}, got {rest_pose!r}")
        kind = FILES[name]
        if rig is not None and not FORMATS[kind].on_rig:
            raise UserError(f"a rig goes with the {spoken(on_rig())}, not {name}")
        delivery = replace(generation.delivery, rest_pose=rest_pose)
        # a skeleton's file (one a rig takes) is on the bind pose asked; the others have none
        variant = f"rig-{rig.id}" if rig is not None else rest_pose if FORMATS[kind].on_rig else REST_POSES[0]
        stem = STEM if variant == REST_POSES[0] else f"{STEM}.{variant}"
        path = generation.directory / (name if stem == STEM else f"{stem}.{kind}")
        if kind not in WRITTEN or stem != STEM:  # not written with the motion: made on first request
            with generation.drawing:
                if not path.exists():
                    self._make(generation, kind, stem, delivery, variant, rig)
        if not path.is_file():
            raise NotFound(f"generation {generation_id} has no {name} any more (its run folder was changed)")
        return path

    def _make(
        self, generation: Generation, kind: str, stem: str, delivery: Delivery, variant: str, rig: UploadedRig | None
    ) -> None:
        """Write a file of the generation after the fact (on ``rig``: a BVH, GLB or FBX), name it in its run's
        record and log it to its MLflow run."""
        from orchestration.generate import plan_output

        plan_output(None, stem, [kind])  # MP4 and FBX need their tools: a one-line error when there are none
        motion = generation.motion
        try:
            if rig is not None:
                path = motion.save_on_rig(generation.directory / f"{stem}.{kind}", kind, rig.target)
            else:
                (path,) = motion.save(generation.directory, stem, (kind,), delivery=delivery).values()
        except (OSError, RuntimeError, ValueError) as error:  # Blender failed, or a rig it cannot take
            raise UserError(str(error)) from error
        record = kind if stem == STEM else f"{kind}_{variant}"
        write_run_info(generation.directory, **{f"file_{record}": str(path)})
        if generation.mlflow_run_id is not None:
            client().log_artifact(generation.mlflow_run_id, str(path), artifact_path="motion")

    def describe(self, generation: Generation) -> dict[str, Any]:
        """The API's answer for a generation: the joints, the actions, the files' URLs, the run."""
        motion = generation.motion
        url = f"/api/generations/{generation.id}"
        return {
            "id": generation.id,
            "model": generation.model,
            "run": generation.run,
            "method": motion.settings.get("method"),
            "seed": generation.seed,
            "describe": generation.describe,
            "settings": {key: _plain(value) for key, value in motion.settings.items()},
            "fps": motion.fps,
            "skeleton": motion.skeleton_name,
            "parents": [int(parent) for parent in motion.skeleton.parents],
            "left_joints": list(motion.skeleton.left_joints),
            "right_joints": list(motion.skeleton.right_joints),
            "head_joint": motion.skeleton.head_joint,
            # 10 µm steps: far below what a body shows, a third of the bytes; the .npy is exact
            "joints": motion.joints.astype(np.float64).round(5).tolist(),
            "actions": [{"text": text, "first": first, "end": end} for first, end, text in motion.segments],
            "boundaries": motion.boundaries,
            "seconds": motion.seconds,
            "quality": motion.quality,
            "files": {
                key: f"{url}/{STEM}.{suffix}"
                for key, (suffix, made_by) in FILE_KINDS.items()
                if _offered(generation, suffix, made_by)
            },
            "on_rig": [fmt.suffix for fmt in on_rig()],  # the files ?rig=<id> gives on an uploaded rig
            "mlflow": {
                "run_id": generation.mlflow_run_id,
                "experiment": experiment_name(self.dataset, GENERATE_STAGE),
                "url": (
                    ui_runs_page(self.mlflow_ui, generation.experiment_id, generation.mlflow_run_id)
                    if self.mlflow_ui and generation.mlflow_run_id
                    else None
                ),
            },
        }


def _offered(generation: Generation, suffix: str, made_by: str) -> bool:
    """Whether a generation's answer lists its file of ``suffix``: a format's when this machine can
    make it (FBX needs Blender, MP4 ffmpeg), a companion (the npy's sidecar, features, an in-place
    clip's root track) when its format wrote one."""
    if suffix == made_by:
        return FORMATS[made_by].lacking() is None
    return (generation.directory / f"{STEM}.{suffix}").is_file()


def _plain(value: Any) -> Any:
    """A settings value as JSON has it (a NumPy number or a tuple as Python's own, a mapping such
    as the ``delivery`` as an object, not its Python repr)."""
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, Mapping):
        return {str(key): _plain(item) for key, item in value.items()}
    return value.item() if hasattr(value, "item") else str(value)
