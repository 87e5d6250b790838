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


# issue 55 §3: the command line, generation and web app in modules of a size a reader holds in mind
MODULE_LINES, FUNCTION_LINES = 500, 60


@pytest.mark.parametrize(
    "package", ["orchestration/cli", "orchestration/generate", "orchestration/web", "training/data"]
)
def test_the_split_rooms_keep_modules_and_functions_a_reader_holds_in_mind(package):
    """Every module of the package under 500 lines and every function under 60 (docstring and
    decorators included), so that the rooms split by job do not grow back into one file."""
    base = ROOT / package
    files = sorted(base.rglob("*.py")) if base.is_dir() else [base.with_suffix(".py")]  # a package, or one module
    long_modules, long_functions = {}, {}
    for path in files:
        text = path.read_text(encoding="utf-8")
        name = str(path.relative_to(ROOT))
        if len(text.splitlines()) > MODULE_LINES:
            long_modules[name] = len(text.splitlines())
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(decorator.lineno for decorator in node.decorator_list)])
                if node.end_lineno - first + 1 > FUNCTION_LINES:
                    long_functions[f"{name}:{node.name}"] = node.end_lineno - first + 1
    assert long_modules == {} and long_functions == {}


def test_each_models_files_sit_in_its_own_package_whose_init_imports_nothing():
    """issue 55 §3, as transformers' models/<name>/: a registered model's generator and sampling
    declaration are modules of one package of m2d2m/generators/, and that package's __init__ is a
    docstring only, so that the registry reading a model's options imports no torch."""
    from orchestration.registry import models

    for name, entry in models().items():
        generator, sampling = (path.split(":")[0] for path in (entry.generator, entry.sampling))
        package = generator.rpartition(".")[0]
        assert package.startswith("m2d2m.generators.") and package.count(".") == 2, (name, generator)
        assert sampling.rpartition(".")[0] == package, (name, sampling)
        init = ast.parse((ROOT / package.replace(".", "/") / "__init__.py").read_text(encoding="utf-8"))
        assert [type(node) for node in init.body] == [ast.Expr], f"{package}/__init__.py holds more than a docstring"


def test_the_motion_package_is_a_clip_and_rooms_named_by_kind():
    """issue 55 §3, as torchvision's io/, datasets/, transforms/: beside the Motion (clip.py) every
    module of m2d2m/motion/ sits in the room of its kind, none flat at the top."""
    motion = ROOT / "m2d2m" / "motion"
    assert sorted(path.name for path in motion.glob("*.py")) == ["__init__.py", "clip.py"]
    rooms = sorted(path.parent.name for path in motion.glob("*/__init__.py"))
    assert rooms == ["files", "representation", "rigs", "transforms"]
