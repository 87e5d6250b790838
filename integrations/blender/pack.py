"""The Blender add-on as the zip Blender installs (Preferences > Add-ons > Install…): the package
``m2d2m_blender`` at the zip's top, its Python files only. ``make blender-addon`` runs it."""

from __future__ import annotations

import sys
import zipfile
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent / "m2d2m_blender"


def pack(out: Path) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for source in sorted(PACKAGE.glob("*.py")):
            archive.write(source, f"{PACKAGE.name}/{source.name}")
    return out


if __name__ == "__main__":
    print(pack(Path(sys.argv[1] if len(sys.argv) > 1 else "dist/m2d2m_blender.zip")))
