"""Blender, which writes our FBX (its glTF importer, then its FBX exporter: :mod:`m2d2m.motion.files.gltf`):
where it is, and what to install where it is not. Apart from the glTF writer, so that a command
can check for it before any work without importing pygltflib."""

from __future__ import annotations

import shutil

# Debian's packages: Blender with its glTF importer and FBX exporter, and the NumPy its glTF
# importer imports (Debian's blender does not depend on it)
BLENDER_PACKAGES = "blender python3-numpy"


def find_blender() -> str:
    """The ``blender`` on the PATH; FileNotFoundError in one line naming the packages when none is."""
    blender = shutil.which("blender")
    if blender is None:
        raise FileNotFoundError(
            f"FBX is written by Blender, and no blender is on the PATH: apt-get install {BLENDER_PACKAGES}"
        )
    return blender
