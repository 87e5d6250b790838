"""The fault matrix of docs/reliability.md: every verb driven through bad values of its arguments
and config keys, corrupt, truncated, empty and wrong-kind input files, and kills.

Every user error must end in exit status 2 and one line on stderr, with no traceback, and leave
nothing that looks complete but is not: no new run marked finished, ``latest`` unchanged and
pointing at a finished run. The kills (SIGKILL while a stage writes) must leave what existed
whole, and a re-run must finish and, where the stage is deterministic, equal a clean run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from tests.helpers import (
    TINY_BODY,
    TINY_MMM,
    TINY_MOTIONDIFFUSE,
    one_line_error,
    pose_clip,
    write_part_tokenizer_configs,
)

# ------------------------------------------------------------------------------ the bad inputs


class RunsCode:
    """Unpickled, this creates a file: what a model file that runs code could do instead."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def write_bad_files(folder: Path, trained: Path) -> None:
    """Input files of every wrong kind the matrix feeds the verbs, beside the real ones."""
    folder.mkdir(parents=True, exist_ok=True)
    joints = np.zeros((12, 22, 3), dtype=np.float32)
    joints[:, :, 1] = np.linspace(0.0, 1.7, 22)
    np.save(folder / "joints.npy", joints)
    (folder / "empty.npy").write_bytes(b"")
    (folder / "truncated.npy").write_bytes((folder / "joints.npy").read_bytes()[:150])
    (folder / "text.npy").write_text("not an array\n", encoding="utf-8")
    np.save(folder / "nan.npy", np.where(np.arange(12)[:, None, None] == 5, np.nan, joints))
    np.save(folder / "inf.npy", np.where(np.arange(12)[:, None, None] == 5, np.inf, joints))
    np.save(folder / "no-frames-joints.npy", np.zeros((0, 22, 3), dtype=np.float32))
    np.save(folder / "no-frames-features.npy", np.zeros((0, 263), dtype=np.float32))
    np.save(folder / "wrong-shape.npy", np.zeros((12, 7), dtype=np.float32))
    np.save(folder / "one-dimensional.npy", np.zeros(12, dtype=np.float32))
    np.save(folder / "objects.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    np.save(folder / "integers.npy", np.zeros((12, 22, 3), dtype=np.int64))

    vq = next((trained / "runs" / "tiny" / "vq").glob("*/vq.pt"))
    model = next((trained / "runs" / "tiny" / "m2d2m").glob("*/model.pt"))
    evaluator = next((trained / "runs" / "tiny" / "evaluator").glob("*/evaluator.pt"))
    (folder / "empty.pt").write_bytes(b"")
    (folder / "random.pt").write_bytes(np.random.default_rng(0).bytes(4096))
    for name, source in (("vq", vq), ("model", model), ("evaluator", evaluator)):
        (folder / f"truncated-{name}.pt").write_bytes(source.read_bytes()[: source.stat().st_size // 2])
    torch.save(RunsCode(folder / "code-ran"), folder / "code.pt")  # would create code-ran when unpickled
    torch.save({"weights": torch.zeros(3)}, folder / "a-dict.pt")
    torch.save(torch.zeros(3), folder / "a-tensor.pt")

    (folder / "empty.yaml").write_text("", encoding="utf-8")
    (folder / "broken.yaml").write_text("model: {width: [\n", encoding="utf-8")
    (folder / "list.yaml").write_text("- 1\n- 2\n", encoding="utf-8")
    (folder / "no-manifest").mkdir(exist_ok=True)
    (folder / "bad-manifest").mkdir(exist_ok=True)
    (folder / "bad-manifest" / "manifest.json").write_text("{", encoding="utf-8")
    (folder / "joints-only").mkdir(exist_ok=True)
    shutil.copytree(trained / "raw" / "joints", folder / "joints-only" / "joints", dirs_exist_ok=True)
    for split in ("train", "val", "test"):
        shutil.copy(trained / "raw" / f"{split}.txt", folder / "joints-only" / f"{split}.txt")


def _bad_files(verb: str, first: list[str], files: tuple[str, ...], *rest: str) -> list[list[str]]:
    return [[verb, *first, "{tmp}/" + name, *rest] for name in files]


BAD_MOTIONS = (
    "empty.npy",
    "truncated.npy",
    "text.npy",
    "nan.npy",
    "inf.npy",
    "no-frames-joints.npy",
    "no-frames-features.npy",
    "wrong-shape.npy",
    "one-dimensional.npy",
    "objects.npy",
    "nowhere.npy",
)
BAD_MODEL_FILES = ("empty.pt", "random.pt", "a-dict.pt", "a-tensor.pt", "nowhere.pt")
BAD_CONFIGS = ("empty.yaml", "broken.yaml", "list.yaml", "nowhere.yaml")
TRAINING = {
    "train-vq": "{root}/vq.yaml",
    "train-diffusion": "{root}/diffusion.yaml",
    "train-evaluator": "{root}/evaluator.yaml",
    "train-mmm": "{root}/mmm.yaml",
    "train-mmm-body": "{root}/body.yaml",
    "train-motiondiffuse": "{root}/motiondiffuse.yaml",
}


def _training_cases() -> list[list[str]]:
    cases = []
    for verb, config in TRAINING.items():
        cases += _bad_files(verb, ["--config"], BAD_CONFIGS)
        cases += [[verb, "--config", "no-such-config"]]
        for override in (
            "optim.lr=abc",
            "optim.lr=-1",
            "optim.lr",
            "trainer.max_steps=-1",
            "trainer.max_steps=x",
            "trainer.val_every_steps=0",
            "no.such.key=1",
            "seed=x",
            "data.batch_size=0",
            "data.dir={tmp}/nowhere",
            "data.dir={tmp}/no-manifest",
            "data.dir={tmp}/bad-manifest",
            "trainer.accelerator=abacus",
            "trainer.devices=0",
        ):
            cases.append([verb, "--config", config, "--set", override])
        cases.append([verb, "--config", config, "--resume"])  # its only run has finished
        cases.append([verb, "--config", config, "--resume", "no-such-run"])
    for verb, override in (
        ("train-vq", "model.width=0"),
        ("train-vq", "model.activation=sigmoidal"),
        ("train-evaluator", "model.embedding_dim=0"),
        ("train-diffusion", "denoiser.heads=3"),
        ("train-diffusion", "diffusion.steps=0"),
        ("train-diffusion", "diffusion.kind=cubic"),
        ("train-mmm", "transformer.heads=3"),
        ("train-mmm", "transformer.cross_layers=9"),
        ("train-mmm", "masking.alpha=2"),
        ("train-mmm-body", "masking.lower_most=2"),
        ("train-mmm-body", "transformer.heads=3"),
        ("train-mmm-body", "vq=latest"),
        ("train-mmm-body", "vq.upper=no-such-run"),
        ("train-mmm-body", "vq.lower={vq}"),
        ("train-motiondiffuse", "network.heads=3"),
        ("train-motiondiffuse", "network.attention=quadratic"),
        ("train-motiondiffuse", "diffusion.steps=0"),
        ("train-motiondiffuse", "diffusion.beta_end=2"),
        ("train-motiondiffuse", "data.min_frames=500"),
    ):
        cases.append([verb, "--config", TRAINING[verb], "--set", override])
    for verb, key in (("train-diffusion", "vq"), ("train-mmm", "vq"), ("train-mmm-body", "vq.upper")):
        for name in (*BAD_MODEL_FILES, "truncated-vq.pt", "model.pt"):
            path = "{model}" if name == "model.pt" else "{tmp}/" + name
            cases.append([verb, "--config", TRAINING[verb], "--set", f"{key}={path}"])
    return cases


BAD_ARGUMENTS: list[list[str]] = [
    ["no-such-verb"],
    ["synthesize", "--clips", "0"],
    ["synthesize", "--clips", "x"],
    ["synthesize", "--workers", "0"],
    ["synthesize", "--families", "walk,moonwalk"],
    ["synthesize", "--seed", "x"],
    ["synthesize", "--out", "{tmp}/joints.npy", "--clips", "3"],
    ["data", "--workers", "0"],
    ["data", "--samples-per-shard", "0"],
    ["data", "--min-frames", "0"],
    ["data", "--max-frames", "x"],
    ["data", "--dataset", "amass"],
    ["data", "--dataset", "humanml3d", "--raw", "{tmp}/nowhere"],
    ["data", "--raw", "{tmp}/joints.npy"],
    ["data", "--raw", "{root}/raw", "--out", "{tmp}/new", "--min-frames", "100", "--max-frames", "50"],
    ["data", "--raw", "{tmp}/joints-only", "--out", "{tmp}/new"],
    ["data", "--raw", "{root}/raw", "--out", "{tmp}/joints.npy"],
    ["data", "--check", "{tmp}/nowhere"],
    ["data", "--check", "{tmp}/bad-manifest"],
    ["data", "--check", "{tmp}/no-manifest"],
    *_training_cases(),
    ["tokenize", "--workers", "0"],
    ["tokenize", "--dataset", "tiny", "--vq", "no-such-run"],
    *_bad_files("tokenize", ["--dataset", "tiny", "--vq"], (*BAD_MODEL_FILES, "truncated-vq.pt")),
    ["tokenize", "--dataset", "tiny", "--vq", "{model}"],
    ["tokenize", "--dataset", "tiny", "--data", "{tmp}/nowhere"],
    ["tokenize", "--dataset", "tiny", "--data", "{tmp}/bad-manifest"],
    ["tokenize", "--check", "{tmp}/nowhere"],
    ["tokenize", "--check", "{tmp}/bad-manifest"],
    ["testset", "--n", "0"],
    ["testset", "--n", "x"],
    ["testset", "--seed", "x"],
    ["testset", "--first", "0"],
    ["testset", "--dataset", "tiny", "--data", "{root}/data", "--mirrors", "sometimes"],
    ["testset", "--dataset", "tiny", "--data", "{root}/data", "--n", "500"],
    ["testset", "--dataset", "tiny", "--data", "{tmp}/nowhere"],
    ["testset", "--dataset", "tiny", "--data", "{tmp}/bad-manifest"],
    ["testset", "--dataset", "tiny", "--data", "{tmp}/no-manifest"],
    *[
        ["evaluate", "--dataset", "tiny", *more]
        for more in (
            ["--model", "no-such-model"],
            ["--method", "teleport"],
            ["--ts", "-1"],
            ["--ts", "100000"],
            ["--ts", "x"],
            ["--eta", "nan"],
            ["--eta", "-1"],
            ["--guidance", "-1"],
            ["--repeats", "0"],
            ["--batch-size", "0"],
            ["--option", "no_such_knob=1"],
            ["--option", "truncation=abc"],
            ["--testset", "{tmp}/nowhere"],
            ["--testset", "{tmp}/bad-manifest"],
            ["--evaluator", "{tmp}/nowhere"],
            ["--evaluator", "{tmp}/empty.pt"],
            ["--evaluator", "{tmp}/truncated-evaluator.pt"],
            ["--evaluator", "{model}"],
            ["--checkpoint", "{tmp}/empty.pt"],
            ["--checkpoint", "{tmp}/truncated-model.pt"],
            ["--checkpoint", "{vq}"],
            ["--resume", "no-such-run"],
            ["--resume", "no-such-run", "--ts", "3"],
            ["--guo-evaluator", "{tmp}/nowhere"],
        )
    ],
    *[
        ["generate", "--dataset", "tiny", "--out", "{tmp}/generated", *more]
        for more in (
            [],
            ["   "],
            ["a person walks", "--seconds", "-1"],
            ["a person walks", "--seconds", "0"],
            ["a person walks", "a person jumps", "--seconds", "1", "2", "3"],
            ["a person walks", "--seconds", "100000"],
            ["a person walks", "--seconds", "nan"],
            ["a person walks", "--method", "teleport"],
            ["a person walks", "--ts", "-1"],
            ["a person walks", "--eta", "-0.5"],
            ["a person walks", "--option", "eta=abc"],
            ["a person walks", "--guidance", "-2"],
            ["a person walks", "--truncation", "0"],
            ["a person walks", "--truncation", "2"],
            ["a person walks", "--formats", "xyz"],
            ["a person walks", "--model", "no-such-model"],
            ["a person walks", "--option", "no_such_knob=1"],
            ["a person walks", "--seed", "x"],
            ["a person walks", "--name", "a/b"],
            ["a person walks", "--max-seconds", "-5"],
            ["a person walks", "--max-seconds", "nan"],
            ["a person walks", "--max-seconds", "0.1"],
            *[
                ["a person walks", "--checkpoint", path]
                for path in (
                    "{tmp}/empty.pt",
                    "{tmp}/random.pt",
                    "{tmp}/a-dict.pt",
                    "{tmp}/truncated-model.pt",
                    "{vq}",
                    "{tmp}/nowhere.pt",
                )
            ],
        )
    ],
    ["generate", "a person walks", "--dataset", "tiny", "--out", "{tmp}/joints.npy", "--formats", "gif"],
    # the newer surfaces as a new user meets them (issue 29): other models, prompts, --part, --edit
    *[
        ["generate", "--dataset", "tiny", "--out", "{tmp}/generated", *more]
        for more in (
            ["a person walks", "--model", "mmm"],
            ["a person walks", "--model", "motiondiffuse"],
            ["a person walks", "--model", "mmm-body"],
            ["a person walks", "--model", "mmm", "--checkpoint", "{model}"],
            ["a person walks", "--model", "motiondiffuse", "--checkpoint", "{model}"],
            ["a person walks", "--model", "mmm-body", "--checkpoint", "{model}"],
            ["!!! ..."],
            ["\U0001f642"],
            ["a person walks " * 700],
            ["a person walks"] * 50,
            ["a person walks", "--seconds", "0.1"],
            ["a person walks", "--seconds", "600"],
            ["a person walks", "--part", "upper"],
            ["a person walks", "--part", "head=waves"],
            ["a person walks", "--part", "upper=waves"],
            ["a person walks", "--part", "upper=waves", "--part", "upper=claps", "--model", "motiondiffuse"],
            ["a person walks", "--part", "upper=waves", "--edit", "{tmp}/joints.npy", "--keep-body", "lower"],
            ["a person claps", "--edit", "{tmp}/joints.npy"],
            ["a person claps", "--keep-body", "lower"],
            ["a person claps", "--edit", "{tmp}/joints.npy", "--keep-body", "torso"],
            ["a person claps", "--edit", "{tmp}/joints.npy", "--keep-body", "lower"],
            ["a person claps", "--edit", "{tmp}/joints.npy", "--keep-body", "lower", "--seconds", "3"],
            ["a person claps", "--edit", "{tmp}/wrong-shape.npy", "--keep-body", "lower"],
            ["a person claps", "--edit", "{tmp}/nowhere.npy", "--keep-body", "lower"],
        )
    ],
    ["generate", "a person walks", "--dataset", "no-such-dataset", "--out", "{tmp}/generated"],
    *[
        ["evaluate", "--dataset", "tiny", *more]
        for more in (
            ["--model", "m2d2m,mmm"],
            ["--model", "m2d2m,no-such-model"],
            ["--model", "mmm-body"],
            ["--model", ","],
        )
    ],
    *[
        ["serve", "--dataset", "tiny", *more]
        for more in (
            ["--port", "99999"],
            ["--port", "{busy_port}"],
            ["--host", "0.0.0.0"],
            ["--host", "0.0.0.0", "--token", "short"],
            ["--max-seconds", "-1"],
            ["--queue", "0"],
            ["--max-batch", "0"],
            ["--max-rig-mb", "0"],
        )
    ],
    ["train-mmm", "--config", "{root}/mmm.yaml", "--set", "vq={tmp}/joints.npy"],
    ["sweep", "--config", "no-such-sweep"],
    *_bad_files("sweep", ["--config"], BAD_CONFIGS),
    *[
        ["sweep", "--set", "dataset=tiny", "--set", override]
        for override in (
            "space.no_such_knob=[1,2]",
            "space.eta=[]",
            "space.eta=0.5",
            "kind=other",
            "repeats=0",
            "bogus",
            "search=sometimes",
            "model=no-such-model",
            "max_concurrent=0",
            "no_such_key=1",
        )
    ],
    *[
        ["render", "{tmp}/joints.npy", "--out", "{tmp}/out.gif", *more]
        for more in (
            ["--fps", "0"],
            ["--fps", "-1"],
            ["--fps", "nan"],
            ["--fps", "inf"],
            ["--fps", "x"],
            ["--skeleton", "smpl"],
        )
    ],
    ["render", "{tmp}/joints.npy", "--out", "{tmp}/out.png"],
    ["render", "{root}/raw", "--out", "{tmp}/out.gif"],
    ["render", "{root}/raw", "--id", "no-such-clip", "--out", "{tmp}/out.gif"],
    *_bad_files("render", [], BAD_MOTIONS, "--out", "{tmp}/out.gif"),
    *[
        ["export", "{tmp}/joints.npy", "--out", "{tmp}/out.bvh", *more]
        for more in (["--fps", "0"], ["--fps", "-1"], ["--fps", "nan"])
    ],
    ["export", "{tmp}/joints.npy", "--out", "{tmp}/out.obj"],
    ["export", "{tmp}/joints.npy", "--out", "{tmp}/out.bvh", "--rest", "apose"],
    *[
        ["export", "{tmp}/joints.npy", "--out", "{tmp}/out.glb", *more]
        for more in (["--root", "sideways"], ["--fps", "5000"], ["--rig", "{tmp}/no-rig.bvh"], ["--joint-map", "cmu"])
    ],
    *_bad_files("export", [], BAD_MOTIONS, "--out", "{tmp}/out.bvh"),
    ["ui", "--port", "99999"],
    ["ui", "--port", "-1"],
    ["ui", "--port", "x"],
    ["ui", "--port", "{busy_port}"],
]


# ------------------------------------------------------------------------------ the invariants


def run_states(root: Path) -> dict[str, str]:
    """Every run folder's status and every ``latest`` marker's target under ``root/runs``."""
    states = {}
    for run_file in sorted((root / "runs").glob("*/*/*/run.json")):
        states[str(run_file.parent.relative_to(root))] = json.loads(run_file.read_text())["status"]
    for marker in sorted((root / "runs").glob("*/*/latest")):
        states[str(marker.relative_to(root))] = marker.read_text().strip()
    return states


def assert_latest_is_finished(root: Path) -> None:
    for marker in (root / "runs").glob("*/*/latest"):
        target = marker.parent / marker.read_text().strip()
        assert json.loads((target / "run.json").read_text())["status"] == "finished", marker


def assert_nothing_looks_finished(root: Path, before: dict[str, str]) -> None:
    """After a user error: no new run unless marked failed, no ``latest`` moved."""
    after = run_states(root)
    for key, value in after.items():
        if key.endswith("latest"):
            assert before.get(key) == value, f"{key} moved to {value}"
        elif key not in before:
            assert value == "failed", f"{key} is a new run left {value}"
    assert_latest_is_finished(root)


@pytest.fixture(scope="module")
def matrix_project(trained_project: Path, tmp_path_factory) -> Iterator[dict[str, str]]:
    tmp = tmp_path_factory.mktemp("bad-inputs")
    write_bad_files(tmp, trained_project)
    (trained_project / "mmm.yaml").write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    (trained_project / "body.yaml").write_text(yaml.safe_dump(TINY_BODY), encoding="utf-8")
    features = {**TINY_MOTIONDIFFUSE["data"], "dir": str(trained_project / "data")}
    (trained_project / "motiondiffuse.yaml").write_text(
        yaml.safe_dump({**TINY_MOTIONDIFFUSE, "data": features}), encoding="utf-8"
    )
    for config in write_part_tokenizer_configs(trained_project):  # what the upper-body editor reads
        assert main(["train-vq", "--config", str(config)]) == 0
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        yield {
            "root": str(trained_project),
            "tmp": str(tmp),
            "busy_port": str(busy.getsockname()[1]),
            "vq": str(next((trained_project / "runs" / "tiny" / "vq").glob("*/vq.pt"))),
            "model": str(next((trained_project / "runs" / "tiny" / "m2d2m").glob("*/model.pt"))),
        }


def _case_id(argv: list[str]) -> str:
    return " ".join(a.replace("{tmp}/", "").replace("{root}/", "") for a in argv)[:90]


@pytest.mark.parametrize("argv", BAD_ARGUMENTS, ids=[_case_id(a) for a in BAD_ARGUMENTS])
def test_a_user_error_is_one_line_with_exit_2_and_leaves_nothing_that_looks_done(argv, matrix_project, capfd):
    root = Path(matrix_project["root"])
    before = run_states(root)
    line = one_line_error([a.format(**matrix_project) for a in argv], capfd)
    assert line.startswith("m2d2m") and "error:" in line, line
    assert_nothing_looks_finished(root, before)


# ------------------------------------------------------------------------------------ the kills


# ``python -c PAUSED module:qualname marker argv...``: m2d2m, stopping for good once the function or
# method ``module:qualname`` first returns, having touched the file ``marker`` to say so. A kill or
# Ctrl-C then lands at that point whatever the machine's speed: a test waits for the marker, a state
# the process cannot leave, instead of racing the rest of the command to its end.
PAUSED = """
import importlib, pathlib, sys, time
module, _, qualname = sys.argv[1].partition(":")
*path, name = qualname.split(".")
owner = importlib.import_module(module)
for attribute in path:
    owner = getattr(owner, attribute)
function = getattr(owner, name)
def then_pause(*args, **kwargs):
    function(*args, **kwargs)
    pathlib.Path(sys.argv[2]).touch()
    while True:
        time.sleep(3600)
setattr(owner, name, then_pause)
from orchestration.cli import main
sys.exit(main(sys.argv[3:]))
"""


def cli_env() -> dict[str, str]:
    """This environment without a tracking server or a cluster: a command the matrix starts uses
    its project's own store and a Ray of its own."""
    return {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "RAY_ADDRESS")}


# Ctrl-C at its default, as a terminal starts a command: a child inherits an ignored SIGINT, and
# this process has been seen to ignore SIGINT and SIGQUIT at times (C's system() does so while it
# waits, in whichever thread of a library calls it), so a command started then never took Ctrl-C
AS_FROM_A_TERMINAL = "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); os.execv(sys.executable, [sys.executable, *sys.argv[1:]])"


@contextlib.contextmanager
def paused_cli(argv: list[str], cwd: Path, pause_after: str, timeout: float = 300.0) -> Iterator[subprocess.Popen]:
    """``m2d2m argv`` in its own session (so that a kill reaches what it started: Ray, workers),
    with Ctrl-C at its default, yielded once it has stopped for good after ``pause_after``
    (``module:qualname``, see ``PAUSED``) returned; SIGKILLed on the way out if still alive."""
    marker = Path(tempfile.mkdtemp(prefix="m2d2m-paused-")) / "paused"
    process = subprocess.Popen(
        [sys.executable, "-c", AS_FROM_A_TERMINAL, "-c", PAUSED, pause_after, str(marker), *argv],
        cwd=cwd,
        env=cli_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + timeout  # a bound on a hung command, not a point to race
        while process.poll() is None and not marker.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not marker.exists() or process.poll() is not None:
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGKILL)
            stderr = process.communicate()[1]
            pytest.fail(f"m2d2m {argv[0]} never paused after {pause_after}; stderr:\n{stderr[-2000:]}")
        yield process
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
        shutil.rmtree(marker.parent)


# where a kill lands in a training: its first checkpoints written (Lightning's ModelCheckpoint writes
# last.ckpt after best.ckpt, whichever hook saves; a validation at step 0 saves nothing)
FIRST_CHECKPOINTS = "lightning.pytorch.callbacks.model_checkpoint:ModelCheckpoint._save_last_checkpoint"
# where it lands in an animation: its first frame encoded, in the partial file beside the final name
GIF_FRAME = "PIL.GifImagePlugin:getdata"


def kill_when(argv: list[str], cwd: Path, pause_after: str, reached: Callable[[], bool]) -> None:
    """Run ``m2d2m argv``, SIGKILL its whole session once it has paused after ``pause_after``,
    and check that it was killed in the state ``reached()`` describes."""
    with paused_cli(argv, cwd, pause_after):
        pass
    assert reached(), f"m2d2m {argv[0]} paused after {pause_after}, but not in the state the test kills"


def killed_and_clean(data: Path, tmp_path: Path, *derived: str) -> dict[str, Path]:
    """Two copies of the dataset ``data`` without its ``derived`` sets, which the verb under test
    writes anew: one for the killed run, one for a clean run to compare with."""
    copies = {name: tmp_path / name for name in ("killed", "clean")}
    for copy in copies.values():
        shutil.copytree(data, copy, ignore=shutil.ignore_patterns(*derived))
    return copies


def tree_digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.slow
def test_a_killed_synthesize_leaves_a_corpus_a_rerun_completes_to_the_clean_one(tmp_path):
    from pipelines.synthetic import generate_corpus

    generate_corpus(tmp_path / "clean", clips=60, seed=3)
    argv = ["synthesize", "--out", "killed", "--clips", "60", "--seed", "3", "--workers", "1"]
    kill_when(
        argv,
        tmp_path,
        "pipelines.synthetic.corpus:_write_clip",
        lambda: any((tmp_path / "killed").glob("joints/*.npy")),
    )
    assert main(["synthesize", "--out", str(tmp_path / "killed"), "--clips", "60", "--seed", "3"]) == 0
    assert tree_digest(tmp_path / "killed") == tree_digest(tmp_path / "clean")


def test_a_killed_rebuild_leaves_the_dataset_whole_and_a_rerun_equals_a_clean_build(tmp_path, ray_local, monkeypatch):
    from pipelines.features import DataConfig, build_dataset
    from pipelines.synthetic import generate_corpus

    generate_corpus(tmp_path / "raw", clips=60, seed=4)
    build_dataset(
        DataConfig(
            dataset="synthetic", raw=str(tmp_path / "raw"), out=str(tmp_path / "data"), samples_per_shard=8, workers=1
        )
    )
    clean = tree_digest(tmp_path / "data")
    argv = ["data", "--raw", "raw", "--out", "data", "--samples-per-shard", "8", "--workers", "1", "--force"]
    # killed with every shard written into the new build's folder, before its manifest and the swap
    kill_when(
        argv,
        tmp_path,
        "pipelines.features:run_shard_tasks",
        lambda: any(tmp_path.glob(".data.building-*/shards/*.tar")),
    )
    assert tree_digest(tmp_path / "data") == clean  # the old dataset, untouched
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 0  # the re-run here, on this session's Ray
    rebuilt = tree_digest(tmp_path / "data")
    assert {k: v for k, v in rebuilt.items() if k.startswith("shards/") or k == "stats.npz"} == {
        k: v for k, v in clean.items() if k.startswith("shards/") or k == "stats.npz"
    }
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".data.")) == [".data.lock"]
    assert main(["data", "--check", str(tmp_path / "data")]) == 0


