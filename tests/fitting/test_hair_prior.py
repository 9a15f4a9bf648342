"""The learned hair prior: network shapes, alignment, checkpoints, training data and
augmentation on tiny configurations, and the shipped weights on held-out corpus heads."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from head360cli.errors import BadInputError
from head360cli.fitting.hair_prior import (
    HairPrior,
    HairPriorConfig,
    HairPriorNet,
    align_matrix,
    default_hair_prior,
    load_hair_prior,
    save_hair_prior,
)
from head360cli.fitting.hair_prior_train import (
    Augmenter,
    HairPriorTrainConfig,
    draw_hat,
    hair_loss,
    render_crops,
    train_hair_prior,
)

TINY = HairPriorConfig(width=4, levels=2, crop=32)


def _tiny_prior(seed: int = 0) -> HairPrior:
    torch.manual_seed(seed)
    canon = np.stack([np.linspace(8, 24, 41), np.linspace(10, 22, 41)], 1)
    return HairPrior(HairPriorNet(TINY), canon)


@pytest.mark.parametrize("levels", [1, 2, 4])
def test_net_keeps_the_crop_size(levels):
    net = HairPriorNet(HairPriorConfig(width=4, levels=levels, crop=32)).eval()
    out = net(torch.rand(2, 3, 32, 32))
    assert out.shape == (2, 1, 32, 32)
    assert torch.isfinite(out).all()


def test_shipped_width_has_the_probe_size():
    """Width 16, 4 levels: 0.84 M parameters, the network as shipped."""
    n = sum(p.numel() for p in HairPriorNet(HairPriorConfig()).parameters())
    assert n == pytest.approx(0.84e6, rel=0.01)


def test_align_matrix_recovers_a_similarity():
    rng = np.random.default_rng(0)
    canon = rng.uniform(30, 100, (41, 2)).astype(np.float32)
    ang, scale, shift = 0.3, 2.5, np.array([40.0, -12.0])
    rot = scale * np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    lm = np.zeros((68, 2), np.float32)
    # landmarks 27-67 are the canonical points moved by the inverse of that similarity
    lm[27:] = (canon - shift) @ np.linalg.inv(rot).T
    m = align_matrix(lm, canon)
    np.testing.assert_allclose(m[:, :2], rot, atol=1e-3)
    np.testing.assert_allclose(m[:, 2], shift, atol=1e-2)


def test_align_matrix_refuses_degenerate_landmarks():
    canon = np.random.default_rng(0).uniform(0, 128, (41, 2))
    assert align_matrix(np.full((68, 2), 50.0), canon) is None


def test_predict_maps_back_to_the_photo():
    prior = _tiny_prior()
    rgb = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    lm = np.zeros((68, 2))
    lm[27:] = prior.canon + np.array([20.0, 10.0])  # the crop is the photo's window at (20, 10)
    p = prior.predict(rgb, lm)
    assert p.shape == (60, 80) and p.dtype == np.float32
    assert (p >= 0).all() and (p <= 1).all()
    assert (p[:, :19] == 0).all() and (p[:9] == 0).all() and (p[:, 53:] == 0).all()
    # inside the window the map is the network's output on that window
    crop = rgb[10:42, 20:52].astype(np.float32) / 255
    direct = prior.predict_crops(crop[None])[0]
    np.testing.assert_allclose(p[12:40, 22:50], direct[2:30, 2:30], atol=1e-4)
    assert prior.predict(rgb, np.full((68, 2), 5.0)) is None


def test_checkpoint_round_trip(tmp_path):
    prior = _tiny_prior(1)
    with torch.no_grad():  # non-trivial batch-norm statistics must travel too
        prior.net.down[0][1].running_mean.uniform_(-0.5, 0.5)
    path = tmp_path / "p.pt"
    save_hair_prior(prior, path, {"steps": 3})
    back = load_hair_prior(path)
    crops = np.random.default_rng(0).random((2, 32, 32, 3))
    np.testing.assert_array_equal(back.predict_crops(crops), prior.predict_crops(crops))
    np.testing.assert_array_equal(back.canon, prior.canon)
    assert back.net.cfg == TINY and back.meta == {"steps": 3}


def test_load_refuses_missing_and_foreign_files(tmp_path):
    """A missing file is bad input (exit 3); one that is no hair prior is a file-format
    error (exit 5), as for the generator and checkpoints (before 2026-12-05 it was exit 3)."""
    from head360cli.errors import FileFormatError

    with pytest.raises(BadInputError, match="does not exist"):
        load_hair_prior(tmp_path / "none.pt")
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(FileFormatError, match="expected a head360-hair-prior/1"):
        load_hair_prior(tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(FileFormatError, match="found a file torch cannot read"):
        load_hair_prior(tmp_path / "junk.pt")
    # weights that do not fit the configuration they carry: a KeyError or RuntimeError
    save_hair_prior(_tiny_prior(1), tmp_path / "p.pt", {})
    blob = torch.load(tmp_path / "p.pt", weights_only=True)
    blob["state_dict"] = {k: v[..., :1] if v.ndim else v for k, v in blob["state_dict"].items()}
    torch.save(blob, tmp_path / "cut.pt")
    with pytest.raises(FileFormatError, match="do not fit together"):
        load_hair_prior(tmp_path / "cut.pt")
    del blob["config"]
    torch.save(blob, tmp_path / "noconfig.pt")
    with pytest.raises(FileFormatError, match="do not fit together"):
        load_hair_prior(tmp_path / "noconfig.pt")


def _disc_data(n: int = 12, size: int = 32):
    """Crops of a grey 'head' disc under a dark 'hair' cap, as render_crops returns them."""
    yy, xx = np.mgrid[0:size, 0:size]
    head = ((xx - size / 2) ** 2 + (yy - size / 2) ** 2) < (size * 0.35) ** 2
    hair = head & (yy < size * 0.4)
    rgb = np.zeros((n, size, size, 3), np.uint8)
    rgb[:, head] = (200, 160, 140)
    rgb[:, hair] = (50, 35, 20)
    alpha = np.repeat(head[None] * 255, n, 0).astype(np.uint8)
    return {"rgb": rgb, "alpha": alpha, "hair": np.repeat(hair[None] * 255, n, 0)
            .astype(np.uint8)}


def test_augmenter_batches_are_valid_and_seeded():
    data = _disc_data()
    a, b = Augmenter(data, seed=5), Augmenter(data, seed=5)
    img, mask = a.batch(6)
    assert img.shape == (6, 3, 32, 32) and mask.shape == (6, 1, 32, 32)
    assert img.min() >= 0 and img.max() <= 1
    assert set(mask.unique().tolist()) <= {0.0, 1.0}
    assert 0 < mask.mean() < 0.5
    img2, mask2 = b.batch(6)
    assert torch.equal(img, img2) and torch.equal(mask, mask2)
    assert not torch.equal(a.batch(6)[0], img)


def test_augmenter_frames_repeat_the_edge_and_leave_the_rest():
    """Photo frames: each framed crop is its unframed self cut to a rectangle around the
    face with the rectangle's edge pixels repeated beyond it (as ``crop_photo`` fills
    the part of a crop outside the photo); the targets, and the crops of a zero share,
    are those of the same seed without frames."""
    data = _disc_data()
    plain, framed = Augmenter(data, seed=5), Augmenter(data, seed=5, frame_share=1.0)
    img, mask = plain.batch(8)
    img_f, mask_f = framed.batch(8)
    assert torch.equal(mask, mask_f)
    s = img.shape[-1]
    ramp = torch.arange(s)
    cut = 0
    for b in range(8):
        # the centre row and column are always inside: where they match the unframed
        # crop is the rectangle (the crops carry sensor noise, so matches are not chance)
        xs = torch.nonzero((img_f[b, :, s // 2] == img[b, :, s // 2]).all(0))[:, 0]
        ys = torch.nonzero((img_f[b, :, :, s // 2] == img[b, :, :, s // 2]).all(0))[:, 0]
        x0, x1, y0, y1 = int(xs[0]), int(xs[-1]), int(ys[0]), int(ys[-1])
        assert x0 <= 0.3 * s and x1 >= 0.7 * s - 1 and y0 <= 0.3 * s and y1 >= 0.75 * s - 1
        expected = img[b][:, ramp.clamp(y0, y1)][:, :, ramp.clamp(x0, x1)]
        assert torch.equal(img_f[b], expected)
        cut += (x0, y0, x1, y1) != (0, 0, s - 1, s - 1)
    assert cut >= 5  # each side is cut with chance 0.7: nearly every crop is framed
    assert torch.equal(Augmenter(data, seed=5, frame_share=0.0).batch(8)[0], img)


def _eyes(y: float, left: float, right: float) -> np.ndarray:
    """Twelve eye landmarks (iBUG 36-47): six around each centre."""
    ring = np.stack([np.cos(np.arange(6)), 0.3 * np.sin(np.arange(6))], 1)
    return np.concatenate([ring + np.array([left, y]), ring + np.array([right, y])]).astype(
        np.float32)


def test_draw_hat_covers_the_head_above_the_eyes_only():
    """A hat lies above the eye line (its brim included), changes no pixel it does not
    cover, is saturated when vivid, and is not drawn where no head is above its line."""
    s = 64
    yy, xx = np.mgrid[0:s, 0:s]
    alpha = torch.tensor((((xx - 32) ** 2 + (yy - 34) ** 2) < 22 ** 2).astype(np.float32))
    img = torch.rand(3, s, s, generator=torch.Generator().manual_seed(0))
    eyes = _eyes(36.0, 26.0, 38.0)
    rng = np.random.default_rng(1)
    covered = 0
    for _ in range(20):
        out, cover = draw_hat(img, alpha, eyes, lambda: float(rng.random()), vivid=1.0)
        assert out.shape == img.shape and cover.shape == alpha.shape
        assert (cover[37:] == 0).all()  # nothing at or below the eyes
        assert torch.equal(out[:, cover == 0], img[:, cover == 0])
        hat = cover == 1
        covered += int(hat.sum())
        if hat.sum() > 20:
            px = out[:, hat]
            sat = (px.max(0).values - px.min(0).values) / px.max(0).values.clamp_min(1e-6)
            assert sat.median() > 0.3
    assert covered > 20 * 150  # hats of a useful size were drawn
    out, cover = draw_hat(img, torch.zeros(s, s), eyes, lambda: float(rng.random()))
    assert (cover == 0).all() and torch.equal(out, img)


def test_augmenter_hats_take_hair_out_of_the_target_only():
    """Hats come from their own generator: the rest of a batch is the batch without
    them, the hat's pixels leave the hair target, and a zero share changes nothing."""
    data = _disc_data()
    canon = np.zeros((41, 2), np.float32)
    canon[9:21] = _eyes(18.0, 12.0, 20.0)
    plain = Augmenter(data, seed=5)
    hats = Augmenter(data, seed=5, hat_share=1.0, canon=canon)
    img, mask = plain.batch(8)
    img_h, mask_h = hats.batch(8)
    assert (mask_h <= mask).all() and mask_h.sum() < 0.8 * mask.sum()
    assert not torch.equal(img_h, img)
    still = (mask_h == mask).all(1, keepdim=True).expand_as(img)
    assert still.float().mean() > 0.5
    none = Augmenter(data, seed=5, hat_share=0.0, canon=canon).batch(8)
    assert torch.equal(none[0], img) and torch.equal(none[1], mask)
    with pytest.raises(ValueError, match="canonical landmarks"):
        Augmenter(data, seed=5, hat_share=0.5)


