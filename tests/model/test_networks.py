"""The networks' export forms: the same functions, written for onnxruntime."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from head360cli.model.config import GeneratorConfig
from head360cli.model.networks import Decoder, _softplus_unit


def test_softplus_unit_matches_softplus_over_a_wide_range():
    z = torch.linspace(-100.0, 100.0, 200001)
    ref = F.softplus(z.double())
    got = _softplus_unit(z)
    assert torch.isfinite(got).all()
    # float32 rounding of values up to 100: torch's own float32 softplus is as far
    assert (got.double() - ref).abs().max() < 1e-5
    small = z.abs() < 20
    assert (got.double() - ref)[small].abs().max() < 1e-6


def test_decoder_with_betas_folded_equals_the_decoder():
    torch.manual_seed(0)
    dec = Decoder(GeneratorConfig(hidden=32), planes=6)
    x = torch.randn(500, dec.net[0].in_features) * 3.0
    with torch.no_grad():
        ref = dec.net(x)
        got = dec._folded(x, _softplus_unit)
    assert got.shape == ref.shape
    assert (got - ref).abs().max() < 1e-5
    # the betas matter: without them the same weights give another function
    plain = torch.nn.Sequential(dec.net[0], torch.nn.Softplus(), dec.net[2],
                                torch.nn.Softplus(), dec.net[4])
    with torch.no_grad():
        assert (plain(x) - ref).abs().max() > 1e-2


def test_refinenet_on_cpu_runs_channels_last_and_returns_the_same_images():
    from head360cli.model.networks import RefineNet

    torch.manual_seed(0)
    cfg = GeneratorConfig(render_res=16, image_res=32, refine_width=16)
    net = RefineNet(cfg)
    for p in net.parameters():  # the last layer starts at zero: give it weights
        p.data.normal_(0.0, 0.2)
    feats = torch.randn(2, cfg.feature_channels, 16, 16)
    alpha, rgb = torch.rand(2, 1, 16, 16), torch.rand(2, 3, 16, 16)
    seen = []
    hook = net.net[0].register_forward_pre_hook(lambda m, args: seen.append(args[0]))
    with torch.no_grad():
        got_rgb, got_alpha = net(feats, alpha, rgb)
        res = net.net(torch.cat([feats, alpha], 1))  # plain NCHW
    hook.remove()
    assert seen[0].is_contiguous(memory_format=torch.channels_last)
    assert not seen[1].is_contiguous(memory_format=torch.channels_last)
    up = F.interpolate(torch.cat([rgb, alpha], 1), scale_factor=2, mode="bilinear",
                       align_corners=False)
    torch.testing.assert_close(got_rgb, (up + res)[:, :3], atol=1e-4, rtol=0)
    torch.testing.assert_close(got_alpha, (up + res)[:, 3:].clamp(0, 1), atol=1e-4, rtol=0)
    # the layout callers had before (a channel slice of a contiguous NCHW tensor)
    assert got_rgb.stride() == (up + res)[:, :3].stride()
    assert got_alpha.shape == (2, 1, 32, 32)
    assert got_rgb.abs().mean() > 0.1  # the residual is not zero: a real comparison
    # with gradients (fitting) too, and the gradients are those of the plain layout
    seen.clear()
    hook = net.net[0].register_forward_pre_hook(lambda m, args: seen.append(args[0]))
    x = feats.clone().requires_grad_(True)
    got_rgb, _ = net(x, alpha, rgb)
    g_got, = torch.autograd.grad(got_rgb.square().sum(), x)
    hook.remove()
    assert seen[0].is_contiguous(memory_format=torch.channels_last)
    plain = net.net(torch.cat([x, alpha], 1))[:, :3] + up[:, :3]
    g_plain, = torch.autograd.grad(plain.square().sum(), x)
    torch.testing.assert_close(g_got, g_plain, atol=1e-4, rtol=1e-4)
    assert g_plain.abs().mean() > 1e-3


def test_decoder_renders_folded_without_gradients_and_trains_unfolded():
    """Without gradients (renders) the decoder runs its folded layers with torch's
    softplus: the same densities and colours as the layers it was trained as, which
    it still runs when gradients are on."""
    torch.manual_seed(0)
    dec = Decoder(GeneratorConfig(hidden=32), planes=6)
    x = torch.randn(700, dec.net[0].in_features) * 3.0
    x[:5] *= 40.0  # beyond softplus's threshold in some units
    calls = []
    hook = dec.net.register_forward_hook(lambda *a: calls.append(1))
    with torch.no_grad():
        density, colour = dec(x)
    assert calls == []  # the folded path, not self.net
    ref_density, ref_colour = dec(x)  # with gradients: self.net
    hook.remove()
    assert calls == [1]
    torch.testing.assert_close(density, ref_density.detach(), atol=1e-3, rtol=1e-5)
    torch.testing.assert_close(colour, ref_colour.detach(), atol=1e-5, rtol=1e-5)
    # under bfloat16 (renders on CPUs that have it) the folded layers round their
    # scaled weights apart, but stay as near float32 as the trained layers do
    with torch.autocast("cpu", dtype=torch.bfloat16):
        with torch.no_grad():
            folded = dec(x)[1].float()
        trained = dec(x)[1].detach().float()
    err_folded = (folded - ref_colour.detach()).abs()
    err_trained = (trained - ref_colour.detach()).abs()
    assert err_folded.mean() < 1.5 * err_trained.mean()
    assert err_folded.max() < 2.0 * err_trained.max()


def test_decoder_renders_on_cpu_through_onednn_linear_with_the_same_values(monkeypatch):
    """Renders on a CPU run the decoder's linear layers through oneDNN's linear op:
    bit for bit the values of ``F.linear`` in float32, and under bfloat16 autocast
    within bfloat16's rounding of them."""
    from head360cli.model import networks

    if not networks._HAS_CPU_LINEAR:
        import pytest

        pytest.skip("this torch build has no oneDNN linear op (F.linear is used)")
    torch.manual_seed(0)
    dec = Decoder(GeneratorConfig(hidden=32), planes=6)
    x = torch.randn(3, 700, dec.net[0].in_features) * 3.0
    calls = []
    real = networks._cpu_linear
    monkeypatch.setattr(networks, "_cpu_linear",
                        lambda *a: calls.append(a[0].shape) or real(*a))
    with torch.no_grad():
        density, colour = dec(x)
        assert len(calls) == 3  # all three layers, on the (3, 700, D) batch as it is
        monkeypatch.setattr(networks, "_HAS_CPU_LINEAR", False)
        ref_density, ref_colour = dec(x)
        assert len(calls) == 3  # F.linear this time
    assert torch.equal(density, ref_density) and torch.equal(colour, ref_colour)
    assert colour.abs().mean() > 0.1
    monkeypatch.setattr(networks, "_HAS_CPU_LINEAR", True)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        fast = dec(x)[1]
        monkeypatch.setattr(networks, "_HAS_CPU_LINEAR", False)
        plain = dec(x)[1]
    assert fast.dtype == plain.dtype == torch.bfloat16
    assert len(calls) == 6
    # equal at this size; at the shipped sizes (128 hidden, 40k points) a few values are
    # a bfloat16 ulp or two apart (frames at most 3 levels of 255, PSNR 77-79 dB)
    torch.testing.assert_close(fast.float(), plain.float(), atol=0.02, rtol=0.01)
    # with gradients (training, fitting) the layers run as trained, not through oneDNN
    monkeypatch.setattr(networks, "_HAS_CPU_LINEAR", True)
    dec(x)
    assert len(calls) == 6