@pytest.mark.parametrize(
    "verb, config, stage, model_file",
    [
        ("train-vq", "vq.yaml", "vq", "vq.pt"),
        ("train-diffusion", "diffusion.yaml", "m2d2m", "model.pt"),
        ("train-evaluator", "evaluator.yaml", "evaluator", "evaluator.pt"),
        ("train-mmm", "mmm.yaml", "mmm", "model.pt"),
        ("train-mmm-body", "body.yaml", "mmm-body", "model.pt"),
        ("train-motiondiffuse", "motiondiffuse.yaml", "motiondiffuse", "model.pt"),
    ],
)
def test_a_killed_training_is_not_latest_and_resumes_to_a_finished_run(matrix_project, verb, config, stage, model_file):
    root = Path(matrix_project["root"])
    folder = root / "runs" / "tiny" / stage
    marker = folder / "latest"
    finished = marker.read_text() if marker.exists() else None
    before = set(folder.iterdir()) if folder.exists() else set()

    def a_new_checkpoint() -> bool:
        return folder.exists() and any(list(run.glob("checkpoints/*.ckpt")) for run in set(folder.iterdir()) - before)

    settings = ["trainer.max_steps=12", "trainer.val_every_steps=2"]
    settings += ["trainer.gif_every=100"] if verb != "train-evaluator" else []  # it draws no previews
    argv = [verb, "--config", config, *(arg for s in settings for arg in ("--set", s))]
    kill_when(argv, root, FIRST_CHECKPOINTS, a_new_checkpoint)
    (killed,) = {run for run in set(folder.iterdir()) - before if run.is_dir()}
    assert json.loads((killed / "run.json").read_text())["status"] == "running"
    assert (marker.read_text() if marker.exists() else None) == finished and not (killed / model_file).exists()
    assert main([verb, "--config", config, "--resume"]) == 0  # here: a second process would import for seconds
    assert json.loads((killed / "run.json").read_text())["status"] == "finished"
    assert marker.read_text().strip() == killed.name and (killed / model_file).is_file()


