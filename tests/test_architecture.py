"""The floors of docs/architecture.md, read from the source: no import runs from a lower floor to a
higher one, nor across between pipelines/ and training/ (function-level imports included)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FORBIDDEN = {
    "m2d2m": {"ray", "lightning", "mlflow", "webdataset", "spacy", "pipelines", "training", "orchestration"},
    "pipelines": {"lightning", "mlflow", "training", "orchestration"},
    "training": {"ray", "mlflow", "spacy", "pipelines", "orchestration"},
}


def imported_packages(path: Path) -> set[str]:
    """The top-level package of every import in a file."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_import_climbs_a_floor(package):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files
    offending = {str(path.relative_to(ROOT)): sorted(imported_packages(path) & FORBIDDEN[package]) for path in files}
    assert {path: names for path, names in offending.items() if names} == {}


def test_the_checker_sees_function_level_imports(tmp_path):
    source = tmp_path / "module.py"
    source.write_text("def f():\n    from orchestration.registry import model\n    import ray.data\n")
    assert imported_packages(source) == {"orchestration", "ray"}


def test_nothing_reads_outside_the_repository():
    """A clone has nothing beside it: no code, test or bench may reach for the shared folder
    beside the repository; the HumanML3D sample the tests use is in tests/fixtures."""
    above = re.compile(r"""\.\.(/|["']\s*/\s*["'])shared""")
    offending = []
    for package in ("m2d2m", "pipelines", "training", "orchestration", "bench", "tests"):
        for path in sorted((ROOT / package).rglob("*.py")):
            if above.search(path.read_text(encoding="utf-8")):
                offending.append(str(path.relative_to(ROOT)))
    assert offending == []