def test_training_can_start_from_a_checkpoint(tmp_path):
    """``init``: training starts from a saved prior's weights (its shape kept, whatever
    ``net_cfg`` says), and a prior aligned otherwise is refused."""
    data = _disc_data()
    canon = np.zeros((41, 2), np.float32)
    start = _tiny_prior(3)
    start.canon = canon
    save_hair_prior(start, tmp_path / "start.pt")
    cfg = HairPriorTrainConfig(steps=1, batch=2, lr=1e-12, seed=0,
                               init=str(tmp_path / "start.pt"))
    prior, summary = train_hair_prior(cfg, HairPriorConfig(), progress=False,
                                      data=(canon, data))
    assert prior.net.cfg == TINY and summary["train_config"]["init"].endswith("start.pt")
    for name, value in start.net.state_dict().items():
        if value.dtype.is_floating_point and "running" not in name:
            torch.testing.assert_close(prior.net.state_dict()[name], value, atol=1e-6,
                                       rtol=0)
    with pytest.raises(BadInputError, match="align its crops"):
        train_hair_prior(cfg, TINY, progress=False, data=(canon + 5, data))
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    junk = HairPriorTrainConfig(steps=1, batch=2, init=str(tmp_path / "junk.pt"))
    from head360cli.errors import FileFormatError

    # before any rendering (data=None would render); exit 5 since 2026-12-05, as for the
    # other model files (it was BadInputError, exit 3)
    with pytest.raises(FileFormatError, match=r"junk\.pt: expected a head360-hair-prior/1"):
        train_hair_prior(junk, TINY, progress=False)


