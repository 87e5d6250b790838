"""Characters' rigs a person uploads to the server, to download generations retargeted onto them
(issue 40 §2, §5; issue 52 §3; docs/serving.md): each a BVH file (its hierarchy and OFFSETs) or a
GLB character (its skin's skeleton as it stands), and the joint maps of their own that they read
them through.

A rig's file is streamed to disk as it comes, kept by the hash of its bytes, so a character of
tens of MB is never held whole in memory and is sent once: the same file under another map is
named by its id (``file``). Each file and map is read and checked once, by retargeting our rest
pose onto the rig, and kept as a :class:`~m2d2m.motion.rigs.retarget.Target` that every download on it
uses, so a download never fails on the rig and never reads its file again."""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
import uuid
from collections.abc import AsyncIterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Any

from starlette.concurrency import run_in_threadpool

from m2d2m.motion.files.bvh_reader import BvhError
from m2d2m.motion.rigs.joint_map import AUTO, PRESETS, JointMap
from m2d2m.motion.rigs.retarget import Target, read_target
from orchestration.errors import UserError
from orchestration.web.catalog import NotFound

RIGS_STAGE = "rigs"  # runs/<dataset>/rigs/: the uploaded rigs' files
GLB_MAGIC = b"glTF"  # a GLB's first four bytes (§4.4.2 of the glTF 2.0 specification); anything else is read as BVH


@dataclass(frozen=True)
class UploadedRig:
    """A rig on the server: its id, the id of its file, its joints' count, the name of the joint
    map that reads them (a preset's, or an uploaded map's id) and the rig read, ready for motions."""

    id: str
    file: str
    joints: int
    joint_map: str
    target: Target


class Rigs:
    """The rigs' files uploaded to this server, in ``folder`` (one ``<file id>.bvh`` or
    ``<file id>.glb`` each), the joint maps uploaded beside them, and the rigs made of the two."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._files: dict[str, Path] = {}
        self._maps: dict[str, JointMap] = {}
        self._kept: dict[str, UploadedRig] = {}
        self._lock = threading.Lock()

    async def receive(self, chunks: AsyncIterator[bytes]) -> str:
        """Write a rig's bytes to disk as they arrive, hashing them on the way; the file's id.
        How many bytes may arrive is the server's to bound (:mod:`orchestration.web.limits`); an
        upload cut off leaves nothing behind."""
        self.folder.mkdir(parents=True, exist_ok=True)
        digest, head, size = hashlib.sha256(), b"", 0
        partial = self.folder / f".upload-{uuid.uuid4().hex}.partial"
        try:
            with partial.open("wb") as out:
                async for chunk in chunks:
                    head = (head + chunk[:4])[:4]
                    size += len(chunk)
                    await run_in_threadpool(_append, out, digest, chunk)  # disk and hashing off the event loop
            if size == 0:
                raise UserError("the rig is empty: send the bytes of a BVH or GLB file")
            file_id = digest.hexdigest()[:16]
            path = self.folder / f"{file_id}{'.glb' if head == GLB_MAGIC else '.bvh'}"
            os.replace(partial, path)
        finally:
            partial.unlink(missing_ok=True)
        with self._lock:
            self._files[file_id] = path
        return file_id

    def add_map(self, data: bytes) -> JointMap:
        """A user's joint map, the text of a YAML file as ``m2d2m generate --joint-map`` reads it
        (:meth:`~m2d2m.motion.rigs.joint_map.JointMap.from_yaml`), checked and kept under the hash of
        its bytes, which names it; a UserError in one line when it is no map of our joints."""
        map_id = hashlib.sha256(data).hexdigest()[:16]
        with self._lock:
            if map_id in self._maps:
                return self._maps[map_id]
        with tempfile.TemporaryDirectory(prefix="m2d2m-map-") as folder:
            path = Path(folder) / "joint-map.yaml"
            path.write_bytes(data)
            try:
                mapping = replace(JointMap.from_yaml(path), name=map_id)
            except UnicodeDecodeError as error:
                raise UserError(f"the joint map is not UTF-8 text ({error.reason} at byte {error.start})") from error
            except ValueError as error:  # a YAML parser's message spans lines and names our temporary file
                said = str(error).replace(f"joint map {path}", "the joint map").replace(str(path), "the joint map")
                raise UserError(" ".join(said.split())) from error
        with self._lock:
            self._maps[map_id] = mapping
        return mapping

    def add(self, file_id: str, joint_map: str | None = None, rest_frame: int | None = None) -> UploadedRig:
        """The rig of an uploaded file through ``joint_map`` (a preset's name, an uploaded map's
        id, ``auto``, or None: the preset its joints fit, else ``auto``), aimed from frame
        ``rest_frame`` of its file or its rest pose (:func:`~m2d2m.motion.rigs.retarget.rig_bind`),
        checked once and kept; a UserError in one sentence when our motions cannot go onto it."""
        with self._lock:
            path = self._files.get(file_id)
        if path is None:
            raise NotFound(f"no rig file {file_id!r} on this server; send its bytes to POST /api/rigs")
        mapping = self._joint_map(joint_map)
        rig_id = hashlib.sha256(f"{file_id}:{joint_map or ''}:{'' if rest_frame is None else rest_frame}".encode())
        rig_id = rig_id.hexdigest()[:16]
        with self._lock:
            if rig_id in self._kept:
                return self._kept[rig_id]
        target = _checked(path, mapping, rest_frame)
        rig = UploadedRig(rig_id, file_id, len(target.rig.names), target.joint_map.name, target)
        with self._lock:
            self._kept[rig_id] = rig
        return rig

    def get(self, rig_id: str) -> UploadedRig:
        with self._lock:
            if rig_id not in self._kept:
                raise NotFound(f"no rig {rig_id!r} on this server; upload it with POST /api/rigs")
            return self._kept[rig_id]

    def _joint_map(self, name: str | None) -> JointMap | str | None:
        """The map a request names: a preset, ``auto`` (found from the rig's names and hierarchy,
        :mod:`m2d2m.motion.rigs.auto_map`) or one uploaded here (never a path on the server)."""
        if name is None or name == AUTO:
            return name
        if name in PRESETS:
            return PRESETS[name]
        with self._lock:
            if name in self._maps:
                return self._maps[name]
        raise UserError(
            f"joint_map must be one of {', '.join([*PRESETS, AUTO])} or the id of a map sent to POST /api/joint-maps, "
            f"got {name!r}"
        )


def _append(out: IO[bytes], digest: Any, chunk: bytes) -> None:
    out.write(chunk)
    digest.update(chunk)


def _checked(path: Path, joint_map: JointMap | str | None, rest_frame: int | None) -> Target:
    """The rig in ``path`` through ``joint_map`` from frame ``rest_frame``, checked by
    :func:`~m2d2m.motion.rigs.retarget.read_target`; a UserError saying why not."""
    try:
        return read_target(path, joint_map, rest_frame=rest_frame)
    except (BvhError, ValueError) as error:
        raise UserError(f"the rig cannot take our motions: {str(error).removeprefix(f'{path}: ')}") from error
