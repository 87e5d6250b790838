"""Builders of test inputs shared by several test files."""

from __future__ import annotations

import io
import socket
from pathlib import Path

import numpy as np
import torch
import yaml

from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.rotations import qnormalize, quat_from_axis_angle
from m2d2m.motion.representation.skeleton import Skeleton
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE, VQConfig
from pipelines.shards import iter_tar_samples

TINY_VQ = VQConfig(width=32, code_dim=16, codebook_size=32, depth=1)


def pose_clip(skeleton: Skeleton, frames: int, seed: int, lengths: np.ndarray | None = None) -> np.ndarray:
    """A moving, turning body built by forward kinematics with smooth random joint rotations."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, frames)[:, None, None]
    axes = rng.normal(size=(1, skeleton.num_joints, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = 0.4 * np.sin(2 * np.pi * (t[..., 0] * rng.uniform(0.5, 2.0, skeleton.num_joints)))
    local = quat_from_axis_angle(axes, angles)
    yaw = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 1.5 * t[:, 0, 0])
    local[:, 0] = yaw
    scale = skeleton.leg_length(skeleton.bone_lengths)
    root = np.stack(
        [scale * np.sin(3 * t[:, 0, 0]), np.full(frames, 1.1 * scale), 2.0 * scale * t[:, 0, 0]],
        axis=-1,
    )
    offsets = skeleton.offsets(lengths)
    return skeleton.forward_kinematics(qnormalize(local), root, offsets).astype(np.float32)


CAPTIONS = (
    "a person walks forward and then turns left#a/DET person/NOUN walk/VERB forward/ADV and/CCONJ then/ADV turn/VERB left/ADV#0.0#0.0",
    "someone jumps on the spot#someone/PRON jump/VERB on/ADP the/DET spot/NOUN#0.0#0.0",
    "a man waves his right hand#a/DET man/NOUN wave/VERB his/PRON right/ADJ hand/NOUN#0.5#2.0",
)


def write_corpus(root, splits: dict[str, int], skeleton, kind: str = "joints", seed: int = 0) -> dict[str, list[str]]:
    """A small corpus in HumanML3D's layout: valid clips of 60–120 frames with three tagged
    captions each. Returns the ids per split."""
    from m2d2m.motion.representation.features import joints_to_features

    folder = root / ("joints" if kind == "joints" else "new_joint_vecs")
    folder.mkdir(parents=True, exist_ok=True)
    (root / "texts").mkdir(exist_ok=True)
    ids: dict[str, list[str]] = {}
    index = 0
    for split, count in splits.items():
        ids[split] = []
        for _ in range(count):
            motion_id = f"{index:06d}"
            joints = pose_clip(skeleton, 61 + (index * 7) % 60, seed=seed + index)
            motion = joints if kind == "joints" else joints_to_features(joints, skeleton)
            np.save(folder / f"{motion_id}.npy", motion)
            (root / "texts" / f"{motion_id}.txt").write_text("\n".join(CAPTIONS) + "\n", encoding="utf-8")
            ids[split].append(motion_id)
            index += 1
        (root / f"{split}.txt").write_text("".join(f"{i}\n" for i in ids[split]), encoding="utf-8")
    return ids


def random_vq(path, data_dir, seed):
    """A random tiny VQ-VAE whose codebook is initialised from encoder outputs of real motions
    (one training-mode forward), so tokens use many codes rather than all being code 0."""
    torch.manual_seed(seed)
    model = MotionVQVAE(TINY_VQ)
    normalizer = Normalizer.load(data_dir / "stats.npz")
    _, members = next(iter_tar_samples(data_dir / "shards" / "train-000000.tar"))
    motion = np.load(io.BytesIO(members["motion.npy"]))
    model.train()
    model(torch.from_numpy(normalizer.normalize(motion))[None])
    model.eval()
    VQ_FORMAT.save(path, model=model, normalizer=normalizer, skeleton="t2m", extra={})
    return model, normalizer


# A VQ-VAE training config small enough for tests (data.dir is filled in per test).
TINY_VQ_RUN = {
    "dataset": "tiny",
    "seed": 1,
    "data": {"dir": None, "window": 32, "batch_size": 4, "num_workers": 0},
    "model": {
        "width": 16,
        "depth": 1,
        "dilation_growth": 3,
        "down_t": 2,
        "code_dim": 8,
        "codebook_size": 16,
        "ema_decay": 0.99,
    },
    "loss": {"recon": 1.0, "joint": 0.5, "commit": 0.02},
    "optim": {
        "lr": 1e-3,
        "betas": [0.9, 0.99],
        "weight_decay": 0.0,
        "warmup_steps": 2,
        "milestones": [100],
        "gamma": 0.05,
        "grad_clip": None,
    },
    "trainer": {
        "max_steps": 6,
        "val_every_steps": 3,
        "val_batches": 1,
        "gif_every": 1,
        "accelerator": "cpu",
        "devices": 1,
        "precision": "auto",
    },
}


# A denoiser training config small enough for tests (the VQ run is the dataset's latest).
TINY_DIFFUSION = {
    "dataset": "tiny",
    "seed": 1,
    "vq": "latest",
    "data": {"batch_size": 4, "num_workers": 0, "max_tokens": None},
    "text": {"kind": "learned", "dim": 16, "layers": 1, "heads": 2},
    "text_drop": 0.1,
    "denoiser": {
        "layers": 1,
        "heads": 2,
        "width": 16,
        "ffn": 32,
        "dropout": 0.0,
        "max_distance": 16,
        "num_buckets": 8,
        "positions": "relative",
    },
    "diffusion": {
        "steps": 8,
        "kind": "dynamic",
        "eta": 0.5,
        "distance": "l2_rank",
        "schedule": "linear",
        "aux_weight": 5e-4,
        "timestep_sampling": "uniform",
    },
    "optim": {
        "lr": 1e-3,
        "betas": [0.9, 0.99],
        "weight_decay": 0.0,
        "warmup_steps": 1,
        "milestones": [100],
        "gamma": 0.1,
        "grad_clip": 1.0,
    },
    "trainer": {
        "max_steps": 4,
        "val_every_steps": 2,
        "val_batches": 1,
        "gif_every": 2,
        "accelerator": "cpu",
        "devices": 1,
        "precision": "auto",
    },
    "preview": {"prompts": ["a person walks forward"], "seconds": [1.0], "guidance": 2.0},
}

# An MMM training config small enough for tests: the denoiser's data, text, optimiser and trainer
# sections, MMM's own network and masking.
TINY_MMM = {
    **{key: TINY_DIFFUSION[key] for key in ("dataset", "seed", "vq", "data", "text", "text_drop", "optim", "trainer")},
    "transformer": {
        "width": 16,
        "heads": 2,
        "layers": 2,
        "cross_layers": 1,
        "ffn": 32,
        "dropout": 0.0,
        "max_tokens": 50,
    },
    "masking": {"alpha": 0.5},
    "preview": {"prompts": ["a person walks forward"], "seconds": [1.0]},
}

# MMM's upper-body editor at test size, over both part tokenizers' latest runs
# (:func:`write_part_tokenizer_configs`).
TINY_BODY = {
    **{key: value for key, value in TINY_MMM.items() if key != "preview"},
    "vq": {"upper": "latest", "lower": "latest"},
    "masking": {"alpha": 0.5, "lower_most": 0.3},
}


def write_part_tokenizer_configs(project: Path) -> list[Path]:
    """``vq-upper.yaml`` and ``vq-lower.yaml`` beside the project's ``vq.yaml``: its tokenizer
    for one body part each, what ``m2d2m train-vq`` trains before the upper-body editor."""
    vq = yaml.safe_load((project / "vq.yaml").read_text(encoding="utf-8"))
    paths = []
    for part in ("upper", "lower"):
        paths.append(project / f"vq-{part}.yaml")
        paths[-1].write_text(yaml.safe_dump({**vq, "model": {**vq["model"], "part": part}}), encoding="utf-8")
    return paths


# A MotionDiffuse training config small enough for tests (data.dir is filled in per test): 50 diffusion
# steps, so that sampling with every step stays quick.
TINY_MOTIONDIFFUSE = {
    "dataset": "tiny",
    "seed": 1,
    "data": {"dir": None, "batch_size": 4, "num_workers": 0, "min_frames": 20, "max_frames": 120},
    "text": TINY_DIFFUSION["text"],
    "text_drop": 0.1,
    "network": {
        "width": 16,
        "layers": 1,
        "heads": 2,
        "ffn": 32,
        "dropout": 0.0,
        "text_width": 16,
        "text_layers": 1,
        "text_heads": 2,
        "text_ffn": 32,
        "max_frames": 160,
        "attention": "linear",
    },
    "diffusion": {"steps": 50, "beta_start": 1e-4, "beta_end": 0.02},
    "optim": TINY_DIFFUSION["optim"],
    "trainer": TINY_DIFFUSION["trainer"],
    "preview": {"prompts": ["a person walks forward"], "seconds": [1.0]},
}

# Evaluator sizes small enough for tests (EvaluatorConfig fields).
TINY_EVALUATOR = {
    "movement_hidden": 16,
    "movement_latent": 16,
    "motion_hidden": 24,
    "text_hidden": 16,
    "embedding_dim": 8,
    "word_dim": 12,
    "word_features": "learned",
    "max_motion_length": 48,
}


def free_port() -> int:
    """A TCP port nobody listens on right now, for servers a test starts."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def latest_evaluation(project: Path) -> Path:
    """The run directory of the newest finished `m2d2m evaluate` on the tiny dataset of ``project``."""
    stage = project / "runs" / "tiny" / "eval"
    return stage / (stage / "latest").read_text(encoding="utf-8").strip()


