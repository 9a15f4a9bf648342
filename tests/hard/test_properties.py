"""Hard cases as properties (hypothesis): whatever goes in, nothing NaN, inf or a crash
comes out, and every rejection is the project's own clear error.

Named cases live next to the code they test; here the inputs are generated."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from head360cli.errors import BadInputError, Head360Error

FAST = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])

coords = st.one_of(st.floats(-1e6, 1e6, width=32),
                   st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.5, 1e30]))


@FAST
@given(st.lists(st.tuples(coords, coords, st.one_of(st.floats(-5, 5, width=32),
                                                    st.just(float("nan")))),
                min_size=3, max_size=12),
       st.lists(st.tuples(st.integers(0, 11), st.integers(0, 11), st.integers(0, 11)),
                min_size=1, max_size=8),
       st.booleans())
def test_rasterize_never_returns_nan(points, tris, perspective):
    """Zero-area, collinear, repeated-vertex, huge, NaN and behind-the-camera triangles."""
    from head360cli.geometry.rasterize import rasterize

    p = torch.tensor(points, dtype=torch.float32)
    faces = torch.tensor([[a % len(p), b % len(p), c % len(p)] for a, b, c in tris])
    frags = rasterize(p[None, :, :2], p[None, :, 2], faces, 9, 11,
                      perspective_correct=perspective,
                      near=1e-4 if perspective else float("-inf"))
    assert frags.face_id.shape == (1, 9, 11)
    assert ((frags.face_id >= -1) & (frags.face_id < len(faces))).all()
    assert torch.isfinite(frags.bary).all() and torch.isfinite(frags.depth).all()
    hit = frags.face_id >= 0
    assert torch.allclose(frags.bary.sum(-1)[hit], torch.ones(()), atol=1e-4)


@FAST
@given(st.text(max_size=80))
def test_expression_and_view_parsing_reject_cleanly(text):
    from head360cli.drive.views import parse_expression, parse_views

    for parse in (parse_expression, parse_views):
        try:
            out = parse(text)
        except BadInputError:
            continue
        assert np.isfinite(np.asarray(out, float)).all()


@FAST
@given(st.lists(st.tuples(*[st.floats(-10, 10, width=32)] * 3), min_size=1, max_size=6))
def test_head_pose_cameras_stay_rigid(angles):
    from head360cli.drive.animate import head_pose_cameras
    from head360cli.drive.views import view_cameras

    cams = head_pose_cameras(np.array(angles), view_cameras(30.0, -20.0)[0]).double()
    r = cams[:, :3, :3]
    assert torch.isfinite(cams).all()
    eye = torch.eye(3, dtype=r.dtype).expand_as(r)
    assert torch.allclose(r @ r.transpose(1, 2), eye, atol=1e-5)


cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.sampled_from(["", "nan", "x", "1e999", "-0", " 0.5 ", "1,2"]))


@FAST
@given(st.lists(st.lists(cells, min_size=1, max_size=5), min_size=0, max_size=6),
       st.sampled_from(["error", "skip", "hold"]))
def test_arkit_reader_accepts_or_rejects_cleanly(rows, policy):
    from head360cli.io.arkit import read_arkit_csv

    header = "time,jawOpen,eyeBlinkLeft,mouthSmileLeft,browInnerUp"
    text = header + "\n" + "".join(",".join(r) + "\n" for r in rows)
    try:
        s = read_arkit_csv(io.StringIO(text), on_bad=policy)
    except Head360Error:
        return
    assert np.isfinite(s.weights).all() and (s.weights >= 0).all() and (s.weights <= 1).all()
    assert np.isfinite(s.timestamps).all()


@pytest.fixture(scope="module")
def tiny_renderer(head_file):
    from head360cli.fitting.pipeline import load_head_renderer

    return load_head_renderer(head_file, samples=2, size=32, precision="fp32")


@pytest.mark.slow
@settings(max_examples=12, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.floats(-720, 720), st.floats(-90, 90), st.floats(0.0, 1.0), st.floats(-8, 8),
       st.integers(0, 29))
def test_any_view_expression_shape_and_style_renders_finite(tiny_renderer, yaw, pitch,
                                                            weight, shape_sigma, style):
    """Top and bottom views, grazing and missing rays, every weight at once, shape codes
    far outside the prior, any hairstyle."""
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.head_render import HeadRenderer

    r = tiny_renderer
    std = np.sqrt(np.diag(r.model.code_cov))
    odd = HeadRenderer(r.gen, r.model.code_mean + shape_sigma * std, r.texture[0], style,
                       r.hair_colour, samples=2, size=32, precision="fp32")
    img = odd.render(view_cameras(yaw, pitch), view_intrinsics(32), np.full(52, weight))
    assert img.shape == (1, 3, 32, 32) and torch.isfinite(img).all()
    assert img.min() >= 0 and img.max() <= 1
