"""Characters' rigs a person uploads to the server, to download generations retargeted onto them
(issue 40 §2, §5; docs/serving.md): each a BVH file (its hierarchy and OFFSETs) or a GLB
character (its skin's skeleton as it stands), kept by the hash of its bytes, with the joint map
its joints take, checked on upload so that a download never fails on the rig."""

from __future__ import annotations

import hashlib
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2d2m.atomic import atomic_path
from m2d2m.motion.bvh_reader import BvhError
from m2d2m.motion.joint_map import PRESETS, joint_map_for
from m2d2m.motion.retarget import Rig, read_rig, retarget, rig_metres_per_unit
from m2d2m.motion.skeleton import T2M
from orchestration.errors import UserError
from orchestration.web.catalog import NotFound

RIGS_STAGE = "rigs"  # runs/<dataset>/rigs/: the uploaded rigs
MAX_RIG_BYTES = 20 * 2**20  # a rig's hierarchy is kilobytes; a long take written as a rig is still well under this


@dataclass(frozen=True)
class UploadedRig:
    """A rig on the server: its file, its joints' count and the joint map that reads them."""

    id: str
    path: Path
    joints: int
    joint_map: str


class Rigs:
    """The rigs uploaded to this server, in ``folder`` (one ``<id>.bvh`` or ``<id>.glb`` each)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._kept: dict[str, UploadedRig] = {}
        self._lock = threading.Lock()

    def add(self, data: bytes, joint_map: str | None = None) -> UploadedRig:
        """Check a BVH's or GLB's bytes (told apart by GLB's magic, §4.4.2 of the glTF 2.0
        specification) as a rig our motions go onto (a UserError in one sentence when they cannot)
        and keep it; the same bytes and map give the same rig."""
        if not data:
            raise UserError("the rig is empty: send the bytes of a BVH or GLB file")
        if len(data) > MAX_RIG_BYTES:
            raise UserError(
                f"the rig is {len(data) / 2**20:.0f} MiB, over the {MAX_RIG_BYTES // 2**20} MiB a rig may be"
            )
        if joint_map is not None and joint_map not in PRESETS:
            raise UserError(f"joint_map must be one of {', '.join(PRESETS)}, got {joint_map!r}")
        rig_id = hashlib.sha256(data + (joint_map or "").encode()).hexdigest()[:16]
        with self._lock:
            if rig_id in self._kept:
                return self._kept[rig_id]
        suffix = ".glb" if data[:4] == b"glTF" else ".bvh"
        with tempfile.TemporaryDirectory(prefix="m2d2m-rig-") as folder:
            candidate = Path(folder) / f"rig{suffix}"
            candidate.write_bytes(data)
            mapping, joints = _checked(candidate, joint_map)
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_path(self.folder / f"{rig_id}{suffix}") as partial:
                partial.write_bytes(data)
        rig = UploadedRig(rig_id, self.folder / f"{rig_id}{suffix}", joints, mapping)
        with self._lock:
            self._kept[rig_id] = rig
        return rig

    def get(self, rig_id: str) -> UploadedRig:
        with self._lock:
            if rig_id not in self._kept:
                raise NotFound(f"no rig {rig_id!r} on this server; upload it with POST /api/rigs")
            return self._kept[rig_id]


def _checked(path: Path, joint_map: str | None) -> tuple[str, int]:
    """The name of the joint map a rig's joints take and their count, having retargeted our rest
    pose onto it once; a UserError saying why not."""
    try:
        clip = read_rig(path)
        mapping = joint_map_for(clip, joint_map)
        scale = rig_metres_per_unit(clip, mapping)
        rig = Rig.from_bvh(clip)
        rest = T2M.forward_kinematics(np.zeros((1, T2M.num_joints, 4)) + [1.0, 0, 0, 0], np.array([[0.0, 0.9, 0.0]]))
        retarget(rest, Rig(rig.names, rig.parents, rig.offsets * scale, rig.end_sites), mapping)
    except (BvhError, ValueError) as error:
        raise UserError(f"the rig cannot take our motions: {str(error).removeprefix(f'{path}: ')}") from error
    return mapping.name, len(rig.names)