def test_ctrl_c_in_training_is_recorded_interrupted_with_a_line_and_exit_130(matrix_project, capsys):
    """Lightning turns a Ctrl-C inside fit into exit(1) after its own shutdown; the run must still
    read ``interrupted`` (resumable), the command say so and exit 130 like any interrupted command.
    A resume that finds no checkpoint yet says it starts from step 0."""
    root = Path(matrix_project["root"])
    folder = root / "runs" / "tiny" / "vq"
    before = set(folder.iterdir())

    def new_runs() -> set[Path]:
        return {run for run in set(folder.iterdir()) - before if run.is_dir()}

    settings = ["trainer.max_steps=12", "trainer.val_every_steps=2", "trainer.gif_every=1000"]
    argv = ["train-vq", "--config", "vq.yaml", *(a for s in settings for a in ("--set", s))]
    with paused_cli(argv, root, FIRST_CHECKPOINTS) as process:  # inside fit, which cannot end now
        assert any(list(run.glob("checkpoints/*.ckpt")) for run in new_runs())
        process.send_signal(signal.SIGINT)
        stderr = process.communicate(timeout=120)[1]
    assert process.returncode == 130, stderr[-2000:]
    assert stderr.strip().splitlines()[-1] == "m2d2m train-vq: interrupted; `m2d2m train-vq --resume` continues it"
    (run,) = new_runs()
    assert json.loads((run / "run.json").read_text())["status"] == "interrupted"

    shutil.rmtree(run / "checkpoints")  # as when Ctrl-C comes before the first validation
    assert main(["train-vq", "--config", "vq.yaml", "--resume"]) == 0
    assert f"{run.name} has no checkpoint yet: it trains again from step 0" in capsys.readouterr().err
    assert json.loads((run / "run.json").read_text())["status"] == "finished"


