"""Configs with checked overrides, and run directories with their `latest` marker."""

import shutil
from pathlib import Path

import pytest
import yaml

from orchestration.config import apply_overrides, flatten, load_config, rename_keys
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


def test_configs_written_before_a_key_was_renamed_read_under_the_new_name(tmp_path):
    renamed = {"denoiser.condition_drop": "text_drop"}
    old = {"seed": 1, "denoiser": {"layers": 2, "condition_drop": 0.2}}
    assert rename_keys(old, renamed, "old.yaml") == {"seed": 1, "denoiser": {"layers": 2}, "text_drop": 0.2}
    assert old["denoiser"]["condition_drop"] == 0.2  # the original is untouched
    assert rename_keys({"text_drop": 0.3}, renamed, "new.yaml") == {"text_drop": 0.3}
    with pytest.raises(UserError, match="both.yaml: both denoiser.condition_drop and text_drop are set"):
        rename_keys({**old, "text_drop": 0.3}, renamed, "both.yaml")
    demo = yaml.safe_load(open("configs/m2d2m/demo.yaml", encoding="utf-8"))
    demo["denoiser"]["condition_drop"] = demo.pop("text_drop")
    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(demo), encoding="utf-8")
    # an override names the new key even though the file has the old one
    assert load_config("m2d2m", str(path), ["text_drop=0.05"], renamed=renamed)["text_drop"] == 0.05


def test_a_run_recorded_before_a_key_was_renamed_is_joined_under_the_new_name(tmp_path):
    """Every DDP rank that joins a resumed run reads its record's older keys as the resuming one does."""
    from orchestration.train import open_run

    write_run_info(tmp_path, stage="m2d2m", config={"seed": 1, "denoiser": {"layers": 2, "condition_drop": 0.2}})
    run = open_run("m2d2m", "m2d2m", "demo", [], True, join=tmp_path, renamed={"denoiser.condition_drop": "text_drop"})
    assert run.config == {"seed": 1, "denoiser": {"layers": 2}, "text_drop": 0.2}


@pytest.mark.parametrize("name", ["m2d2m", "mmm", "mmm-body", "motiondiffuse"])
def test_every_renamed_key_is_renamed_to_a_key_of_the_models_configs(name):
    """A recipe's ``renamed`` maps old names onto the shipped configs' names, never to a key they lack."""
    entry = model(name)
    for name in ("demo", "humanml3d", "kit"):
        config = flatten(entry.load("recipe").load_config(entry, name))
        for old, new in entry.load("recipe").renamed.items():
            assert new in config and old not in config, (entry.name, name, old)


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
    with pytest.raises(UserError, match="available: demo, humanml3d, kit"):
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


def test_runs_of_the_old_diffusion_stage_still_resolve(tmp_path, monkeypatch):
    """M2D2M's runs lived under runs/<dataset>/diffusion/ before the model registry named the stage
    m2d2m: `latest`, a run name and an MLflow id still find them there."""
    from orchestration.generate import resolve_model_file

    monkeypatch.chdir(tmp_path)
    old = tmp_path / "runs" / "tiny" / "diffusion" / "20250101-000000-abcd"
    old.mkdir(parents=True)
    (old / "run.json").write_text('{"mlflow_run_id": "' + "0" * 32 + '"}', encoding="utf-8")
    (old / "model.pt").write_bytes(b"")
    (old.parent / "latest").write_text(old.name + "\n", encoding="utf-8")
    for reference in ("latest", old.name, "0" * 32):
        assert resolve_model_file("m2d2m", reference, "tiny").resolve() == (old / "model.pt").resolve()


def test_evaluation_settings_recorded_before_the_registry_read_as_m2d2m():
    from orchestration.evaluate import EvalSettings

    recorded = {
        "checkpoint": "model.pt",
        "testset": None,
        "evaluator": "evaluator.pt",
        "glove": None,
        "meta": None,
        "methods": ["tps"],
        "ts": 80,
        "eta": 0.25,
        "guidance": 2.0,
        "repeats": 2,
        "single": False,
    }
    settings = EvalSettings.from_dict(recorded)
    (only,) = settings.candidates
    assert only.model == "m2d2m" and only.options == {"ts": 80, "eta": 0.25, "guidance": 2.0}
    assert only.methods == ("tps",) and only.checkpoint == "model.pt" and settings.repeats == 2


def test_one_model_evaluation_settings_read_as_one_candidate_and_round_trip():
    from dataclasses import asdict

    from orchestration.evaluate import EvalSettings

    recorded = {
        "model": "mmm",
        "checkpoint": "model.pt",
        "testset": None,
        "evaluator": "evaluator.pt",
        "glove": None,
        "meta": None,
        "methods": ["transition"],
        "options": {"temperature": 0.5},
        "repeats": 1,
        "single": True,
    }
    settings = EvalSettings.from_dict(recorded)
    assert settings.models == ("mmm",) and settings.candidates[0].options == {"temperature": 0.5}
    assert EvalSettings.from_dict(asdict(settings)) == settings


def test_sweep_configs_written_before_the_registry_still_load():
    from orchestration.sweep import _upgrade

    config = _upgrade({"kind": "training", "diffusion_config": "demo", "resources": {"cpu": 1, "gpu": 0}})
    assert config["model"] == "m2d2m" and config["train_config"] == "demo" and "diffusion_config" not in config
    assert config["resources"]["workers"] == 0


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
