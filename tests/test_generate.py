"""`m2d2m generate` and M2D2M's generator on a tiny trained checkpoint: files, MLflow, editing,
every baseline, and a one-line error with exit status 2 for each bad input."""

from pathlib import Path

import mlflow
import numpy as np
import pytest
import torch

from m2d2m.generators.m2d2m.checkpoint import load_m2d2m
from m2d2m.generators.m2d2m.generator import M2D2MGenerator
from m2d2m.motion.clip import Motion
from orchestration.cli import main
from orchestration.errors import UserError
from orchestration.generate import PromptPlanner, edit, generate, load_generator

PROMPTS = ["a person walks forward", "a person jumps", "a person waves their right hand"]


@pytest.fixture(scope="module")
def trained(trained_project) -> Path:
    """A project holding a tiny VQ-VAE and denoiser run: this module's copy of conftest's trained store."""
    return trained_project


@pytest.fixture
def generator(trained) -> M2D2MGenerator:
    return load_generator("m2d2m", "latest", dataset="tiny")


def test_the_checkpoint_is_self_contained(trained, tmp_path):
    model = next((trained / "runs" / "tiny" / "m2d2m").glob("*/model.pt"))
    moved = tmp_path / "elsewhere.pt"
    moved.write_bytes(model.read_bytes())  # no run directory, no vq.pt beside it
    checkpoint = load_m2d2m(moved)
    assert checkpoint.codec.vq.config.codebook_size == checkpoint.denoiser.config.codebook_size == 16
    assert checkpoint.schedule.config.kind == "dynamic" and checkpoint.codec.skeleton.name == "t2m"
    assert checkpoint.lengths.median >= 1 and checkpoint.lengths.longest >= checkpoint.lengths.median


def test_generate_returns_a_motion_with_one_range_per_action(generator):
    motion = generate(generator, PROMPTS, seconds=[1.6, 1.2, 2.0], seed=3, ts=4, split=False)
    assert isinstance(motion, Motion) and motion.fps == 20.0 and generator.codec.frames_per_token == 4
    assert motion.ranges == [(0, 32), (32, 56), (56, 96)] and motion.boundaries == [32, 56]
    assert motion.features.shape == (96, 263) and motion.joints.shape == (96, 22, 3)
    assert motion.tokens.shape == (24,) and motion.actions == PROMPTS
    again = generate(generator, PROMPTS, seconds=[1.6, 1.2, 2.0], seed=3, ts=4, split=False)
    assert np.array_equal(motion.joints, again.joints)


@pytest.mark.parametrize("method", ["tps", "independent", "handshake", "slerp"])
def test_every_method_gives_a_whole_motion(generator, method):
    motion = generate(generator, PROMPTS[:2], seconds=[2.0, 2.0], method=method, ts=4, split=False)
    assert np.isfinite(motion.joints).all() and np.isfinite(motion.features).all()
    assert len(motion.features) == len(motion.joints)
    lengths = [end - first for first, end in motion.ranges]
    if method == "slerp":  # the second action gives its first 8 frames to the transition window
        assert lengths == [40, 32] and motion.ranges[1][0] == 48
    else:
        assert lengths == [40, 40] and motion.ranges[1][0] == 40


def test_lengths_default_to_the_corpus_prior(generator):
    actions, frames = PromptPlanner(generator).plan(PROMPTS, split=False)
    assert actions == PROMPTS and frames == [generator.checkpoint.lengths.median * 4] * 3


def test_editing_keeps_the_kept_span(generator):
    source = generate(generator, PROMPTS[:2], seconds=[2.0, 2.0], ts=4, split=False, seed=1)
    edited = edit(
        generator, source, keep=[(0.0, 1.0), (3.6, 4.0)], actions=["a person jumps", "a person sits down"], ts=4, seed=2
    )
    vq, normalizer = generator.codec.vq, generator.codec.normalizer
    with torch.no_grad():
        encoded = vq.encode(torch.as_tensor(normalizer.normalize(source.features))[None])[0].numpy()
    assert np.array_equal(edited.tokens[:5], encoded[:5]) and np.array_equal(edited.tokens[18:], encoded[18:])
    assert not np.array_equal(edited.tokens[5:18], encoded[5:18])
    assert edited.actions == ["a person jumps", "a person sits down"] and edited.ranges == source.ranges


def test_reconstruction_decodes_the_segments_tokens_together(generator):
    """The evaluation's codec row: each segment's own tokens, concatenated, decoded in one call."""
    first, second = (
        generate(generator, [p], seconds=[s], split=False, seed=3).features
        for p, s in ((PROMPTS[0], 1.6), (PROMPTS[1], 1.2))
    )
    (motion,) = generator.reconstruct([[first, second]])
    tokens = torch.cat([generator.codec.encode(first), generator.codec.encode(second)])
    assert motion.ranges == [(0, 32), (32, 56)] and np.array_equal(motion.tokens, tokens.numpy())
    assert np.allclose(motion.features, generator.codec.decode(tokens), atol=1e-6)
    assert motion.settings["method"] == "vq reconstruction"


def test_the_command_writes_files_and_logs_to_mlflow(trained, capsys, monkeypatch):
    monkeypatch.chdir(trained)
    out = trained / "out"
    code = main(
        [
            "generate",
            *PROMPTS[:2],
            "--seconds",
            "1.5",
            "--dataset",
            "tiny",
            "--ts",
            "4",
            "--no-split",
            "--out",
            str(out),
            "--name",
            "walk-jump",
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "a person walks forward" in printed and "logged to MLflow run" in printed
    for suffix in (".npy", ".json", ".bvh", ".gif", ".features.npy"):
        assert (out / f"walk-jump{suffix}").exists(), suffix
    run_id = printed.split("logged to MLflow run ")[1].split()[0]
    mlflow.set_tracking_uri(f"sqlite:///{trained / 'mlflow.db'}")
    run = mlflow.get_run(run_id)
    assert run.data.params["method"] == "tps" and run.data.params["ts"] == "4"
    assert "a person jumps" in run.data.params["prompts"] and run.data.tags["stage"] == "generate"
    names = {Path(a.path).name for a in mlflow.MlflowClient().list_artifacts(run_id, "motion")}
    assert {"walk-jump.gif", "walk-jump.npy", "walk-jump.bvh", "walk-jump.json"} <= names


@pytest.mark.parametrize(
    "arguments, message",
    [
        ([], "give at least one prompt"),
        (["a person jumps", "--seconds", "60"], "outside what this model supports"),
        (["a person jumps", "--seconds", "0.05"], "outside what this model supports"),
        (["a person jumps", "--ts", "9"], "T_s must lie in 0..T = 8"),
        (["a person jumps", "--eta", "-1"], "eta must be [0, 100]"),
        (["a person jumps", "--guidance", "-2"], "option guidance must be [0, 20], got -2"),
        (["a person jumps", "--method", "blend"], "unknown method 'blend'"),
        (["a person jumps", "--checkpoint", "no-such-run"], "no m2d2m run 'no-such-run'"),
        (["a person jumps", "--checkpoint", "vq.yaml"], "vq.yaml is not an M2D2M model file"),
        (["a", "b", "--seconds", "1", "2", "3"], "one duration per prompt"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(trained, capsys, monkeypatch, arguments, message):
    monkeypatch.chdir(trained)
    code = main(["generate", *arguments, "--dataset", "tiny", "--no-split", "--no-track", "--out", "bad"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1, err


def test_a_missing_checkpoint_says_what_to_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserError, match="make train-diffusion"):
        load_generator("m2d2m", "latest", dataset="tiny")