def test_a_killed_tokenize_leaves_no_token_set_and_a_rerun_equals_a_clean_one(matrix_project, tmp_path):
    from pipelines.tokenize import check_tokens, tokenize_dataset

    root = Path(matrix_project["root"])
    data = Path(yaml.safe_load((root / "vq.yaml").read_text())["data"]["dir"])
    copies = killed_and_clean(data, tmp_path, "tokens")
    argv = ["tokenize", "--dataset", "tiny", "--vq", matrix_project["vq"], "--workers", "1"]
    tokens = copies["killed"] / "tokens"
    # killed with every token shard written, before the manifest
    kill_when(
        [*argv, "--data", str(copies["killed"])],
        root,
        "pipelines.features:run_json_tasks",  # imported by pipelines.tokenize where tokens are made
        lambda: any(tokens.glob("*/*.tar")),
    )
    (written,) = (p for p in tokens.iterdir() if p.is_dir())  # beside it, the writer's lock file
    assert not (written / "manifest.json").exists()  # nothing that looks complete
    assert main([*argv, "--data", str(copies["killed"])]) == 0  # the re-run here, on this session's Ray
    clean = copies["clean"] / "tokens" / written.name
    tokenize_dataset(copies["clean"], matrix_project["vq"], clean, workers=1)  # in this process's Ray
    assert check_tokens(written) == []
    shards = lambda folder: {p.name: p.read_bytes() for p in folder.glob("*.tar")}  # noqa: E731
    assert shards(written) == shards(clean) and shards(clean)


