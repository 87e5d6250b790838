"""A dataset survives a failed, refused or killed rebuild, and no stage reads shards that no longer
match their manifest (docs/data.md, "Rebuilding" and "Reading")."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from m2d2m import integrity
from m2d2m.integrity import verified_paths
from m2d2m.layout import MANIFEST, read_manifest
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from pipelines.shards import ShardWriter, sha256_of, shard_records
from pipelines.testset import build_testset
from pipelines.tokenize import tokenize_dataset
from tests.helpers import one_line_error, random_vq, write_corpus
from training.data.tokens import TokenDataModule


def checksums(directory: Path) -> dict[str, str]:
    """Every file under ``directory`` by relative path, with its sha256."""
    return {
        str(path.relative_to(directory)): sha256_of(path) for path in sorted(directory.rglob("*")) if path.is_file()
    }


def flip_byte(path: Path, offset: int = 1000) -> None:
    """Change one byte in place, keeping the size."""
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def data_command(raw: Path, out: Path, *flags: str) -> list[str]:
    return ["data", "--raw", str(raw), "--out", str(out), "--samples-per-shard", "4", *flags]


@pytest.fixture
def dataset(tmp_path, tiny_data) -> tuple[Path, Path]:
    """(a copy of the tiny dataset, with a token set and a test set of its own, alone in its
    folder; the raw corpus it was built from)."""
    out = tmp_path / "data" / "tiny"
    shutil.copytree(tiny_data, out)
    for derived in ("tokens/vq-run/manifest.json", "testsets/n4-seed0/manifest.json"):
        (out / derived).parent.mkdir(parents=True)
        (out / derived).write_text("{}\n", encoding="utf-8")
    return out, tiny_data.parent / "raw"


def siblings(out: Path) -> set[str]:
    return {path.name for path in out.parent.iterdir()}


def test_a_rebuild_that_fails_leaves_the_dataset_byte_identical(dataset, tmp_path, capsys):
    out, raw = dataset
    no_texts = tmp_path / "no-texts"
    shutil.copytree(raw, no_texts, ignore=shutil.ignore_patterns("texts"))
    before = checksums(out)
    error = one_line_error(data_command(no_texts, out, "--replace"), capsys)
    assert "no valid training motion" in error and "read: no text file" in error
    assert checksums(out) == before
    assert siblings(out) <= {out.name, f".{out.name}.lock"}  # the failed build is gone


def test_replacing_a_dataset_of_another_corpus_needs_replace_and_keeps_derived_sets(dataset, tmp_path, capsys):
    out, raw = dataset
    other = tmp_path / "other-raw"
    write_corpus(other, {"train": 3, "val": 1, "test": 1}, T2M, seed=5)
    before = checksums(out)
    error = one_line_error(data_command(other, out), capsys)
    assert "--replace" in error and str(raw.resolve()) in error
    assert checksums(out) == before

    assert main(data_command(other, out, "--replace")) == 0
    manifest = read_manifest(out)
    assert manifest["config"]["raw"] == str(other.resolve()) and manifest["splits"]["train"]["originals"] == 3
    assert main(["data", "--check", str(out)]) == 0
    kept = {name: digest for name, digest in before.items() if name.startswith(("tokens/", "testsets/"))}
    assert len(kept) == 2 and {name: checksums(out)[name] for name in kept} == kept
    assert siblings(out) == {out.name, f".{out.name}.lock"}  # no build or backup left behind


def test_a_rerun_after_a_kill_between_the_renames_restores_then_rebuilds(dataset):
    out, raw = dataset
    # What SIGKILL leaves after the old dataset was renamed aside but before the new one went in.
    out.rename(out.parent / f".{out.name}.previous")
    stale = out.parent / f".{out.name}.building-0badc0de" / "shards"
    stale.mkdir(parents=True)
    (stale / "train-000000.tar.partial").write_bytes(b"half")
    assert main(data_command(raw, out, "--min-frames", "41")) == 0  # same corpus, another config
    assert read_manifest(out)["config"]["min_frames"] == 41
    assert (out / "tokens" / "vq-run" / MANIFEST).exists()
    assert siblings(out) == {out.name, f".{out.name}.lock"}


def test_training_refuses_a_shard_changed_after_the_build(project, tmp_path, tiny_data, capsys):
    data = tmp_path / "damaged"
    shutil.copytree(tiny_data, data)
    flip_byte(data / "shards" / "train-000001.tar")
    assert main(["data", "--check", str(data)]) == 2
    capsys.readouterr()
    error = one_line_error(["train-vq", "--config", str(project / "tiny.yaml"), "--set", f"data.dir={data}"], capsys)
    assert "train-000001.tar: sha256 differs" in error and f"m2d2m data --check {data}" in error


@pytest.mark.parametrize(
    "damage, expected",
    [
        (flip_byte, (ValueError, "sha256 differs")),
        (lambda path: path.write_bytes(path.read_bytes()[:-1]), (ValueError, "bytes, the manifest records")),
        (Path.unlink, (FileNotFoundError, "missing, though the manifest lists it")),
    ],
)
def test_a_read_checks_size_always_and_sha256_once(tmp_path, monkeypatch, damage, expected):
    with ShardWriter(tmp_path, "train", 2) as writer:
        for key in ("a", "b", "c"):
            writer.write(key, {"meta.json": key.encode() * 2000})
    records = shard_records(writer.shards)
    hashed = []
    monkeypatch.setattr(integrity, "sha256_of", lambda path: hashed.append(path) or sha256_of(path))
    assert verified_paths(tmp_path, records, "fix it") == [str(tmp_path / r["name"]) for r in records]
    assert verified_paths(tmp_path, records, "fix it") and len(hashed) == 2  # the second read is cached

    shard = tmp_path / records[0]["name"]
    stamp = shard.stat()
    damage(shard)
    if shard.exists():
        os.utime(shard, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))  # same mtime: the ctime still tells
    kind, message = expected
    with pytest.raises(kind, match=message) as error:
        verified_paths(tmp_path, records, "fix it")
    assert str(error.value).startswith(str(shard)) and str(error.value).endswith("; fix it")


def test_token_shards_are_checked_before_training_reads_them(tmp_path):
    shards = {"test": []}
    for split in ("train", "val"):  # training needs both (training/data/shards.py, require_training_splits)
        with ShardWriter(tmp_path, split, 2) as writer:
            writer.write("a", {"tokens.npy": b"\0" * 2000, "meta.json": b"{}"})
        shards[split] = shard_records(writer.shards)
    (tmp_path / MANIFEST).write_text(json.dumps({"kind": "tokens", "shards": shards}), encoding="utf-8")
    assert TokenDataModule(tmp_path).urls("train") == [str(tmp_path / "train-000000.tar")]
    flip_byte(tmp_path / "train-000000.tar", offset=600)
    with pytest.raises(ValueError, match=r"train-000000.tar: sha256 differs .*m2d2m tokenize --check"):
        TokenDataModule(tmp_path)


def test_tokenize_and_testset_refuse_a_damaged_dataset_before_writing(tiny_data, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(tiny_data, data)
    random_vq(tmp_path / "vq.pt", data, seed=0)
    (data / "shards" / "test-000000.tar").unlink()
    with pytest.raises(FileNotFoundError, match="test-000000.tar: missing.*m2d2m data --check"):
        tokenize_dataset(data, tmp_path / "vq.pt", tmp_path / "tokens")
    with pytest.raises(FileNotFoundError, match="test-000000.tar: missing"):
        build_testset(data, n=2)
    assert not (tmp_path / "tokens").exists() and not (data / "testsets").exists()
