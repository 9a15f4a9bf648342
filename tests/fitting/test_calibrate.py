"""Landmark calibration from annotated faces."""

from __future__ import annotations

import numpy as np
import pytest

from head360cli.errors import FileFormatError
from head360cli.fitting.calibrate import CALIBRATED, calibrate_landmarks, read_dlib_landmarks
from head360cli.mesh.bilinear import load_bilinear


def test_read_dlib_xml(tmp_path):
    parts = "".join(f"<part name='{i:02d}' x='{10 + i}' y='{20 + i % 7}'/>" for i in range(68))
    (tmp_path / "f.xml").write_text(
        "<?xml version='1.0'?><dataset><images>"
        f"<image file='a.jpg' width='100' height='80'><box top='1' left='2' width='3' "
        f"height='4'>{parts}</box><box top='0' left='0' width='1' height='1'/></image>"
        "</images></dataset>")
    faces = read_dlib_landmarks(tmp_path / "f.xml")
    assert len(faces) == 1  # the box without 68 parts is skipped
    pts, size = faces[0]
    assert size == (100, 80) and pts.shape == (68, 2) and pts[5].tolist() == [15.0, 25.0]
    (tmp_path / "bad.xml").write_text("<dataset><images>")
    with pytest.raises(FileFormatError):
        read_dlib_landmarks(tmp_path / "bad.xml")


def test_calibration_recovers_displaced_landmarks():
    """Move some landmark vertices, make faces from the true ones, calibrate back."""
    from head360cli.fitting.shape import ShapeFitter
    from tests.fitting.test_shape import synthetic

    model = load_bilinear()
    truth_fitter = ShapeFitter(model)
    rng = np.random.default_rng(3)
    faces = []
    std = np.sqrt(np.diag(model.code_cov))
    for _ in range(12):
        uv, _ = synthetic(truth_fitter, rng.normal(size=model.rank) * std, np.zeros(52),
                          rng.uniform(-25, 25), rng.uniform(-15, 15), 0.5, rng)
        faces.append((uv, (640, 640)))
    start = model.landmarks.copy()
    mean = model.neutral_mean
    moved = [30, 33, 36, 45]  # nose tip, nose base, eye corners
    for k in moved:  # a neighbour 3-6 mm away
        d = np.linalg.norm(mean - mean[start[k]], axis=1)
        start[k] = int(np.nonzero((d > 0.003) & (d < 0.006) & (model.region == model.region[
            start[k]]))[0][0])
    displaced = model.with_landmarks(start)
    new, stats = calibrate_landmarks(displaced, faces, rounds=2)
    assert stats["round1_error"] < stats["round0_error"]
    back = np.linalg.norm(new.landmark_points(mean)[moved]
                          - model.landmark_points(mean)[moved], axis=1)
    assert (back < 0.003).all(), back
    changed = np.nonzero(np.abs(new.landmark_points(mean) - displaced.landmark_points(mean))
                         .max(1) > 0)[0]
    assert set(changed) <= set(CALIBRATED)
    assert np.allclose(new.landmark_bary.sum(1), 1.0) and (new.landmark_bary >= 0).all()


def test_mesh_outline_is_the_longest_boundary_loop():
    """A 4 x 4 grid of squares with one square's two triangles removed inside: the outer
    ring (12 vertices) is the outline, not the hole's 4."""
    from head360cli.fitting.calibrate import mesh_outline

    n = 5
    idx = np.arange(n * n).reshape(n, n)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            if (i, j) == (1, 1):
                continue
            a, b, c, d = idx[i, j], idx[i, j + 1], idx[i + 1, j], idx[i + 1, j + 1]
            faces += [(a, b, d), (a, d, c)]
    outline = mesh_outline(np.array(faces))
    ring = sorted(set(idx[0]) | set(idx[-1]) | set(idx[:, 0]) | set(idx[:, -1]))
    assert outline.tolist() == ring


def test_the_shipped_registration_belongs_to_the_shipped_model():
    """419 of the 468 mesh points are fitted, on faces, noses and lips of the shipped
    model; a registration for another model is ignored (the fit then uses the 68)."""
    from head360cli.fitting import calibrate
    from head360cli.mesh.bilinear import load_bilinear

    model = load_bilinear()
    keep, tri, bary = calibrate.load_dense_points(model)
    assert len(keep) == len(tri) == len(bary) and 380 <= len(keep) <= 440
    assert np.isin(model.region[tri], [1, 2, 3]).all()
    np.testing.assert_allclose(bary.sum(1), 1.0, atol=1e-5)

    other = type("Other", (), {})()
    other.meta = {"sha256": "0" * 64}
    assert calibrate.load_dense_points(other) is None