@pytest.mark.parametrize("force", [False, True], ids=["new", "force over the old"])
def test_a_killed_testset_leaves_no_half_set_and_a_rerun_equals_a_clean_one(matrix_project, tmp_path, force):
    from pipelines.testset import build_testset, check_testset

    root = Path(matrix_project["root"])
    copies = killed_and_clean(root / "data", tmp_path, "testsets", "tokens")
    parameters = {"n": 2, "seed": 11, "mirrors": "distinct"}
    clean = Path(build_testset(copies["clean"], **parameters)["path"])
    sets = copies["killed"] / "testsets"
    target = sets / clean.name
    old = tree_digest(Path(build_testset(copies["killed"], **parameters)["path"])) if force else None
    argv = ["testset", "--dataset", "tiny", "--data", str(copies["killed"]), "--n", "2", "--seed", "11"]
    argv += ["--mirrors", "distinct", *(["--force"] if force else [])]
    # killed once its motions are written into the new set's folder, before its manifest
    written = lambda: any(sets.glob(f".{target.name}.*.partial/motions.npz"))  # noqa: E731
    kill_when(argv, root, "pipelines.testset:_write_npz", written)
    assert tree_digest(target) == old if force else not target.exists()  # nothing half-written looks done
    if force:  # and had the kill come between --force's two renames: the old set is aside, whole
        aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=sets))
        target.rename(aside / target.name)
    assert main(argv) == 0  # the re-run here: a second process would import for seconds
    assert check_testset(target) == []
    assert sorted(p.name for p in sets.iterdir()) == [f".{target.name}.lock", target.name]
    no_manifest = lambda folder: {k: v for k, v in tree_digest(folder).items() if k != "manifest.json"}  # noqa: E731
    assert no_manifest(target) == no_manifest(clean)  # the manifest names the dataset's folder


