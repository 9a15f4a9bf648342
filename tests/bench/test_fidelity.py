"""Expression fidelity read with the face tracker: the tables, the AUC, a head's frames
tracked, and their report."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.bench.fidelity import (
    NAMED,
    auc,
    corpus_fidelity,
    fidelity_table,
    head_fidelity,
)
from head360cli.io.arkit import ArkitStream
from head360cli.mesh.arkit52 import INDEX


def test_auc_counts_ordered_pairs_and_ties():
    assert auc([2, 3], [0, 1]) == 1.0
    assert auc([0, 1], [2, 3]) == 0.0
    assert auc([1, 1], [1, 1]) == 0.5
    assert auc([3, 1], [2, 0]) == 0.75


def test_fidelity_table_scores_each_blendshape_and_the_most_active():
    rng = np.random.default_rng(0)
    d = np.zeros((50, 52), np.float32)
    d[:, INDEX["jawOpen"]] = rng.uniform(0, 1, 50)
    d[:, INDEX["eyeBlinkLeft"]] = rng.uniform(0, 0.5, 50)
    found = np.arange(0, 50, 2)
    t = np.zeros((25, 52), np.float32)
    t[:, INDEX["jawOpen"]] = 0.3 * d[found, INDEX["jawOpen"]] + 0.1  # compressed: r = 1
    t[:, INDEX["eyeBlinkLeft"]] = rng.uniform(0, 1, 25)  # unrelated
    table = fidelity_table(d, found, t)
    assert table["frames"] == 50 and table["faces_found"] == 25
    assert table["r"]["jawOpen"] == pytest.approx(1.0, abs=1e-4)
    assert abs(table["r"]["eyeBlinkLeft"]) < 0.5
    assert table["r"]["mouthSmileLeft"] is None  # constant in the capture
    assert table["top_active"] == ["jawOpen", "eyeBlinkLeft"]
    assert table["mean_r_top_active"] == pytest.approx(
        (1.0 + table["r"]["eyeBlinkLeft"]) / 2, abs=1e-3)
    assert set(table["named"]) == set(NAMED)


@pytest.fixture(scope="module")
def jaw_and_blinks():
    w = np.zeros((12, 52), np.float32)
    w[:, INDEX["jawOpen"]] = np.tile([0.0, 0.5, 1.0], 4)
    w[:, INDEX["eyeBlinkLeft"]] = w[:, INDEX["eyeBlinkRight"]] = np.repeat([0, 1, 0, 1], 3)
    return ArkitStream(w, np.arange(12) / 30.0, 30.0)


def test_a_head_s_frames_are_tracked_and_follow_jaw_and_blinks(head_file, jaw_and_blinks,
                                                                tmp_path):
    from head360cli.bench.animate import _fidelity_markdown
    from head360cli.viz import plot_fidelity

    f = head_fidelity(head_file, jaw_and_blinks, stride=1)
    assert f["frames"] == f["faces_found"] == 12
    assert f["r"]["jawOpen"] > 0.8 and f["r"]["eyeBlinkLeft"] > 0.8
    assert f["series"]["names"][:3] == f["top_active"][:3]
    plot_fidelity(f["series"], tmp_path / "plot.png", title="t")
    assert (tmp_path / "plot.png").stat().st_size > 1000
    ref = corpus_fidelity(jaw_and_blinks, stride=2, heads=1, size=192)
    assert ref[0]["frames"] == 6 and ref[0]["faces_found"] == 6
    md = "\n".join(_fidelity_markdown({"fidelity": [{"take": "t.csv", "head": f,
                                                     "reference": ref}]}))
    jaw = next(line for line in md.splitlines() if line.startswith("| jawOpen |"))
    header = next(line for line in md.splitlines() if line.startswith("| blendshape |"))
    assert jaw.count("|") == header.count("|") == 4
    assert "mean over the 20 most active" in md


def test_fidelity_table_also_averages_over_the_shapes_the_tracker_reads():
    rng = np.random.default_rng(1)
    d = np.zeros((40, 52), np.float32)
    d[:, INDEX["jawOpen"]] = rng.uniform(0, 1, 40)
    d[:, INDEX["cheekPuff"]] = rng.uniform(0, 0.8, 40)  # the tracker never reads it
    found = np.arange(40)
    t = np.zeros((40, 52), np.float32)
    t[:, INDEX["jawOpen"]] = d[:, INDEX["jawOpen"]]
    table = fidelity_table(d, found, t, unread=["cheekPuff"])
    assert table["mean_r_top_active"] == pytest.approx(0.5, abs=1e-4)  # cheekPuff r = 0
    assert table["top_active_read"] == ["jawOpen"]
    assert table["mean_r_top_active_read"] == pytest.approx(1.0, abs=1e-4)
    assert "mean_r_top_active_read" not in fidelity_table(d, found, t)
