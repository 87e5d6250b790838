"""Load a motion for looking at, exporting or editing: a ``.npy`` of joints or features (with what
its JSON sidecar says, when it has one: docs/generation.md, "Output files"), or a clip of a raw
corpus in HumanML3D's layout (with its captions and, for the synthetic corpus, its actions)."""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2d2m.motion.files.sidecar import Sidecar, SidecarError, sidecar_path
from m2d2m.motion.representation.features import features_to_joints, joints_to_features
from m2d2m.motion.representation.skeleton import SKELETONS, Skeleton
from m2d2m.motion.transforms.retime import check_fps, resample
from orchestration.errors import UserError


@dataclass
class LoadedMotion:
    joints: np.ndarray
    skeleton: Skeleton
    segments: list[tuple[int, int, str]]
    caption: str | None
    fps: float | None = None  # the frame rate its sidecar states (none: the skeleton's)
    loop: bool = False  # one cycle of a loop, as its sidecar says


def _check_values(array: np.ndarray, origin: str) -> None:
    """What no drawing or BVH can be made of: no frames, or values that are not finite numbers
    (a NaN would otherwise surface as a traceback deep in the renderer or the exporter)."""
    if not np.issubdtype(array.dtype, np.number):
        raise UserError(f"{origin}: holds {array.dtype} values, not numbers")
    if array.ndim >= 1 and len(array) == 0:
        raise UserError(f"{origin}: shape {array.shape} has no frames")
    bad = np.size(array) - np.count_nonzero(np.isfinite(array))
    if bad:
        raise UserError(f"{origin}: {bad} NaN or infinite value(s); the motion cannot be drawn or exported")


# a body whose legs are this many times (or this fraction of) the skeleton's own is in other units
SCALE_LIMITS = (0.2, 5.0)
# no joint of a body stands this many metres from its root, nor its root this high (HumanML3D's
# clip 012314's within ±1.95): features placing one further are another kind of array, or another
# unit. Rotations and velocities are not bounded: an arithmetic on them stays finite
FEATURE_LIMIT_M = 100.0


def _check_body(joints: np.ndarray, skeleton: Skeleton, origin: str) -> np.ndarray:
    """``joints`` if they are a body in the skeleton's units: a bone of no length (joints collapsed
    onto one point) would export a BVH of NaN rotations, and a body in centimetres a 160 m figure."""
    lengths = skeleton.bone_lengths_of(joints.astype(np.float64)).mean(axis=0)
    collapsed = [skeleton.joint_names[j] for j in skeleton.bones if lengths[j] <= 1e-3 * skeleton.bone_lengths[j]]
    if collapsed:
        raise UserError(
            f"{origin}: the bone{'s' if len(collapsed) > 1 else ''} to {', '.join(collapsed[:4])}"
            f"{' …' if len(collapsed) > 4 else ''} {'have' if len(collapsed) > 1 else 'has'} no length "
            "(joints on one point): not a body to draw or export"
        )
    scale = skeleton.leg_length(lengths) / skeleton.leg_length(skeleton.bone_lengths)
    if not SCALE_LIMITS[0] <= scale <= SCALE_LIMITS[1]:
        unit = "metres" if skeleton.metres_per_unit == 1.0 else f"units of {skeleton.metres_per_unit:g} m"
        raise UserError(
            f"{origin}: the body is {scale:.3g}× the size of the {skeleton.name} skeleton's (legs "
            f"{skeleton.leg_length(lengths):.3g} against {skeleton.leg_length(skeleton.bone_lengths):.3g}): "
            f"give its joints in {unit}"
        )
    return joints


def _as_joints(array: np.ndarray, skeleton: Skeleton, origin: str) -> np.ndarray:
    _check_values(array, origin)
    if array.ndim == 3 and array.shape[1:] == (skeleton.num_joints, 3):
        return _check_body(array.astype(np.float32), skeleton, origin)
    if array.ndim == 2 and array.shape[1] == skeleton.feature_dim:
        return _check_body(features_to_joints(array.astype(np.float32), skeleton), skeleton, origin)
    raise UserError(
        f"{origin}: shape {array.shape} is neither joints (T, {skeleton.num_joints}, 3) nor "
        f"{skeleton.feature_dim}-d features of skeleton {skeleton.name!r} (see --skeleton)"
    )


