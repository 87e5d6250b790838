"""bench/gpu_carry.py and bench/gpu_run.sh: what a bare GPU machine is given for issue 54's bench,
and the command line's rows of that bench run for real in the project it carries."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))  # bench scripts import `timing` beside them
import bench.gpu  # noqa: E402
from bench.gpu_carry import CARRIED, ON_THE_MACHINE, make_project, pinned, project_name  # noqa: E402
from tests.helpers import lacking  # noqa: E402


def test_wheel_file_names_give_their_distribution_s_normalised_name():
    assert project_name("mlflow_skinny-3.17.2-py3-none-any.whl") == "mlflow-skinny"
    assert project_name("SQLAlchemy-2.1.9-cp312-cp312-manylinux2014_x86_64.whl") == "sqlalchemy"
    assert project_name("typing_extensions-4.15.0-py3-none-any.whl") in ON_THE_MACHINE


def test_the_carried_distributions_are_pinned_to_the_versions_the_tests_run():
    from importlib.metadata import version

    assert pinned() == [f"{name}=={version(name)}" for name in CARRIED]
    assert not set(CARRIED) & ON_THE_MACHINE


@pytest.mark.slow
def test_the_run_script_takes_one_of_its_parts():
    answer = subprocess.run(["bash", "bench/gpu_run.sh", "everything"], cwd=ROOT, capture_output=True, text=True)
    assert answer.returncode == 2 and "usage: bash bench/gpu_run.sh steps|cli" in answer.stderr


@pytest.mark.slow
def test_every_training_verb_runs_through_the_command_line_in_the_carried_project(
    tmp_path, one_torch_thread, monkeypatch
):
    """The project the GPU machine is given (its raw corpus, the VQ-VAE's checkpoints and MLflow's
    copies left out) trains every model from the command line, as the bench's rows run it, where
    neither Ray nor spaCy nor pygltflib can be imported: the machine has none and none is carried
    (a training on current tokens imported Ray and spaCy before)."""
    project = tmp_path / "demo-project"
    make_project(project, clips=20)
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "sitecustomize.py").write_text(lacking("ray", "spacy", "pygltflib"), encoding="utf-8")
    monkeypatch.setenv("PYTHONPATH", str(bare))
    assert not (project / "data" / "raw").exists() and not list(project.glob("runs/*/vq/*/checkpoints"))
    for name in ("m2d2m", "mmm", "motiondiffuse", "vq"):
        figure = bench.gpu.measure_cli(name, project, steps=20, compiled=False)
        assert figure.steps == 20 and figure.steps_per_s > 0 and figure.finished_to_exit_s is not None, name