def test_ctrl_c_checkpoints_the_step_and_resuming_ends_as_one_run(tmp_path, monkeypatch):
    """Ctrl-C lost the whole run (render and training, 23 min at the defaults); now it
    ends after the step it is on with a checkpoint, and the same run resumes from it to
    the weights of a run never stopped. Hats and photo frames are on, so all three of the
    augmenter's generators are restored."""
    import signal

    import head360cli.fitting.hair_prior_train as hpt

    cfg = HairPriorTrainConfig(steps=6, batch=3, lr=5e-3, seed=0, frame_share=0.5,
                               hat_share=0.5)
    canon = np.tile(np.array([[16.0, 14.0]], np.float32), (41, 1))
    canon[:, 0] += np.linspace(-6, 6, 41)
    data = (canon, _disc_data())
    ckpt = tmp_path / "p.resume.pt"
    real, calls = hpt.hair_loss, []

    def interrupted_in_the_third_step(logits, target):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return real(logits, target)

    monkeypatch.setattr(hpt, "hair_loss", interrupted_in_the_third_step)
    with pytest.raises(KeyboardInterrupt):
        train_hair_prior(cfg, TINY, progress=False, data=data, checkpoint=ckpt)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # put back
    assert torch.load(ckpt, weights_only=True)["step"] == 3
    monkeypatch.setattr(hpt, "hair_loss", real)
    lines = []
    resumed, summary = train_hair_prior(cfg, TINY, progress=False, data=data,
                                        checkpoint=ckpt, log=lines.append)
    assert summary["steps"] == 6 and summary["resumed_from"] == 3
    assert "resuming from step 3 of 6" in lines[0]
    whole, whole_summary = train_hair_prior(cfg, TINY, progress=False, data=data)
    assert summary["final_loss"] == pytest.approx(whole_summary["final_loss"], abs=1e-4)
    for name, value in whole.net.state_dict().items():
        torch.testing.assert_close(resumed.net.state_dict()[name], value, atol=1e-6,
                                   rtol=0)
    # a run stopped at its last step saves it too, and resumes to a prior with no step left
    done = tmp_path / "done.resume.pt"
    train_hair_prior(cfg, TINY, progress=False, data=data, checkpoint=done, stop_at=6)
    again, summary = train_hair_prior(cfg, TINY, progress=False, data=data, checkpoint=done)
    assert (summary["steps"], summary["resumed_from"]) == (6, 6)
    for name, value in whole.net.state_dict().items():
        torch.testing.assert_close(again.net.state_dict()[name], value, atol=1e-6, rtol=0)


