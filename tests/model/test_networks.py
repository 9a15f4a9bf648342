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
        got = dec._folded(x)
    assert got.shape == ref.shape
    assert (got - ref).abs().max() < 1e-5
    # the betas matter: without them the same weights give another function
    plain = torch.nn.Sequential(dec.net[0], torch.nn.Softplus(), dec.net[2],
                                torch.nn.Softplus(), dec.net[4])
    with torch.no_grad():
        assert (plain(x) - ref).abs().max() > 1e-2