def on_the_floor_as(reference: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """``joints`` (T, J, 3) turned about the vertical and moved on the floor onto ``reference``'s
    place (least squares): the actions after an edit continue from where the new motion ends."""
    ours, theirs = joints[..., [0, 2]].reshape(-1, 2), reference[..., [0, 2]].reshape(-1, 2)
    u, _, vt = np.linalg.svd((ours - ours.mean(0)).T @ (theirs - theirs.mean(0)))
    turn = u @ vt
    if np.linalg.det(turn) < 0:
        turn = u @ np.diag([1.0, -1.0]) @ vt
    placed = joints.copy()
    placed[..., [0, 2]] = (joints[..., [0, 2]] - ours.mean(0)) @ turn + theirs.mean(0)
    return placed


def one_line_error(argv: list[str], capture) -> str:
    """Run the command line on ``argv`` (``capture``: pytest's capsys or capfd): it must fail with
    status 2 and one line on stderr, no traceback, argparse's refusals included; that line."""
    from orchestration.cli import main

    capture.readouterr()
    try:
        status = main(argv)
    except SystemExit as stopped:  # argparse's errors
        status = stopped.code
    err = capture.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert status == 2 and len(lines) == 1 and "Traceback" not in err, (status, err)
    return lines[0]


XBOT = Path(__file__).parent / "fixtures" / "mixamo" / "xbot-skeleton.glb"


def xbot_with_a_mesh(path: Path, megabytes: float = 3.0) -> Path:
    """Mixamo's X Bot (tests/fixtures/mixamo) with a skinned mesh of ``megabytes``, as a character
    comes from Mixamo or Blender rather than the fixture's bare skeleton: a valid GLB (glTF 2.0
    §3.7.3: a mesh node naming the skin, its vertices' POSITION, JOINTS_0 and WEIGHTS_0 in the
    binary chunk), its vertices scattered over the body's height, each bound to the hips."""
    import pygltflib as gl

    gltf = gl.GLTF2().load(str(XBOT))
    count = int(megabytes * 2**20) // (12 + 4 + 16)  # a vertex's position, joints and weights
    rng = np.random.default_rng(0)
    positions = (rng.uniform([-40, -10, 0], [40, 10, 180], (count, 3))).astype(np.float32)  # the Armature's cm, Z up
    joints = np.zeros((count, 4), np.uint8)
    weights = np.tile(np.array([1, 0, 0, 0], np.float32), (count, 1))
    blob = positions.tobytes() + joints.tobytes() + weights.tobytes()
    views, start = [], 0
    for array in (positions, joints, weights):
        views.append(gl.BufferView(buffer=0, byteOffset=start, byteLength=array.nbytes, target=gl.ARRAY_BUFFER))
        start += array.nbytes
    gltf.bufferViews = views
    gltf.accessors = [
        gl.Accessor(
            bufferView=0,
            componentType=gl.FLOAT,
            count=count,
            type=gl.VEC3,
            min=positions.min(axis=0).tolist(),
            max=positions.max(axis=0).tolist(),
        ),
        gl.Accessor(bufferView=1, componentType=gl.UNSIGNED_BYTE, count=count, type=gl.VEC4),
        gl.Accessor(bufferView=2, componentType=gl.FLOAT, count=count, type=gl.VEC4),
    ]
    gltf.buffers = [gl.Buffer(byteLength=len(blob))]
    attributes = gl.Attributes(POSITION=0, JOINTS_0=1, WEIGHTS_0=2)
    gltf.meshes = [gl.Mesh(name="body", primitives=[gl.Primitive(attributes=attributes, mode=gl.POINTS)])]
    armature = next(i for i, node in enumerate(gltf.nodes) if node.name == "Armature")
    gltf.nodes.append(gl.Node(name="body", mesh=0, skin=0))
    gltf.nodes[armature].children = [*gltf.nodes[armature].children, len(gltf.nodes) - 1]
    gltf.set_binary_blob(blob)
    gltf.save_binary(str(path))
    return path


def lacking(*packages: str) -> str:
    """Python source that makes ``packages`` unimportable in the interpreter that runs it: the
    preamble of a ``-c`` script or a ``sitecustomize.py``, to run code as on a machine without them
    (a bare GPU machine: bench/gpu_carry.py)."""
    return f"""
import sys
class Lacking:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {set(packages)!r}:
            raise ImportError(f"no module named {{name!r}} on this machine")
sys.meta_path.insert(0, Lacking())
"""