def test_a_checkpoint_is_resumed_by_its_own_run_only(tmp_path):
    """Settings that change what is trained are refused, naming the setting and both
    values, before any rendering; the step count and time limit may change."""
    import dataclasses

    from head360cli.errors import FileFormatError
    from head360cli.fitting.hair_prior_train import RUN_FORMAT

    cfg = HairPriorTrainConfig(steps=4, batch=2, seed=0)
    data = (np.zeros((41, 2), np.float32), _disc_data())
    ckpt = tmp_path / "p.resume.pt"
    train_hair_prior(cfg, TINY, progress=False, data=data, checkpoint=ckpt, stop_at=2)
    with pytest.raises(BadInputError, match=r"found lr 0\.01 where it has 0\.002"):
        train_hair_prior(dataclasses.replace(cfg, lr=1e-2), TINY, progress=False,
                         checkpoint=ckpt)  # no data: it would render, were it not refused
    wider = HairPriorConfig(width=8, levels=2, crop=32)
    with pytest.raises(BadInputError, match=r"found network .*'width': 8"):
        train_hair_prior(cfg, wider, progress=False, checkpoint=ckpt)
    with pytest.raises(BadInputError, match="at least the 2 steps"):
        train_hair_prior(dataclasses.replace(cfg, steps=1), TINY, progress=False,
                         checkpoint=ckpt)
    _, summary = train_hair_prior(dataclasses.replace(cfg, steps=3, minutes=5.0), TINY,
                                  progress=False, data=data, checkpoint=ckpt)
    assert (summary["steps"], summary["resumed_from"]) == (3, 2)
    save_hair_prior(_tiny_prior(), tmp_path / "prior.pt")  # a prior is no run
    with pytest.raises(FileFormatError, match=RUN_FORMAT):
        train_hair_prior(cfg, TINY, progress=False, checkpoint=tmp_path / "prior.pt")


def test_hair_loss_prefers_the_right_mask():
    target = torch.zeros(2, 1, 8, 8)
    target[:, :, :3] = 1
    right = (target * 2 - 1) * 6
    assert hair_loss(right, target) < 0.05
    assert hair_loss(-right, target) > 1.5