def test_a_killed_sweep_resumes_without_evaluating_a_finished_trial_again(
    matrix_project, tiny_testset, capfd, monkeypatch
):
    import mlflow

    import m2d2m.progress
    from tests.test_sweep import sweep_config

    root = Path(matrix_project["root"])
    config = root / "killed-sweep.yaml"
    config.write_text(yaml.safe_dump(sweep_config(tiny_testset, max_concurrent=1)), encoding="utf-8")
    evaluations = root / "runs" / "tiny" / "eval"
    before = set(evaluations.iterdir()) if evaluations.exists() else set()

    def finished_evaluations() -> list[Path]:
        new = set(evaluations.glob("*/run.json")) - {run / "run.json" for run in before}
        return [info.parent for info in new if json.loads(info.read_text()).get("status") == "finished"]

    # killed as the driver hears that the first trial finished, before it starts the second
    finished_one = lambda: len(finished_evaluations()) == 1  # noqa: E731
    kill_when(
        ["sweep", "--config", str(config)], root, "orchestration.sweep_lines:TrialLines.on_trial_complete", finished_one
    )
    monkeypatch.setattr(m2d2m.progress, "MIN_SECONDS", 0.0)  # a line for each trial, however quick
    capfd.readouterr()
    assert main(["sweep", "--config", str(config)]) == 0  # the re-run here, its stderr a log
    log = capfd.readouterr().err
    assert len(finished_evaluations()) == 2  # the trial that finished before the kill is not evaluated again
    lines = [line for line in log.splitlines() if line.startswith("sweep killed-sweep: ")]
    assert lines and lines[-1].startswith("sweep killed-sweep: 2/2 trial (100 %)"), log[-3000:]

    sweep_dir = root / "runs" / "tiny" / "sweep" / "killed-sweep"
    summary = json.loads((sweep_dir / "summary.json").read_text(encoding="utf-8"))
    assert [row["ts"] for row in summary] == [2, 4] and all(row["multi/tps/jerk"] is not None for row in summary)
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{root / 'mlflow.db'}")
    parent = client.get_run(json.loads((sweep_dir / "sweep.json").read_text(encoding="utf-8"))["parent_run_id"])
    children = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent.info.run_id}'")
    assert parent.info.status == "FINISHED"
    assert sorted(run.info.status for run in children) == ["FINISHED", "FINISHED"]
    assert len({run.info.run_name for run in children}) == 2


