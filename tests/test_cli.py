"""The command line: user errors end in one line on stderr and exit status 2."""

import subprocess
import sys

import numpy as np
import pytest

from orchestration.cli import main


@pytest.mark.slow
def test_the_installed_entry_point_ends_a_user_error_in_one_line(tmp_path):
    """The one case run as a real process; the rest call ``main`` in this one (the same code,
    seconds cheaper each)."""
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "orchestration.cli",
            "render",
            str(tmp_path / "no.npy"),
            "--out",
            str(tmp_path / "x.gif"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines() == [
        f"m2d2m render: error: {tmp_path / 'no.npy'}: no such file or directory"
    ]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["render", "no/such/file.npy", "--out", "x.gif"], "no such file or directory"),
        (["synthesize", "--clips", "0"], "must be a positive integer"),
        (["synthesize", "--families", "walk,moonwalk"], "unknown family moonwalk"),
        (["render", "{tmp}", "--out", "x.gif"], "name the clip with --id"),
        (["render", "{tmp}", "--id", "000123", "--out", "x.gif"], "no clip '000123'"),
        (["render", "{tmp}/bad.npy", "--out", "x.gif"], "neither joints"),
        (["render", "{tmp}/joints.npy", "--out", "x.png"], "use .gif or .mp4"),
        (
            ["export", "{tmp}/joints.npy", "--out", "{tmp}/x.gif"],
            "export writes .npy, .bvh, .glb, .fbx (the suffix is the format)",
        ),
        (["render", "{tmp}/corrupt.npy", "--out", "x.gif"], "not a readable .npy"),
        (["data", "--dataset", "humanml3d", "--raw", "{tmp}/nowhere"], "pass --raw /path/to/humanml3d"),
        (["data", "--dataset", "amass"], "unknown dataset 'amass'"),
        (["data", "--check", "{tmp}"], "problem(s) against its manifest"),
        (["train-vq", "--config", "nope"], "no config 'nope' for vq; available: bandai-namco, demo, humanml3d, kit"),
        (["train-vq", "--set", "model.widht=3"], "no key 'widht' in model"),
        (["train-vq", "--set", "optim.lr"], "expected key.sub=value"),
        (["generate", "a person walks", "--option", "steps"], "argument --option: expected key.sub=value, got 'steps'"),
        (["generate", "a person walks", "--option", "steps=[1"], "argument --option: the value is not valid YAML"),
        (
            ["train-diffusion", "--config", "nope"],
            "no config 'nope' for m2d2m; available: bandai-namco, demo, humanml3d, kit",
        ),
        (["train-diffusion", "--set", "diffusion.knid=uniform"], "no key 'knid' in diffusion"),
        (["tokenize", "--vq", "nope", "--dataset", "zzz"], "no vq run 'nope' for dataset 'zzz'"),
        (["tokenize", "--check", "{tmp}"], "problem(s) against its manifest"),
        (["tokenize", "--dataset", "zzz"], "no finished vq run for dataset 'zzz' yet; run `make train-vq` first"),
    ],
)
def test_user_errors_exit_2_with_one_line(tmp_path, capsys, args, message):
    np.save(tmp_path / "bad.npy", np.zeros((10, 7), dtype=np.float32))
    np.save(tmp_path / "joints.npy", np.zeros((10, 22, 3), dtype=np.float32))
    (tmp_path / "corrupt.npy").write_bytes(b"\x93NUMPY garbage")
    try:
        status = main([a.replace("{tmp}", str(tmp_path)) for a in args])
    except SystemExit as stop:  # argparse
        status = stop.code
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and message in lines[0]


def test_no_verb_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([])
    assert exit_info.value.code == 2
