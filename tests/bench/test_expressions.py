"""The expression sweep: its weights and what counts as rising with the weight."""

from __future__ import annotations

import numpy as np

from head360cli.bench.expressions import LEVELS, _table, rises, sweep_weights
from head360cli.mesh.arkit52 import ARKIT52, INDEX


def test_sweep_sets_one_shape_at_a_time_and_closes_the_lips_over_an_open_jaw():
    w = sweep_weights()
    assert w.shape == (1 + 52 * len(LEVELS), 52)
    assert not w[0].any()
    for j, name in enumerate(ARKIT52):
        rows = w[1 + j * len(LEVELS): 1 + (j + 1) * len(LEVELS)]
        np.testing.assert_allclose(rows[:, j], LEVELS)
        others = np.delete(rows, j, axis=1)
        if name == "mouthClose":
            np.testing.assert_allclose(rows[:, INDEX["jawOpen"]], LEVELS)
            others = np.delete(rows, [j, INDEX["jawOpen"]], axis=1)
        assert not others.any(), name


def test_rising_needs_a_rise_and_no_dip():
    assert rises(np.array([0.0, 0.1, 0.2, 0.3, 0.4]))
    assert rises(np.array([0.0, 0.04, 0.02, 0.05, 0.12]))  # a dip within 0.05
    assert not rises(np.array([0.0, 0.02, 0.04, 0.06, 0.08]))  # 0.08 < 0.1
    assert not rises(np.array([0.0, 0.5, 0.2, 0.4, 0.6]))  # falls by 0.3
    assert not rises(np.array([0.3, 0.3, 0.3, 0.3, 0.3]))


def test_table_reads_each_shapes_own_score_and_counts_missed_faces():
    scores = np.zeros((1 + 52 * len(LEVELS), 52), np.float32)
    j = INDEX["jawOpen"]
    scores[1 + j * len(LEVELS): 1 + (j + 1) * len(LEVELS), j] = [0.2, 0.4, 0.6, 0.8]
    scores[4, :] = np.nan  # no face in one frame (eyeBlinkLeft at 1)
    t = _table(scores, LEVELS)
    assert t["rising"] == 1 and t["of"] == 52 and t["faces_missed"] == 1
    assert t["per_shape"]["jawOpen"] == {"scores": [0.0, 0.2, 0.4, 0.6, 0.8], "rises": True}
    assert t["per_shape"]["eyeBlinkLeft"]["scores"][-1] is None
    assert "jawOpen" not in t["not_rising"] and len(t["not_rising"]) == 51
