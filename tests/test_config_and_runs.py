"""Configs with checked overrides, and run directories with their `latest` marker."""

import json
import shutil
from pathlib import Path

import pytest

from orchestration.config import apply_overrides, flatten, load_config
from orchestration.errors import UserError
from orchestration.registry import model
from orchestration.runs import find_run, latest_run, mark_latest, new_run_dir, newest_run, write_run_info

BASE = {"seed": 1, "model": {"width": 128, "depth": 2}, "optim": {"betas": [0.9, 0.99], "lr": 2e-4}}


def test_overrides_parse_values_as_yaml():
    config = apply_overrides(BASE, ["model.width=64", "optim.lr=1e-3", "optim.betas=[0.5, 0.9]", "seed=7"])
    assert config["model"]["width"] == 64 and config["optim"]["lr"] == 1e-3
    assert config["optim"]["betas"] == [0.5, 0.9] and config["seed"] == 7
    assert BASE["model"]["width"] == 128  # the original is untouched


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("model.widht=64", "no key 'widht' in model; known keys: depth, width"),
        ("modle.width=64", "no key 'modle' in the top level"),
        ("model=3", "model is a section"),
        ("model.width", "expected key.sub=value"),
        ("seed.x=1", "not a section"),
    ],
)
def test_bad_overrides_name_the_problem(override, message):
    with pytest.raises(UserError, match=message):
        apply_overrides(BASE, [override])


def test_repository_configs_load_and_flatten():
    for name in ("demo", "humanml3d", "kit"):
        config = load_config("vq", name)
        flat = flatten(config)
        assert flat["model.down_t"] == 2 and flat["loss.joint"] == 0.5 and flat["loss.commit"] == 0.02
    assert load_config("vq", "humanml3d")["model"]["codebook_size"] == 512


@pytest.mark.parametrize(
    ("stage", "ours"),
    [
        (
            "m2d2m",
            {"denoiser.positions", "diffusion.aux_weight", "sampling.steps", "sampling.guidance", "preview.guidance"},
        ),
        ("motiondiffuse", {"diffusion.prediction"}),
    ],
)
def test_the_demo_departs_from_the_papers_setting_only_where_docs_say_ours(stage, ours):
    """``paper-demo.yaml`` is a copy of ``demo.yaml`` with the paper's values: an edit to one that
    misses the other would silently change what "the paper's setting" measures."""
    demo, paper = flatten(_read_as_its_stage_does(stage, "demo")), flatten(_read_as_its_stage_does(stage, "paper-demo"))
    assert {key for key in demo.keys() | paper.keys() if demo.get(key) != paper.get(key)} == ours


def _read_as_its_stage_does(stage: str, path: str) -> dict:
    from orchestration.sweep import load_sweep_config
    from orchestration.train import TRAINING_DEFAULTS

    if stage == "sweep":
        return load_sweep_config(path, [])
    if stage in ("vq", "evaluator"):
        return load_config(stage, path, defaults=TRAINING_DEFAULTS)
    entry = model(stage)
    return entry.load("recipe").load_config(entry, path)