def test_a_killed_generation_leaves_no_file_that_looks_complete(matrix_project):
    from PIL import Image

    root = Path(matrix_project["root"])
    runs = root / "runs" / "tiny" / "generate"
    before = set(runs.iterdir()) if runs.exists() else set()

    def writing_the_gif() -> bool:
        return any("gif" in path.name for run in set(runs.glob("*")) - before for path in run.iterdir())

    argv = [
        "generate",
        "a person walks forward",
        "a person jumps",
        "--seconds",
        "4",
        "--dataset",
        "tiny",
        "--formats",
        "npy",
        "gif",
        "--no-track",
    ]
    kill_when(argv, root, GIF_FRAME, writing_the_gif)  # its first frame written
    (killed,) = set(runs.iterdir()) - before
    assert json.loads((killed / "run.json").read_text())["status"] != "finished"
    assert main(argv) == 0
    (done,) = set(runs.iterdir()) - before - {killed}
    assert json.loads((done / "run.json").read_text())["status"] == "finished"
    frames = len(np.load(done / "motion.npy"))
    with Image.open(done / "motion.gif") as image:
        assert frames == image.n_frames == 160
    if (killed / "motion.gif").exists():  # only ever a whole animation under the final name
        with Image.open(killed / "motion.gif") as image:
            assert image.n_frames == frames


@pytest.mark.slow
@pytest.mark.parametrize(
    "out, pause_after",
    [("clip.gif", GIF_FRAME), ("clip.bvh", "numpy:savetxt")],  # a GIF's first frame, a BVH's whole text
    ids=["render", "export"],
)
def test_a_killed_render_or_export_leaves_no_file_and_a_rerun_leaves_no_trace(tmp_path, monkeypatch, out, pause_after):
    from PIL import Image

    frames = 80
    np.save(tmp_path / "clip.npy", pose_clip(T2M, frames, seed=5))
    argv = ["render" if out.endswith(".gif") else "export", "clip.npy", "--out", out]
    # a render writes .clip.<pid>.partial.gif; an export the same BVH in its folder .clip.<pid>.partial
    kill_when(argv, tmp_path, pause_after, lambda: any(tmp_path.rglob(".clip.*.partial.*")))
    assert not (tmp_path / out).exists()
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["clip.npy", out])  # the killed write's file went
    if out.endswith(".gif"):
        with Image.open(tmp_path / out) as image:
            assert image.n_frames == frames
    else:
        header, rows = (tmp_path / out).read_text(encoding="utf-8").split("Frame Time:")
        assert f"Frames: {frames}\n" in header and len(rows.strip().splitlines()) == 1 + frames  # its time, its rows


