"""Training views: bald and with-hair renders and the hair they come with."""

from __future__ import annotations

import numpy as np
import torch

from head360cli.model.data import Views, eval_cameras


def test_views_mix_bald_and_hair_renders():
    views = Views(2, size=32, texture_size=64)
    batch = views.sample(np.random.default_rng(3), 6, bald_share=0.5)
    assert batch.rgb.shape == (6, 3, 32, 32) and batch.verts.shape[0] == 6
    assert 0 < int(batch.with_hair.sum()) < 6
    for i in range(6):
        has_mesh = batch.hair.meshes[i] is not None
        style = int(batch.hair.style[i])
        assert has_mesh == (bool(batch.with_hair[i]) and style != 0)
        if not batch.with_hair[i]:
            assert batch.hair_alpha[i].max() == 0
    # Head 1 wears style 1 (short): its with-hair renders show hair.
    one = views.render(1, np.zeros(52, np.float32), eval_cameras()[0][:1], with_hair=True)
    assert one.hair_alpha.max() > 0.5 and one.hair.meshes[0] is not None
    swapped = views.render(1, np.zeros(52, np.float32), eval_cameras()[0][:1],
                           with_hair=True, style=17, colour="red")
    assert int(swapped.hair.style[0]) == 17
    assert torch.allclose(swapped.hair.colour[0], torch.tensor([0.55, 0.20, 0.07]))
    assert swapped.hair_alpha.sum() > one.hair_alpha.sum()  # long hair covers more


def test_sample_expression_featured_share():
    import numpy as np

    from head360cli.model.data import sample_expression

    rng = np.random.default_rng(0)
    base = np.stack([sample_expression(rng) for _ in range(4000)])
    rng = np.random.default_rng(0)
    more = np.stack([sample_expression(rng, featured=0.25) for _ in range(4000)])
    closed = lambda w: float((w[:, 0] >= 0.7).mean())  # noqa: E731  eyeBlinkLeft
    assert closed(base) < 0.02
    assert 0.10 < closed(more) < 0.16  # 1/4 featured, half the groups close the left eye
    assert 0.04 < float((more[:, 17] >= 0.7).mean()) < 0.09  # jawOpen: 1/16 plus chance
    everyone = np.stack([sample_expression(rng, featured=1.0) for _ in range(200)])
    assert ((everyone[:, [0, 7, 17]] >= 0.7).any(axis=1)).all()
    assert everyone.max() <= 1.0 and everyone.min() >= 0.0