def test_render_softplus_looks_up_torch_bfloat16_softplus_bit_for_bit():
    """Renders on a CPU look bfloat16 softplus values up in a table of every bfloat16
    value: the same bits as ``F.softplus``, infinities and NaN included, at any shape
    and layout; other dtypes go to ``F.softplus`` itself."""
    from head360cli.model import networks
    from head360cli.model.networks import render_softplus, softplus_table

    every = torch.arange(-32768, 32768, dtype=torch.int32).to(torch.int16).view(torch.bfloat16)
    got, ref = render_softplus(every), F.softplus(every)
    nan = torch.isnan(ref)
    assert nan.sum() > 0 and torch.equal(torch.isnan(got), nan)
    assert torch.equal(got[~nan].view(torch.int16), ref[~nan].view(torch.int16))
    assert got[every == float("inf")].item() == float("inf")
    assert got[every == float("-inf")].item() == 0.0
    # a slice of a larger tensor (not contiguous) keeps its shape
    torch.manual_seed(0)
    x = (torch.randn(40, 9) * 8).bfloat16()[:, 1:4]
    assert not x.is_contiguous()
    assert torch.equal(render_softplus(x), F.softplus(x))
    assert render_softplus(x).shape == (40, 3)
    # more values than one lookup takes at a time (the chunks' seams)
    big = (torch.randn(3, networks._LOOKUP_CHUNK + 77) * 6).bfloat16()
    assert torch.equal(render_softplus(big), F.softplus(big))
    assert softplus_table("cpu") is softplus_table(torch.device("cpu"))  # made once
    y = torch.randn(50) * 5
    assert torch.equal(render_softplus(y), F.softplus(y))  # float32: torch's own
    assert torch.equal(render_softplus(y.double()), F.softplus(y.double()))


def test_decoder_renders_bfloat16_through_the_table_as_through_torch(monkeypatch):
    """The render path's softplus lookups give the frames torch's softplus gives."""
    from head360cli.model import networks

    torch.manual_seed(0)
    dec = Decoder(GeneratorConfig(hidden=32), planes=6)
    x = torch.randn(2, 900, dec.net[0].in_features) * 3.0
    x[0, :5] *= 40.0  # beyond the threshold
    calls = []
    real = networks.render_softplus
    monkeypatch.setattr(networks, "render_softplus",
                        lambda z: calls.append(z.dtype) or real(z))
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        density, colour = dec(x)
        assert calls == [torch.bfloat16] * 3  # both hidden layers and the density
        monkeypatch.setattr(networks, "render_softplus", F.softplus)
        ref_density, ref_colour = dec(x)
    assert torch.equal(density, ref_density) and torch.equal(colour, ref_colour)
    assert density.abs().mean() > 0 and colour.abs().mean() > 0.1