def load_features(
    source: str | Path | bytes, skeleton: Skeleton, origin: str = "", fps: float | None = None, given: bool = True
) -> np.ndarray:
    """Float32 features (T, D) of ``skeleton``, at its frame rate, from a ``.npy`` of features (the
    ``.features.npy`` that ``m2d2m generate`` writes, a corpus's ``new_joint_vecs`` clip) or of
    joints (T, J, 3), which HumanML3D's processing turns into features (one frame fewer): the
    motion an edit starts from. ``source``: the file, or its bytes (an upload, named ``origin`` in
    errors); ``fps``: the rate it was made at (None: the skeleton's), resampled to the skeleton's.
    What is no body (no frames, values that are no numbers, bones of no length, a body of another
    size, features no body has) is one line before any arithmetic is done on it, in a motion
    ``given`` (uploaded, or a file of joints); a model's own features, which an undertrained
    model may make far from any body (the tests' 10-step MotionDiffuse: legs of 143 m), are
    checked only for numbers, and are edited as they are."""
    if isinstance(source, bytes):
        array = _load_npy(io.BytesIO(source), origin)
    else:
        path = Path(source)
        if not path.is_file():
            raise UserError(f"{path}: no such file; give a .npy of features or joints")
        array, origin = _load_npy(path, str(path)), str(path)
    _check_values(array, origin)
    try:
        rate = skeleton.fps if fps is None else check_fps(fps)
    except ValueError as error:
        raise UserError(f"{origin}: {error}") from error
    if array.ndim == 2 and array.shape[1] == skeleton.feature_dim:
        features = array.astype(np.float32)
        if not given:
            if rate != skeleton.fps:
                raise UserError(f"{origin}: a model's features are at its {skeleton.fps:g} fps, not {rate:g}")
            return features
        positions = features[:, 3 : 4 + 3 * (skeleton.num_joints - 1)]  # root height, joints around the root
        largest, limit = float(np.abs(positions).max()), FEATURE_LIMIT_M / skeleton.metres_per_unit
        if largest > limit:
            raise UserError(
                f"{origin}: places a joint {largest:.3g} units from its root or the floor, which no body's "
                f"features do (they stay within ±{limit:g}, {FEATURE_LIMIT_M:g} m): not features of a motion"
            )
        joints = _check_body(features_to_joints(features, skeleton), skeleton, origin)
        if rate == skeleton.fps:
            return features
    elif array.ndim == 3 and array.shape[1:] == (skeleton.num_joints, 3):
        joints = _check_body(array.astype(np.float32), skeleton, origin)
    else:
        raise UserError(
            f"{origin}: shape {array.shape} is neither {skeleton.feature_dim}-d features nor joints "
            f"(T >= 2, {skeleton.num_joints}, 3) of the model's skeleton {skeleton.name!r}"
        )
    if rate != skeleton.fps:
        joints = resample(joints, skeleton, rate, skeleton.fps)
    if len(joints) < 2:  # velocities need two frames
        raise UserError(f"{origin}: {len(joints)} frame at {skeleton.fps:g} fps; a motion needs at least two")
    with np.errstate(invalid="ignore", divide="ignore"):  # said below, once, in words
        features = joints_to_features(joints, skeleton)
    if not np.isfinite(features).all():
        raise UserError(
            f"{origin}: these joints give no finite features: HumanML3D's processing needs a body whose "
            "hips and shoulders show which way it faces"
        )
    return features


