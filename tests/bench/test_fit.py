"""``head360 bench fit`` parts that run without ../shared/data, on tiny settings."""

from __future__ import annotations

from head360cli.bench.fit import _hair_style, _markdown


def test_hairstyle_accuracy_on_three_heads():
    r = _hair_style(views=3)
    assert r["heads"] == 3
    for key in ("true_mask", "parsed_mask"):
        assert 0.0 <= r[key]["top1"] <= r[key]["top3"] <= 1.0
    # Heads 0..2 wear styles 0..2 (bald, buzz, crew): with the true mask at least the
    # bald head (empty mask) and one other are right.
    assert r["true_mask"]["top1"] >= 2 / 3


def test_markdown_lists_every_part():
    r = {"hair_parse": {"figaro": {"photos": 2, "with_face": 0, "mean_iou": 0.5}},
         "hair_style": {"true_mask": {"top1": 0.9, "top3": 1.0},
                        "parsed_mask": {"top1": 0.5, "top3": 0.8}},
         "synthetic_fit": {"fast": {"mean": {"psnr_all_views": 15.0, "ssim_all_views": 0.8,
                                             "psnr_input_view": 20.0, "seconds": 12.0}}},
         "real": {"fast": {"mean": {"psnr_face": 22.0, "psnr_face_bald": 25.0,
                                    "distance_0": None,
                                    "distance_30": 0.7, "seconds": 13.0}}},
         "sweep": [{"texture_steps": 5, "psnr_face": 20.0, "invert_s": 3.0, "total_s": 9.0}]}
    md = _markdown(r)
    for text in ("| figaro | 2 | 0 | 0.500 |", "| true | 90.00% | 100.00% |",
                 "| fast | 15.00 | 0.800 | 20.00 | 12.0 |",
                 "| fast | 22.00 | 25.00 | - | 0.700 | 13.0 |",
                 "| 5 | 20.00 | 3.0 | 9.0 |"):
        assert text in md
