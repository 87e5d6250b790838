"""Configs with checked overrides, and run directories with their `latest` marker."""

import pytest

from orchestration.config import apply_overrides, flatten, load_config
from orchestration.errors import UserError
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
