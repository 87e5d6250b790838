"""bench/vq_smoothness.py's table: a Jerk's interval is Student's t over the clips that define one."""

from __future__ import annotations

import numpy as np

from bench.vq_smoothness import jerk_cell


def test_a_jerk_cell_is_the_mean_and_students_t_half_width_of_the_defined_clips():
    # three defined clips (s = 1): t at 2 degrees of freedom, 4.302653 · 1 / √3 = 2.484, where the
    # normal 1.96 with the population spread gave 1.96 · 0.8165 / √3 = 0.92
    assert jerk_cell(np.array([1.0, 2.0, 3.0, np.nan])) == "2.00 ± 2.48"


def test_one_defined_clip_has_a_mean_and_no_interval():
    assert jerk_cell(np.array([1.5, np.nan])) == "1.50 (n = 1: no interval)"