def _load_npy(source: Path | io.BytesIO, origin: str) -> np.ndarray:
    try:
        loaded = np.load(source, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:  # EOFError: an empty file
        raise UserError(f"{origin}: not a readable .npy file ({error or type(error).__name__})") from error
    if not isinstance(loaded, np.ndarray):  # a zip archive: an .npz, or a torch model file
        loaded.close()
        raise UserError(f"{origin}: an archive (.npz, or a model file), not one .npy array of a motion")
    return loaded


def _first_caption(text_file: Path) -> str | None:
    if not text_file.exists():
        return None
    lines = text_file.read_text(encoding="utf-8", errors="replace").splitlines()
    return lines[0].split("#", 1)[0].strip() if lines else None


def _segments_of(corpus: Path, clip_id: str) -> list[tuple[int, int, str]]:
    """Action segments from the synthetic corpus's annotations (other corpora have none)."""
    annotations = corpus / "annotations.jsonl"
    if not annotations.exists():
        return []
    with annotations.open(encoding="utf-8") as lines:
        for line in lines:
            record = json.loads(line)
            if record["id"] == clip_id:
                return [(a["start"], a["end"], a["text"]) for a in record["actions"]]
    return []


def read_sidecar(npy: Path) -> Sidecar | None:
    """The sidecar beside ``npy`` (:mod:`m2d2m.motion.files.sidecar`; none: a file without one); one line
    when it is not one."""
    try:
        return Sidecar.read(npy)
    except SidecarError as error:
        raise UserError(str(error)) from error


def _from_npy(path: Path, skeleton: str | None) -> LoadedMotion:
    """A ``.npy`` of joints or features; its sidecar, when there is one, gives the skeleton (unless
    ``skeleton`` names one), the frame rate, the actions and, for an in-place clip, the root motion
    taken out, put back so that the clip is what was generated."""
    array = _load_npy(path, str(path))
    sidecar = read_sidecar(path) if array.ndim == 3 else None
    if sidecar is not None and sidecar.num_frames != len(array):
        raise UserError(
            f"{sidecar_path(path)}: states {sidecar.num_frames} frames, {path.name} has {len(array)}; "
            "it belongs to another file"
        )
    name = skeleton or (sidecar.skeleton if sidecar is not None else "t2m")
    if name not in SKELETONS:
        raise UserError(f"unknown skeleton {name!r}; choose one of {', '.join(SKELETONS)}")
    skel = SKELETONS[name]
    joints = _as_joints(array, skel, str(path))
    if sidecar is None:
        return LoadedMotion(joints, skel, [], None)
    if sidecar.root_motion is not None:
        track_file = path.parent / sidecar.root_motion
        track = _load_npy(track_file, str(track_file))
        if track.shape != (len(joints), 3):
            raise UserError(f"{track_file}: shape {track.shape}, expected ({len(joints)}, 3)")
        joints = joints + track[:, None, :].astype(np.float32)
    return LoadedMotion(joints, skel, list(sidecar.segments), None, sidecar.fps, sidecar.loop)


def load_motion(source: str | Path, clip_id: str | None = None, skeleton: str | None = None) -> LoadedMotion:
    """Joints and captions of ``source``: a ``.npy`` file, or a corpus directory with ``clip_id``
    (skeleton: t2m unless named, or stated by a .npy's sidecar)."""
    if skeleton is not None and skeleton not in SKELETONS:
        raise UserError(f"unknown skeleton {skeleton!r}; choose one of {', '.join(SKELETONS)}")
    path = Path(source)
    if not path.exists():
        raise UserError(f"{path}: no such file or directory")
    if path.is_file():
        return _from_npy(path, skeleton)
    skel = SKELETONS[skeleton or "t2m"]
    if clip_id is None:
        raise UserError(f"{path} is a directory: name the clip with --id (e.g. --id 000000)")
    for folder in ("joints", "new_joint_vecs"):
        clip = path / folder / f"{clip_id}.npy"
        if clip.exists():
            joints = _as_joints(_load_npy(clip, str(clip)), skel, str(clip))
            return LoadedMotion(
                joints, skel, _segments_of(path, clip_id), _first_caption(path / "texts" / f"{clip_id}.txt")
            )
    raise UserError(f"{path}: no clip {clip_id!r} under joints/ or new_joint_vecs/")
