"""DecodeReuse: decoded points, the RefineNet's output and still inputs kept between frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from head360cli.model.reuse import DecodeReuse


class _Counting:
    """A decoder stand-in: density = sum of the inputs, colour = the inputs doubled; it
    counts the points it is run on."""

    def __init__(self) -> None:
        self.points = 0

    def __call__(self, f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self.points += f.shape[1]
        return f.sum(-1), 2.0 * f


def test_decode_runs_only_on_points_whose_input_changed():
    run = _Counting()
    reuse = DecodeReuse(tol=1e-3)
    feats = torch.arange(12.0).reshape(6, 2)
    keys = torch.tensor([5, 0, 9, 3, 7, 1])
    d, c = reuse.decode("head", run, feats, keys, size=10)
    assert run.points == 6
    torch.testing.assert_close(d, feats.sum(-1))
    # the same points again, in another order: nothing to decode
    perm = torch.tensor([3, 1, 5, 0, 2, 4])
    d, c = reuse.decode("head", run, feats[perm], keys[perm], size=10)
    assert run.points == 6
    torch.testing.assert_close(c, 2.0 * feats[perm])
    # one input moved beyond the tolerance, one within it
    moved = feats.clone()
    moved[2, 0] += 0.5
    moved[4, 1] += 5e-4
    d, c = reuse.decode("head", run, moved, keys, size=10)
    assert run.points == 7
    assert d[2] == pytest.approx(float(moved[2].sum()))
    assert d[4] == pytest.approx(float(feats[4].sum()))  # kept: within tol
    assert (reuse.points, reuse.decoded) == (18, 7)


def test_small_changes_do_not_pile_up_past_the_tolerance():
    run = _Counting()
    reuse = DecodeReuse(tol=1e-3)
    keys = torch.tensor([0])
    x = torch.zeros(1, 1)
    reuse.decode("head", run, x, keys, size=1)
    decoded_at = []
    for step in range(1, 8):  # 4e-4 a frame: each step within tol, three are not
        x = x + 4e-4
        d, _ = reuse.decode("head", run, x, keys, size=1)
        assert abs(float(d[0]) - float(x[0, 0])) <= 1e-3
        if run.points > len(decoded_at) + 1:
            decoded_at.append(step)
    assert decoded_at == [3, 6]


def test_a_new_size_or_a_clear_starts_afresh_and_stores_are_per_decoder():
    run = _Counting()
    reuse = DecodeReuse()
    feats = torch.ones(4, 3)
    keys = torch.arange(4)
    reuse.decode("head", run, feats, keys, size=4)
    reuse.decode("hair", run, feats, keys, size=4)
    assert run.points == 8  # the hair has its own store
    reuse.decode("head", run, feats, keys, size=8)
    assert run.points == 12
    reuse.clear()
    reuse.decode("head", run, feats, keys, size=8)
    assert run.points == 16
    with pytest.raises(ValueError, match="tolerance >= 0"):
        DecodeReuse(tol=-1.0)
    with pytest.raises(ValueError, match="tolerance >= 0"):
        DecodeReuse(tol=float("nan"))


def test_kept_remakes_only_for_other_inputs():
    reuse = DecodeReuse()
    made = []

    def make():
        made.append(1)
        return torch.tensor(float(len(made)))

    a, b = torch.ones(3), torch.zeros(2)
    assert reuse.kept("x", (a, b), make) == 1
    assert reuse.kept("x", (a.clone(), b), make) == 1
    a[0] = 2.0  # the stored inputs are copies: changing the caller's tensor is seen
    assert reuse.kept("x", (a, b), make) == 2
    assert reuse.kept("x", (a, torch.zeros(3)), make) == 3


@pytest.mark.parametrize("where", ["middle", "corner", "nothing"])
def test_refine_on_a_crop_equals_the_whole_image(where):
    from head360cli.model.config import GeneratorConfig
    from head360cli.model.networks import RefineNet

    torch.manual_seed(0)
    net = RefineNet(GeneratorConfig(render_res=64, image_res=256, refine_width=16,
                                    feature_channels=6))
    for p in net.parameters():  # the last layer starts at zero: give it weights
        torch.nn.init.normal_(p, std=0.3)
    h = 64
    feats, alpha, rgb = torch.rand(1, 6, h, h), torch.rand(1, 1, h, h), torch.rand(1, 3, h, h)
    reuse = DecodeReuse()
    with torch.no_grad():
        reuse.refine(net, feats, alpha, rgb, net.scale, net.reach)
        f2 = feats.clone()
        if where == "middle":
            f2[..., 30:33, 40:42] += 1.0
        elif where == "corner":
            f2[..., 0, h - 1] -= 1.0
        got = reuse.refine(net, f2, alpha, rgb, net.scale, net.reach)
        ref = net(f2, alpha, rgb)
    assert net.reach == 4  # two upsampling steps
    for g, r in zip(got, ref, strict=True):
        assert g.shape == r.shape
        torch.testing.assert_close(g, r, atol=2e-5, rtol=0)
    if where == "middle":
        # the crop: the change grown by twice the reach (rows 22-40, columns 32-49), out
        # to the 16-pixel grid (rows 16-47, columns 32-63), not the whole image
        assert reuse.refined_pixels == 32 * 32
    # an output does not change under the caller: later frames write into copies
    again = reuse.refine(net, feats, alpha, rgb, net.scale, net.reach)
    torch.testing.assert_close(got[0], ref[0], atol=2e-5, rtol=0)
    assert not torch.equal(again[0], got[0]) or where == "nothing"


@pytest.fixture(scope="module")
def renderer(tmp_path_factory):
    """A head drawn from a tiny hex-plane generator (trained one step): the reuse of
    decoded points belongs to that generator only (the deferred one decodes no volume)."""
    import dataclasses

    from head360cli.drive.sample import sample_heads, write_samples
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.model.train import CHECKPOINT, TrainConfig, save_generator, train
    from head360cli.paths import use_generator
    from tests.model.test_generator import TINY

    folder = tmp_path_factory.mktemp("hexplane")
    train(folder / "run", TrainConfig(identities=2, steps=1, batch=2, log_every=1),
          dataclasses.replace(TINY, renderer="hexplane"), progress=False)
    save_generator(folder / "run" / CHECKPOINT, folder / "hex.pt")
    weights = folder / "hex.pt"
    with use_generator(weights):
        head = write_samples(sample_heads(1, seed=0, lids=False), folder)[0]
        r = load_head_renderer(head, samples=4, size=64, precision="fp32")
    assert r.gen.kind == "hexplane"
    return r


def _frames(r, weights, cams, tol):
    from head360cli.drive.views import view_intrinsics

    own = r.reuse
    r.reuse = tol
    try:
        return torch.cat([torch.as_tensor(f) for f in r.frames(
            cams, weights, view_intrinsics(64), uint8=False)])
    finally:
        r.reuse = own


def _weights(n):
    from head360cli.mesh.arkit52 import INDEX

    w = np.zeros((n, 52), np.float32)
    w[:, INDEX["jawOpen"]] = np.linspace(0.0, 0.6, n)
    w[:, INDEX["eyeBlinkLeft"]] = np.linspace(0.0, 1.0, n) ** 2
    w[n // 2:, INDEX["mouthSmileRight"]] = 0.4
    return w


def test_animation_with_reuse_matches_decoding_every_point(renderer):
    from head360cli.drive.views import view_cameras

    w = _weights(6)
    cams = view_cameras(20.0, 5.0).expand(len(w), 4, 4)
    ref = _frames(renderer, w, cams, None)
    exact = _frames(renderer, w, cams, 0.0)
    near = _frames(renderer, w, cams, 1e-3)
    # tol 0 reuses only equal inputs: the same frames up to the matrix products' rounding
    assert (exact - ref).abs().max() < 1e-5
    # measured 4.6e-4 on the fitted astronaut at 256 px over a real capture
    assert (near - ref).abs().max() < 2e-3
    assert (near - ref).abs().max() > 0  # it did reuse something inexact


def test_reuse_decodes_fewer_points_and_only_for_a_still_camera(renderer, monkeypatch):
    from head360cli.drive.views import view_cameras
    from head360cli.model import reuse as reuse_mod

    made = []
    real = reuse_mod.DecodeReuse

    def spy(*args, **kwargs):
        made.append(real(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(reuse_mod, "DecodeReuse", spy)
    w = _weights(5)
    _frames(renderer, w, view_cameras(0.0, 0.0).expand(5, 4, 4), 1e-3)
    assert len(made) == 1
    assert 0 < made[0].decoded < 0.7 * made[0].points
    moving = view_cameras(np.linspace(0, 40, 5), 0.0)
    got = _frames(renderer, w, moving, 1e-3)
    # a moving camera: every point decoded, only the planes' still triangles and the
    # RefineNet's output around the head (the background stays as it was) kept, and the
    # frames are those of no reuse at all
    assert len(made) == 2 and made[1].camera_moves
    assert made[1].points == made[1].decoded == 0
    assert sorted(made[1]._kept) == ["planes_under"]
    # the RefineNet went through the reuse's crops (at this size they hold the whole
    # image: the head fills it; the crops' values are checked above)
    assert made[1].refined_pixels > 0
    assert torch.equal(got, _frames(renderer, w, moving, None))
    assert len(made) == 2  # no reuse: nothing made


def test_generator_refuses_reuse_for_batches_and_training(renderer):
    from head360cli.drive.views import view_cameras, view_intrinsics

    gen = renderer.gen
    verts = renderer.vertices(np.zeros((2, 52)))
    cams = view_cameras(np.array([0.0, 10.0]), 0.0)
    with torch.no_grad(), gen.image_size(64), pytest.raises(ValueError, match="one item"):
        gen(verts, cams, view_intrinsics(64), texture=renderer.texture.expand(2, -1, -1, -1),
            reuse=DecodeReuse())


def test_still_triangles_drawn_once_give_the_same_planes_and_depth(renderer):
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.model.render import screen_depth

    gen = renderer.gen
    still = renderer._still_vertices
    reuse = DecodeReuse(0.0, still)
    assert 0.2 < float(still[gen.faces].all(1).float().mean()) < 0.8
    cam = view_cameras(30.0, 10.0)
    k = view_intrinsics(64).clone()[None]
    k[:, :2] *= gen.cfg.render_res / gen.cfg.image_res
    made = []
    real = reuse.kept

    def spy(name, inputs, make):
        return real(name, inputs, lambda: made.append(name) or make())

    reuse.kept = spy
    with torch.no_grad():
        for w in _weights(3):
            v = renderer.vertices(w[None])
            still = gen._still(v, reuse)
            assert torch.equal(gen._head_planes(v, renderer.texture, reuse, still),
                               gen.planes(v, renderer.texture))
            assert torch.equal(gen._head_depth(v, cam, k, reuse, still),
                               screen_depth(v, gen.faces, cam, k, gen.cfg.render_res))
    assert sorted(made) == ["head_depth_under", "planes_under"]  # drawn once, kept
