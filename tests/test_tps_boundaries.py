"""bench/tps_boundaries.py: where TPS's tokens differ from independent sampling's, paired."""

from __future__ import annotations

import numpy as np
import pytest

from bench.tps_boundaries import (
    NEAREST,
    Paired,
    another_seed,
    changed_by_distance,
    distance_to_boundary,
    main,
    paired_difference,
    repeats_for,
    seed_spread,
)


def test_distance_to_the_nearest_boundary_counts_both_neighbours_as_zero():
    # actions of 4, 3 and 3 tokens: boundaries before tokens 4 and 7
    assert distance_to_boundary(10, [4, 7]).tolist() == [3, 2, 1, 0, 0, 1, 0, 0, 1, 2]


def test_changed_tokens_are_binned_by_distance():
    independent = Paired([np.zeros(10, int)], [[4, 7]], np.zeros((1, 2)), np.zeros((1, 3)))
    tps = Paired([np.array([0, 0, 0, 5, 0, 5, 0, 0, 0, 5])], [[4, 7]], np.zeros((1, 2)), np.zeros((1, 3)))
    changed = changed_by_distance(tps, independent)
    assert len(changed) == NEAREST + 1
    # distance 0: tokens 3, 4, 6, 7 (one changed); 1: tokens 2, 5, 8 (one); 2: tokens 1, 9 (one); 3: token 0
    assert changed[:4].tolist() == pytest.approx([1 / 4, 1 / 3, 1 / 2, 0.0])


def test_paired_difference_skips_undefined_pairs():
    mean, half = paired_difference(np.array([[1.0, 3.0], [np.nan, 5.0]]), np.array([[0.0, 1.0], [1.0, 1.0]]))
    assert mean == pytest.approx(7 / 3)
    # Student's t with 2 degrees of freedom (4.302653), not the normal 1.96: three pairs are few
    assert half == pytest.approx(4.302653 * np.std([1.0, 2.0, 4.0], ddof=1) / np.sqrt(3))


def test_tps_at_t_equals_independent_and_every_ts_is_reported(trained_project, tiny_testset, capsys):
    out = trained_project / "boundaries"
    main(["--dataset", "tiny", "--testset", str(tiny_testset), "--ts", "0", "8", "--seeds", "2", "--out", str(out)])
    rows = {
        line.split("|")[1].strip(): line.split("|")[2:-1]
        for line in (out / "boundaries.md").read_text(encoding="utf-8").splitlines()
        if line.startswith("| ") and "T_s" not in line
    }
    # T_s = T (8 steps) is independent sampling draw for draw: no token changes, Jerk identical
    assert [float(cell) for cell in rows["8"][2:5]] == [0.0, 0.0, 0.0]
    assert rows["8"][5].strip() == "+0.000 ± 0.000"
    # a whole joint phase is measured too (whether it changes tokens depends on how this tiny model
    # trained, which varies with test order; test_sampling.py checks jointness on a fixed sampler)
    assert all(0.0 <= float(cell) <= 1.0 for cell in rows["0"][2:5])
    assert (out / "boundaries.png").stat().st_size > 0 and "T_s" in capsys.readouterr().out


def test_power_from_the_seed_to_seed_spread():
    # two seeds (seed-major) of two instances, one boundary each: per-instance variances 2 and 0
    paired = Paired([], [], np.array([[1.0], [5.0], [3.0], [5.0]]), np.zeros((4, 1)))
    assert seed_spread(paired, seeds=2) == pytest.approx(1.0)
    # 1.96 · 1 / √(R · 2) ≤ 0.5  ⇔  R ≥ 7.68
    assert repeats_for(1.0, instances=2, half_width=0.5) == 8


def test_another_seed_compares_the_same_instance_across_seeds():
    # seed-major: two instances under seed 0, then the same two under seed 1; boundary before token 2
    tokens = [np.array([1, 2, 3, 4]), np.array([5, 6, 7, 8]), np.array([1, 9, 3, 4]), np.array([5, 6, 7, 8])]
    independent = Paired(tokens, [[2]] * 4, np.zeros((4, 1)), np.zeros((4, 2)))
    # distance 0 holds tokens 1 and 2 of both instances: one of the four differs; distance 1 none
    assert another_seed(independent, instances=2)[:2].tolist() == [0.25, 0.0]