def without_write_permission(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``m2d2m argv`` as a user that folder permissions bind: root gives up the capabilities that
    let it write anywhere (util-linux's setpriv), so a read-only folder is read-only to it too."""
    privileges = ["dac_override", "dac_read_search", "fowner"]
    dropped = ",".join(f"-{name}" for name in privileges)
    prefix = ["setpriv", f"--inh-caps={dropped}", f"--bounding-set={dropped}"] if os.geteuid() == 0 else []
    command = [*prefix, sys.executable, "-m", "orchestration.cli", *argv]
    return subprocess.run(command, cwd=cwd, env=cli_env(), capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def read_only_project(matrix_project, tmp_path_factory) -> Iterator[Path]:
    """A copy of the trained project whose ``runs/`` and ``data/`` (without token sets or test
    sets, so that tokenize and testset would write) and ``ro/`` may be read but not written."""
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        pytest.skip("running as root without util-linux's setpriv, nothing is read-only")
    root = tmp_path_factory.mktemp("read-only")
    source = Path(matrix_project["root"])
    shutil.copytree(source / "runs", root / "runs")
    shutil.copytree(source / "data", root / "data", ignore=shutil.ignore_patterns("tokens", "testsets"))
    shutil.copytree(source / "raw", root / "raw")
    shutil.copy(source / "vq.yaml", root / "vq.yaml")
    (root / "ro").mkdir()
    np.save(root / "clip.npy", pose_clip(T2M, 40, seed=5))
    folders = [
        root / "ro",
        *(d for top in ("runs", "data") for d in [root / top, *(root / top).rglob("*")] if d.is_dir()),
    ]
    for folder in folders:
        folder.chmod(0o555)
    yield root
    for folder in folders:
        folder.chmod(0o755)


READ_ONLY_CASES = [
    ["synthesize", "--out", "ro/raw", "--clips", "3"],
    ["data", "--raw", "raw", "--out", "ro/data"],
    ["tokenize", "--dataset", "tiny", "--data", "data", "--vq", "latest"],
    ["testset", "--dataset", "tiny", "--data", "data", "--n", "2"],
    ["train-vq", "--config", "vq.yaml"],  # every verb that makes a run folder does it through new_run_dir
    ["export", "clip.npy", "--out", "ro/clip.bvh"],
]


@pytest.mark.parametrize("argv", READ_ONLY_CASES, ids=[_case_id(a) for a in READ_ONLY_CASES])
def test_a_folder_it_may_not_write_is_one_line(argv, read_only_project):
    kept = ("runs", "data", "ro")
    before = [tree_digest(read_only_project / folder) for folder in kept]
    done = without_write_permission(argv, read_only_project)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith(f"m2d2m {argv[0]}: error: ")
    assert "permission denied" in lines[0].lower()
    assert [tree_digest(read_only_project / folder) for folder in kept] == before


@pytest.mark.parametrize("in_the_way", ["runs/elsewhere", "runs/elsewhere/generate"])
def test_a_file_where_a_run_folder_should_be_is_one_line(matrix_project, tmp_path, monkeypatch, capfd, in_the_way):
    from orchestration.errors import UserError
    from orchestration.runs import new_run_dir

    monkeypatch.chdir(tmp_path)
    (tmp_path / in_the_way).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / in_the_way).write_text("not a folder\n", encoding="utf-8")
    with pytest.raises(UserError, match="cannot make the run folder runs/elsewhere/generate/.*must be folders"):
        new_run_dir("elsewhere", "generate")
    capfd.readouterr()
    argv = ["generate", "a person walks", "--dataset", "elsewhere", "--checkpoint", matrix_project["model"]]
    assert main(argv + ["--seconds", "1", "--no-track"]) == 2
    err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("m2d2m generate: error: cannot make the run folder"), err


def test_a_killed_evaluation_resumes_from_its_finished_batches_to_the_clean_result(matrix_project, tiny_testset):
    root = Path(matrix_project["root"])
    runs = root / "runs" / "tiny" / "eval"
    argv = ["evaluate", "--dataset", "tiny", "--testset", str(tiny_testset), "--method", "tps", "--repeats", "1"]
    argv += ["--ts", "4", "--batch-size", "3"]
    before = set(runs.iterdir()) if runs.exists() else set()
    # killed once the first batch is kept
    kill_when(argv, root, "orchestration.evaluate.jobs:KeptBatches.save", lambda: any(runs.glob("*/batches/*/*.npz")))
    (killed,) = {run for run in set(runs.iterdir()) - before if run.is_dir()}
    assert json.loads((killed / "run.json").read_text())["status"] == "running"
    assert main(["evaluate", "--dataset", "tiny", "--resume", killed.name, "--batch-size", "3"]) == 0
    assert main(argv) == 0  # a clean run of the same settings
    (clean,) = {run for run in set(runs.iterdir()) - before - {killed} if run.is_dir()}
    for result in sorted((clean / "results").glob("*.json")):
        resumed = json.loads((killed / "results" / result.name).read_text())["metrics"]
        assert resumed == pytest.approx(json.loads(result.read_text())["metrics"], rel=1e-4), result.name
    assert not (killed / "batches").exists() or not any((killed / "batches").iterdir())


CODE_FILE_OPTIONS = [
    ["generate", "a person walks", "--dataset", "tiny", "--checkpoint", "{tmp}/code.pt"],
    ["generate", "a person walks", "--dataset", "tiny", "--model", "mmm", "--checkpoint", "{tmp}/code.pt"],
    ["generate", "a person walks", "--dataset", "tiny", "--model", "motiondiffuse", "--checkpoint", "{tmp}/code.pt"],
    ["generate", "a person walks", "--dataset", "tiny", "--model", "mmm-body", "--checkpoint", "{tmp}/code.pt"],
    ["evaluate", "--dataset", "tiny", "--checkpoint", "{tmp}/code.pt"],
    ["evaluate", "--dataset", "tiny", "--evaluator", "{tmp}/code.pt"],
    ["tokenize", "--dataset", "tiny", "--vq", "{tmp}/code.pt"],
    ["train-diffusion", "--config", "{root}/diffusion.yaml", "--set", "vq={tmp}/code.pt"],
    ["train-mmm", "--config", "{root}/mmm.yaml", "--set", "vq={tmp}/code.pt"],
    ["render", "{tmp}/code.pt", "--out", "{tmp}/out.gif"],
]


@pytest.mark.parametrize("argv", CODE_FILE_OPTIONS, ids=[_case_id(a) for a in CODE_FILE_OPTIONS])
def test_a_model_file_that_would_run_code_runs_nothing(argv, matrix_project, capfd):
    marker = Path(matrix_project["tmp"]) / "code-ran"
    capfd.readouterr()
    assert main([a.format(**matrix_project) for a in argv]) == 2
    err = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "error:" in err[0], err
    assert not marker.exists(), "unpickling the model file ran its code"