@pytest.mark.slow
def test_training_lowers_the_loss_on_a_toy_task():
    cfg = HairPriorTrainConfig(steps=150, batch=8, lr=5e-3, seed=0)
    canon = np.zeros((41, 2), np.float32)
    prior, summary = train_hair_prior(cfg, TINY, progress=False, data=(canon, _disc_data()))
    assert summary["steps"] == 150 and summary["crops"] == 12
    aug = Augmenter(_disc_data(), seed=1)
    img, mask = aug.batch(16)
    untrained = HairPriorNet(TINY).eval()
    with torch.no_grad():
        after = float(hair_loss(prior.net(img), mask))
        before = float(hair_loss(untrained(img), mask))
    assert after < 0.6 * before  # measured 0.74 vs 1.70


def test_render_crops_aligns_corpus_views():
    """Two corpus heads, two views each: the crops hold the head near the centre and the
    hair (if any) inside the head's silhouette."""
    cfg = HairPriorTrainConfig(heads=2, views=2, render_size=96)
    canon, data = render_crops(cfg, 64)
    assert canon.shape == (41, 2)
    assert data["rgb"].shape == (4, 64, 64, 3) and data["hair"].shape == (4, 64, 64)
    alpha, hair = data["alpha"] > 127, data["hair"] > 127
    assert alpha[:, 32, 32].all()  # the crop's centre is on the face
    assert (hair & ~alpha).sum() <= 0.01 * hair.sum() + 4


@pytest.fixture(scope="module")
def shipped():
    prior = default_hair_prior()
    if prior is None:
        pytest.fail("models/hair_prior.pt is not installed: run head360 train-hair-prior")
    return prior


def test_shipped_prior_is_the_documented_network(shipped):
    assert shipped.net.cfg == HairPriorConfig()
    assert shipped.meta["steps"] == 2400 and shipped.meta["crops"] == 3000
    assert shipped.canon.shape == (41, 2)


@pytest.mark.slow
@pytest.mark.parametrize(("index", "iou"), [(5, 0.961), (24, 0.935), (27, 0.868)])
def test_shipped_prior_alone_reads_held_out_corpus_heads(shipped, index, iou):
    """The network alone on development heads it never saw (corpus seed 1, test split):
    IoU of its map at 0.5 with the true hair, measured as given."""
    from head360cli.fitting.hair_parse import mask_iou
    from tests.fitting.test_hair_parse import _corpus_portrait

    img, lm, truth, _ = _corpus_portrait(index)
    p = shipped.predict(img, lm)
    assert mask_iou(p > 0.5, truth) == pytest.approx(iou, abs=0.02)
    np.testing.assert_array_equal(shipped.predict(img, lm), p)  # deterministic


@pytest.mark.parametrize(("field", "value", "expected"), [
    ("lr", float("inf"), "finite and > 0"), ("batch", 0, ">= 1"), ("heads", -1, ">= 1"),
    ("hat_share", 2.0, "in [0, 1]"), ("shrink", 0.0, "in (0, 1]"),
    ("pitch", (30.0, -10.0), "a (low, high) range within -90..90 degrees"),
    ("minutes", float("nan"), "finite and >= 0"),
])
def test_train_config_refuses_settings_no_run_trains_with(field, value, expected):
    """From Python, HairPriorTrainConfig took any value (the CLI checked its options)."""
    import re

    with pytest.raises(BadInputError, match=re.escape(
            f"expected HairPriorTrainConfig.{field} {expected}, found {value!r}")):
        HairPriorTrainConfig(**{field: value})


def test_a_run_that_diverges_stops_and_a_prior_with_nan_is_refused(tmp_path):
    """train-hair-prior --lr 1e6 wrote a prior of NaN weights, exit 0 ("final_loss":
    null), which parse-hair and fit would then have used."""
    cfg = HairPriorTrainConfig(steps=40, batch=2, lr=1e6, seed=0)
    data = (np.zeros((41, 2), np.float32), _disc_data())
    with pytest.raises(BadInputError, match=r"loss to stay finite, found (nan|inf) at step \d+ "
                                            r"\(the weights diverged\): lower --lr"):
        train_hair_prior(cfg, TINY, progress=False, data=data)
    from head360cli.errors import FileFormatError

    prior = _tiny_prior()
    with torch.no_grad():
        next(prior.net.parameters())[0] = float("nan")
    save_hair_prior(prior, tmp_path / "nan.pt")
    with pytest.raises(FileFormatError, match="non-finite values"):
        load_hair_prior(tmp_path / "nan.pt")
