"""What a bare GPU machine is given to run ``bench/gpu.py`` whole: ``make gpu-carry``.

A machine lent for a GPU bench has PyTorch, Lightning, transformers and the scientific stack, but
not this project's other dependencies, and cannot reach a package index. This prepares, under
``--out`` (``.carry``, ignored by git):

- ``wheels/``: MLflow's tracking client (``mlflow-skinny`` and the SQLAlchemy store's
  ``sqlalchemy`` and ``alembic``) and WebDataset, at the versions this environment runs, with
  whatever they need that the machine lacks (:data:`ON_THE_MACHINE`), for its Python and platform;
- ``demo-project/``: a project with the demo's configs, a synthetic corpus of ``--clips`` clips
  made into shards by ``m2d2m data`` (Ray and spaCy run here, not there), a VQ-VAE of a few steps
  and its tokens: what ``bench/gpu.py --cli-project`` needs for every training verb.

It checks that the checkout and ``--out`` together fit what a call may carry, and prints the
command that runs the bench there (``bench/gpu_run.sh``).

    python bench/gpu_carry.py [--out .carry] [--clips 60] [--python 3.12] [--no-wheels]
"""

from __future__ import annotations

import argparse
import importlib.metadata
import re
import shutil
import subprocess
import sys
from pathlib import Path

from exit_time import from_this_checkout

ROOT = Path(__file__).resolve().parents[1]
CARRY_LIMIT = 64 * 2**20  # bytes one call may carry: the checkout's tracked files and the carried paths
# the distributions to carry, at this environment's versions: MLflow's client with its SQL store, WebDataset
CARRIED = ("mlflow-skinny", "mlflow-tracing", "sqlalchemy", "alembic", "webdataset")
# what the lent GPU machines' image holds (as read on 2026-11-17): carried again, a second version
# of one of these would stop the install
ON_THE_MACHINE = frozenset(
    """absl-py accelerate aiofiles aiohappyeyeballs aiohttp aiosignal annotated-doc anyio attrs certifi
    charset-normalizer click cloudpickle colorama contourpy cycler filelock fonttools frozenlist fsspec
    grpcio h11 h5py httpcore httpx huggingface-hub idna imageio jinja2 joblib kiwisolver lightning
    lightning-utilities markdown markdown-it-py markupsafe matplotlib mdurl msgpack multidict narwhals
    networkx numpy packaging pandas pillow pip pluggy prometheus-client propcache protobuf psutil pyarrow
    pygments pyparsing python-dateutil pytorch-lightning pyyaml regex requests rich safetensors scikit-learn
    scipy setuptools six sympy tabulate tensorboard threadpoolctl tokenizers torch torchmetrics tqdm
    transformers triton typing-extensions urllib3 werkzeug wheel wrapt yarl zipp""".split()
)
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux1_x86_64")


def project_name(wheel: str) -> str:
    """The normalised distribution name of a wheel's file name (PEP 427, PEP 503)."""
    return re.sub(r"[-_.]+", "-", wheel.split("-", 1)[0]).lower()


def pinned() -> list[str]:
    """:data:`CARRIED` at the versions installed here, which the test suite runs against."""
    return [f"{name}=={importlib.metadata.version(name)}" for name in CARRIED]


def download_wheels(into: Path, python: str) -> list[Path]:
    """The wheels of :func:`pinned` and their requirements for CPython ``python`` on x86-64 Linux,
    less those of :data:`ON_THE_MACHINE`."""
    into.mkdir(parents=True, exist_ok=True)
    platforms = [flag for platform in PLATFORMS for flag in ("--platform", platform)]
    command = [sys.executable, "-m", "pip", "download", "-qq", "--only-binary=:all:", "--implementation", "cp"]
    command += ["--python-version", python, *platforms, "--dest", str(into), *pinned()]
    subprocess.run(command, check=True)
    kept = []
    for wheel in sorted(into.glob("*.whl")):
        if project_name(wheel.name) in ON_THE_MACHINE:
            wheel.unlink()
        else:
            kept.append(wheel)
    return kept


def cli(project: Path, *arguments: str) -> None:
    """``m2d2m <arguments>`` in ``project``, from this checkout."""
    command, env = from_this_checkout(*arguments)
    subprocess.run(command, cwd=project, env=env, check=True)


def make_project(project: Path, clips: int) -> None:
    """A project with the demo's configs, ``clips`` synthetic clips in shards, a VQ-VAE of a few
    steps and its tokens. Left out, as nothing a training verb reads: the raw corpus, the VQ-VAE
    run's checkpoints and previews, and MLflow's copies of its files (the run's record stays)."""
    if project.exists():
        shutil.rmtree(project)
    project.mkdir(parents=True)
    shutil.copytree(ROOT / "configs", project / "configs")
    cli(project, "synthesize", "--out", "data/raw/synthetic", "--clips", str(clips), "--seed", "0")
    cli(project, "data", "--dataset", "synthetic", "--raw", "data/raw/synthetic")
    quick = ["trainer.max_steps=20", "trainer.val_every_steps=20", "trainer.val_batches=1", "trainer.gif_every=100"]
    cli(project, "train-vq", "--config", "demo", *(f"--set={setting}" for setting in quick))
    cli(project, "tokenize", "--dataset", "synthetic")
    shutil.rmtree(project / "data" / "raw")
    for unread in [*project.glob("runs/*/vq/*/checkpoints"), *project.glob("mlruns/*/*/artifacts")]:
        shutil.rmtree(unread)
    for drawn in project.glob("runs/**/*.gif"):
        drawn.unlink()


def tree_bytes(folder: Path) -> int:
    return sum(path.stat().st_size for path in folder.rglob("*") if path.is_file())


def checkout_bytes() -> int:
    """The size of the checkout's tracked files, which every call carries."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return sum((ROOT / name).stat().st_size for name in listed.decode().split("\0") if name and (ROOT / name).is_file())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / ".carry")
    parser.add_argument(
        "--clips", type=int, default=60, help="synthetic clips in the demo project (and as many mirrors)"
    )
    parser.add_argument("--python", default="3.12", help="the GPU machine's Python, for its compiled wheels")
    parser.add_argument("--no-wheels", action="store_true", help="only the demo project")
    args = parser.parse_args(argv)
    out = args.out.resolve()
    if not args.no_wheels:
        shutil.rmtree(out / "wheels", ignore_errors=True)
        wheels = download_wheels(out / "wheels", args.python)
        print(f"{len(wheels)} wheels, {tree_bytes(out / 'wheels') / 2**20:.1f} MiB, in {out / 'wheels'}")
    make_project(out / "demo-project", args.clips)
    print(f"the demo project, {tree_bytes(out / 'demo-project') / 2**20:.1f} MiB, in {out / 'demo-project'}")
    total = checkout_bytes() + tree_bytes(out)
    print(
        f"the checkout and {out.name}/ together: {total / 2**20:.1f} MiB of the {CARRY_LIMIT / 2**20:.0f} a call carries"
    )
    if total > CARRY_LIMIT:
        print(f"too much to carry: take fewer --clips than {args.clips}", file=sys.stderr)
        return 1
    print(
        f"on the GPU machine, carrying {out.relative_to(ROOT) if out.is_relative_to(ROOT) else out}: bash bench/gpu_run.sh"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