@pytest.mark.parametrize(
    "path", sorted(Path("configs").glob("*/*.yaml")), ids=lambda path: f"{path.parent.name}/{path.name}"
)
def test_every_shipped_config_reads_against_the_other_configs_of_its_stage(path):
    """Each file's keys are checked against its siblings': a key only one file has must be declared
    optional (a recipe's ``optional``, the text encoder's options), or the others' check fails."""
    _read_as_its_stage_does(path.parent.name, str(path))


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda text: text.replace("  window:", "  windw:"),
            "unknown key data.windw (did you mean data.window?); missing data.window",
        ),
        (
            lambda text: text[: text.index("model:")],
            "missing loss (the whole section), model (the whole section), optim (the whole section)",
        ),
        (lambda text: text + "trainer_extra: 1\n", "unknown key trainer_extra"),
    ],
    ids=["typo", "truncated", "unknown top-level key"],
)
def test_a_config_file_with_a_typo_or_cut_short_is_one_line_before_any_run_exists(
    tmp_path, monkeypatch, capsys, edit, message
):
    """Issue 38, item 1: a typo inside a file was `KeyError: 'window'` after the run was made, and that
    failed run was the one `--resume` then picked."""
    from orchestration.cli import main

    shutil.copytree(Path("configs"), tmp_path / "configs")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.yaml").write_text(edit((tmp_path / "configs/vq/demo.yaml").read_text()), encoding="utf-8")
    assert main(["train-vq", "--config", "mine.yaml"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("m2d2m train-vq: error: mine.yaml: ") and message in line
    assert not (tmp_path / "runs").exists()


def test_a_bad_diffusion_setting_is_refused_before_tokenizing_and_before_a_run_exists(tmp_path, monkeypatch, capsys):
    from orchestration.cli import main

    shutil.copytree(Path("configs"), tmp_path / "configs")
    monkeypatch.chdir(tmp_path)  # no data and no VQ run here: reading either would fail differently
    assert main(["train-diffusion", "--set", "diffusion.kind=dinamic"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == "m2d2m train-diffusion: error: diffusion: kind must be one of ('uniform', 'dynamic'), got 'dinamic'"
    assert not (tmp_path / "runs").exists()


def test_resume_passes_over_a_run_that_failed_before_training_began(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    interrupted = new_run_dir("tiny", "vq")
    write_run_info(interrupted, status="interrupted", mlflow_run_id="a" * 32)
    never = new_run_dir("tiny", "vq")  # newer: its data could not be read
    write_run_info(never, status="failed", error="NotInProject: no finished vq run")
    assert newest_run("tiny", "vq") == interrupted
    shutil.rmtree(interrupted)
    with pytest.raises(UserError, match="nothing to resume: no vq run .* that began training"):
        newest_run("tiny", "vq")


def test_unknown_config_lists_the_available_ones():
    with pytest.raises(UserError, match="available: bandai-namco, demo, humanml3d, kit"):
        load_config("vq", "nope")


def test_runs_are_found_by_name_mlflow_id_and_latest_marker(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UserError, match="run `make train-vq` first"):
        latest_run("synthetic", "vq", "make train-vq")
    first = new_run_dir("synthetic", "vq")
    write_run_info(first, status="finished", mlflow_run_id="abc123")
    mark_latest(first)
    second = new_run_dir("synthetic", "vq")
    write_run_info(second, status="running")
    assert latest_run("synthetic", "vq", "make train-vq").name == first.name
    assert newest_run("synthetic", "vq").name == second.name
    assert find_run("abc123", "synthetic", "vq").name == first.name
    assert find_run(first.name, "synthetic", "vq").name == first.name
    with pytest.raises(UserError, match="no vq run 'zzz'"):
        find_run("zzz", "synthetic", "vq")


def test_evaluation_settings_round_trip_through_their_record():
    from dataclasses import asdict

    from orchestration.evaluate.settings import Candidate, EvalSettings

    settings = EvalSettings(
        candidates=(Candidate("mmm", "model.pt", ("transition",), {"temperature": 0.5}, ("inbetween",)),),
        testset=None,
        evaluator="evaluator.pt",
        glove=None,
        meta=None,
        repeats=1,
        single=True,
        editing=("inbetween",),
        regenerate=3,
    )
    recorded = json.loads(json.dumps(asdict(settings)))  # as run.json holds it: lists, not tuples
    assert EvalSettings.from_dict(recorded) == settings


@pytest.mark.parametrize(
    "override, message",
    [
        ("optim.lr=abc", "optim.lr takes a number, got 'abc'"),
        ("optim.betas=0.9", "optim.betas takes a list"),
        ("model.width=[1]", "model.width takes a number"),
    ],
)
def test_a_value_of_another_kind_than_the_files_is_refused(override, message):
    with pytest.raises(UserError, match=message.replace("[", r"\[")):
        apply_overrides(BASE, [override])


def test_texts_and_nulls_in_a_file_take_any_value():
    config = apply_overrides(
        {"trainer": {"devices": "auto", "clip": None, "lr": 1.0}},
        ["trainer.devices=2", "trainer.clip=0.5", "trainer.lr=null"],
    )
    assert config["trainer"] == {"devices": 2, "clip": 0.5, "lr": None}
