"""``head360 bench multiview``: fitted heads seen from where the photo did not see them,
against real photos of the same people from there.

Data: ``../shared/data/multiview/pointing04`` (Pointing'04: each person photographed by one
still camera while turning the head from yaw -90 to +90 degrees every 15 degrees). For
each person and series, the tilt-0 pan-0 photo is fitted (``fit_photo``, per preset);
the fitted head is turned by each other pan in front of the photo's own camera (about
the vertical axis through the head's origin) and rendered in the fit's crop, where the
real photos are cropped by the same map. Per |yaw| bin:

- the dlib face-descriptor distance between the render and the real photo at that yaw
  (dlib's HOG detector, 68-point shape and recognition model, on both crops);
- how often dlib finds a face in the render where it finds one in the real photo;
- the distance between the real frontal and the real turned photo: what the turn alone
  costs the descriptor, the floor for the first;
- the IoU of the head's silhouette: the render's coverage against the real photo's
  foreground on its plain backdrop, both above the fitted chin (below it the real photo
  shows the neck and clothes, the render a cut neck);
- the hair (:mod:`head360cli.bench.hair`): the IoU of the render's hair (where it is the
  nearest surface) with the hair MediaPipe's segmenter finds in the real photo, the
  CIEDE2000 between their median colours, whether the segmenter reads the render's hair
  as hair where it finds hair in the real photo, and the stair steps on the render's
  hair silhouette.

It writes ``multiview_sheet.png``: for one person the real photos in one row and the
renders of each preset below.
"""

from __future__ import annotations

import csv
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["bench_multiview", "foreground_mask", "orbit", "read_pointing04"]

YAW_BINS = ((15.0, 45.0), (60.0, 60.0), (75.0, 90.0), (15.0, 90.0))
"""|yaw| bins reported (inclusive), as the goals are stated, and all turned views."""
HAIR_BINS = ((0.0, 0.0), (15.0, 45.0), (60.0, 60.0), (75.0, 90.0), (90.0, 90.0),
             (15.0, 90.0))
"""|yaw| bins of the hair's measures (inclusive): the photo's own view, the turned ones
as above, and the sides alone."""
FOREGROUND_DIFF = 28.0
"""A pixel further than this (0-255, largest channel) from every colour the backdrop has
in its row is foreground (:func:`foreground_mask`)."""


def read_pointing04(folder: Path) -> list[dict[str, Any]]:
    """The rows of ``index.csv`` (file, person, series, tilt, pan, face box) with ints."""
    with open(folder / "index.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for key in ("person", "series", "tilt_deg", "pan_deg"):
            r[key] = int(r[key])
        r["path"] = folder / r["file"]
    return rows


def foreground_mask(rgb: np.ndarray) -> np.ndarray:
    """``(H, W)`` bool: what is not the plain backdrop of ``rgb (H, W, 3)`` uint8.

    The backdrop's colour is read per row from the outermost tenth of columns on each
    side (medians); a pixel is backdrop where it lies within :data:`FOREGROUND_DIFF` of
    the left colour, the right one or the line between them across the row (a wall lit
    from one side, or a brighter panel on one side). The rest is opened, and its
    largest connected part, with its holes filled, is the foreground.
    """
    import cv2

    img = rgb.astype(np.float32)
    h, w = img.shape[:2]
    edge = max(2, w // 10)
    left = np.median(img[:, :edge], 1)[:, None]  # (H, 1, 3)
    right = np.median(img[:, w - edge:], 1)[:, None]
    t = ((np.arange(w, dtype=np.float32) - edge / 2) / max(w - edge, 1))[None, :, None]
    diff = np.minimum.reduce([np.abs(img - b).max(-1)
                              for b in (left, right, left + (right - left) * t)])
    mask = cv2.morphologyEx((diff > FOREGROUND_DIFF).astype(np.uint8), cv2.MORPH_OPEN,
                            np.ones((3, 3), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return np.zeros((h, w), bool)
    mask = (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    outside = np.zeros((h + 2, w + 2), np.uint8)
    filled = mask.copy()
    for corner in ((0, 0), (w - 1, 0)):  # the backdrop from the top corners
        if not filled[corner[1], corner[0]]:
            cv2.floodFill(filled, outside, corner, 1)
    return (mask | (1 - filled)).astype(bool)


def orbit(c2w: np.ndarray, yaw_deg: float) -> np.ndarray:
    """``(4, 4)`` camera ``c2w`` carried about the head's vertical axis (through its
    origin) as if the head turned by ``yaw_deg`` in front of it: + shows the head's left
    side, as ``render --yaw``."""
    a = np.radians(yaw_deg)
    turn = np.eye(4)
    turn[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    return (turn @ np.asarray(c2w, np.float64)).astype(np.float32)


def _project(points: np.ndarray, c2w: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Pixels ``(N, 2)`` of world ``points (N, 3)`` seen by camera ``c2w`` (OpenCV axes)."""
    w2c = np.linalg.inv(np.asarray(c2w, np.float64))
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    uv = cam @ np.asarray(k, np.float64).T
    return uv[:, :2] / uv[:, 2:3]


def _iou(a: np.ndarray, b: np.ndarray) -> float | None:
    union = np.logical_or(a, b).sum()
    return None if union == 0 else float(np.logical_and(a, b).sum() / union)


def _person(rows: list[dict[str, Any]], presets: tuple[str, ...], work: Path,
            device: str) -> dict[str, Any]:
    """Fit the frontal photo of one person's series with each preset and compare the
    renders at every pan with the real photos."""
    import torch

    from head360cli.bench.colours import outlier_share, photo_palette_of
    from head360cli.bench.fit import _descriptor
    from head360cli.bench.hair import segmented_hair
    from head360cli.drive.views import photo_expression
    from head360cli.fitting.pipeline import fit_photo, load_head_renderer
    from head360cli.fitting.texture import crop_image
    from head360cli.io.headfile import read_head
    from head360cli.io.images import load_image
    from head360cli.mesh.template import template
    from head360cli.model.head_render import to_uint8

    by_pan = {r["pan_deg"]: r for r in rows if r["tilt_deg"] == 0}
    pans = sorted(by_pan)
    front = by_pan[0]["path"]
    real = {p: load_image(by_pan[p]["path"]).pixels for p in pans}
    out: dict[str, Any] = {"person": rows[0]["person"], "series": rows[0]["series"],
                           "pans": pans, "presets": {}}
    sheet_rows: dict[str, list[np.ndarray]] = {}
    real_crops = None
    palette = photo_palette_of(real[0])
    for preset in presets:
        head_file = work / f"p{out['person']}s{out['series']}_{preset}.h360"
        s = fit_photo(front, head_file, preset=preset, device=device)
        affine = np.asarray(s["crop"]["affine"], np.float64)
        res = int(s["crop"]["size"])
        if real_crops is None:
            real_crops = {p: crop_image(real[p], affine, res) for p in pans}
            real_desc = {p: _descriptor(real_crops[p]) for p in pans}
            real_fg = {p: foreground_mask(real[p]) for p in pans}
            real_fg = {p: crop_image(real_fg[p].astype(np.uint8), affine, res, nearest=True)
                       > 0 for p in pans}
            real_hair = {p: segmented_hair(real_crops[p]) for p in pans}
            sheet_rows["real"] = [real_crops[p] for p in pans]
        arrays = read_head(head_file).arrays
        head = load_head_renderer(head_file, device=device, precision="fp32", size=res)
        c2w, k = np.asarray(arrays["pose"]), np.asarray(arrays["intrinsics"])
        chin = template().landmarks[8]
        chin_row = float(_project(np.asarray(arrays["vertices"])[chin][None], c2w, k)[0, 1])
        cut = int(np.clip(round(chin_row), 0, res))
        cams = torch.tensor(np.stack([orbit(c2w, p) for p in pans]))
        rgb, alpha, hair_alpha = head.render(cams, torch.tensor(k), expression=photo_expression(
            head.expression), alpha=True, hair_alpha=True)
        renders = to_uint8(rgb)
        alpha = alpha[:, 0].numpy()
        hair_alpha = hair_alpha[:, 0].numpy()
        per_pan = []
        for i, p in enumerate(pans):
            d = _descriptor(renders[i])
            ref, ref0 = real_desc[p], real_desc[0]
            fg = real_fg[p].copy()
            sil = alpha[i] > 0.5
            fg[cut:] = False
            sil[cut:] = False
            per_pan.append({
                "pan": p, "render_face": d is not None, "real_face": ref is not None,
                "distance": None if d is None or ref is None
                else round(float(np.linalg.norm(d - ref)), 4),
                "real_to_front": None if ref is None or ref0 is None
                else round(float(np.linalg.norm(ref - ref0)), 4),
                "iou": None if (r := _iou(sil, fg)) is None else round(r, 4),
                **_hair_measures(renders[i], hair_alpha[i] > 0.5, real_crops[p],
                                 real_hair[p])})
        shares = [] if palette is None else [
            x for x in outlier_share(renders, alpha, palette) if x is not None]
        out["presets"][preset] = {"pans": per_pan, "seconds": s["timings"]["total"],
                                  "hair": s["hair_style"]["name"],
                                  "colour_outliers": round(float(np.mean(shares)), 4)
                                  if shares else None}
        sheet_rows[preset] = list(renders)
    out["sheet_rows"] = sheet_rows
    return out


def _hair_measures(render: np.ndarray, hair: np.ndarray, real: np.ndarray,
                   real_hair: np.ndarray) -> dict[str, Any]:
    """The hair's measures at one yaw: a render ``(H, W, 3)`` uint8 and its hair pixels
    ``(H, W)`` bool against the real photo's crop and the hair the segmenter finds there.
    """
    from head360cli.bench.hair import MIN_HAIR_PIXELS, compare_hair, reads_as_hair

    real_has = int(np.count_nonzero(real_hair)) >= MIN_HAIR_PIXELS
    return {"real_hair": real_has, **compare_hair(render, hair, real, real_hair),
            "hair_read": reads_as_hair(render, hair) if real_has else None}


def _hair_bins(people: list[dict[str, Any]], preset: str) -> list[dict[str, Any]]:
    """The hair's per-pan measures of ``preset`` over every person, by |yaw| bin."""
    rows = [r for p in people for r in p["presets"][preset]["pans"]]
    out = []
    for lo, hi in HAIR_BINS:
        sel = [r for r in rows if lo <= abs(r["pan"]) <= hi]
        real = [r for r in sel if r["real_hair"]]
        out.append({
            "yaw": f"{lo:.0f}-{hi:.0f}" if lo != hi else f"{lo:.0f}",
            "views": len(sel),
            "hair_iou": _mean([r["hair_iou"] for r in sel]),
            "hair_delta_e": _mean([r["hair_delta_e"] for r in sel]),
            "colours": sum(r["hair_delta_e"] is not None for r in sel),
            "read_where_real": [sum(bool(r["hair_read"]) for r in real), len(real)],
            "steps": sum(r["hair_steps"] for r in sel),
            "views_with_steps": sum(r["hair_steps"] > 0 for r in sel)})
    return out


def _mean(values: list[float | None]) -> float | None:
    values = [v for v in values if v is not None]
    return round(float(np.mean(values)), 4) if values else None


def _bins(people: list[dict[str, Any]], preset: str) -> list[dict[str, Any]]:
    """The per-pan measures of ``preset`` over every person, by |yaw| bin."""
    rows = [r for p in people for r in p["presets"][preset]["pans"]]
    out = []
    for lo, hi in YAW_BINS:
        sel = [r for r in rows if lo <= abs(r["pan"]) <= hi]
        dist = [r["distance"] for r in sel if r["distance"] is not None]
        base = [r["real_to_front"] for r in sel if r["real_to_front"] is not None]
        real_found = [r for r in sel if r["real_face"]]
        ious = [r["iou"] for r in sel if r["iou"] is not None]
        out.append({
            "yaw": f"{lo:.0f}-{hi:.0f}" if lo != hi else f"{lo:.0f}",
            "distance": round(float(np.mean(dist)), 4) if dist else None,
            "distances": len(dist),
            "real_to_front": round(float(np.mean(base)), 4) if base else None,
            "found_where_real": [sum(r["render_face"] for r in real_found), len(real_found)],
            "found_render": [sum(r["render_face"] for r in sel), len(sel)],
            "found_real": [len(real_found), len(sel)],
            "iou": round(float(np.mean(ious)), 4) if ious else None})
    return out


def _sheet(person: dict[str, Any], size: int = 128) -> np.ndarray:
    """The contact sheet of one person: real photos, then each preset's renders."""
    import cv2

    from head360cli.drive.views import grid_image

    images, labels = [], []
    for name, row in person["sheet_rows"].items():
        for pan, img in zip(person["pans"], row, strict=True):
            images.append(cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA))
            labels.append(f"{name} {pan:+d}")
    return grid_image(np.stack(images), labels, cols=len(person["pans"]))


def bench_multiview(presets: tuple[str, ...] = ("fast", "quality"),
                    people: tuple[int, ...] | None = None, series: tuple[int, ...] = (1,),
                    sheet_person: int = 2, out_dir: str | Path | None = None,
                    device: str = "cpu", progress=None) -> tuple[dict[str, Any], str]:
    """Run the multi-view comparison; returns ``(result, markdown)`` and writes the sheet
    of ``sheet_person`` into ``out_dir`` (if given).

    Raises:
        BadInputError: The shared multi-view set is not there.
    """
    from PIL import Image

    from head360cli.bench.report import device_fields
    from head360cli.errors import BadInputError
    from head360cli.io.images import png_info
    from head360cli.paths import shared_data_dir

    data = shared_data_dir()
    folder = None if data is None else data / "multiview" / "pointing04"
    if folder is None or not (folder / "index.csv").is_file():
        raise BadInputError("expected the real multi-view photos in "
                            "../shared/data/multiview/pointing04, found none")
    say = progress or (lambda text: None)
    rows = read_pointing04(folder)
    chosen = sorted({(r["person"], r["series"]) for r in rows
                     if (people is None or r["person"] in people) and r["series"] in series})
    if not chosen:
        raise BadInputError(f"expected people and series of the set, found none of "
                            f"people {people} series {series}")
    t0 = time.perf_counter()
    result: dict[str, Any] = {**device_fields(device), "presets": list(presets),
                              "people": []}
    with tempfile.TemporaryDirectory() as tmp:
        for person, ser in chosen:
            say(f"person {person}, series {ser}")
            result["people"].append(_person(
                [r for r in rows if r["person"] == person and r["series"] == ser],
                presets, Path(tmp), device))
    sheet_of = next((p for p in result["people"] if p["person"] == sheet_person),
                    result["people"][0])
    if out_dir is not None:
        from head360cli.io.atomic import atomic_path

        Path(out_dir).mkdir(parents=True, exist_ok=True)
        target = Path(out_dir) / "multiview_sheet.png"
        with atomic_path(target) as tmp_png:
            Image.fromarray(_sheet(sheet_of)).save(tmp_png, format="PNG", pnginfo=png_info())
        result["sheet"] = str(target)
    for p in result["people"]:
        del p["sheet_rows"]
    result["bins"] = {preset: _bins(result["people"], preset) for preset in presets}
    result["hair_bins"] = {preset: _hair_bins(result["people"], preset)
                           for preset in presets}
    result["colour_outliers"] = {preset: _mean([p["presets"][preset]["colour_outliers"]
                                                for p in result["people"]])
                                 for preset in presets}
    result["seconds"] = round(time.perf_counter() - t0, 1)
    return result, _markdown(result)


def _markdown(r: dict[str, Any]) -> str:
    def f(x, fmt=".3f"):
        return "-" if x is None else format(x, fmt)

    lines = ["## Multi-view: renders against real photos (Pointing'04, tilt 0)", "",
             f"{len(r['people'])} people; each frontal photo fitted, the head turned to the "
             "other photos' yaws.", "",
             "| preset | \\|yaw\\| | descriptor distance render-real | real front-real side "
             "| faces found in renders where real has one | in renders / real | head "
             "silhouette IoU |", "|---|---|---|---|---|---|---|"]
    for preset, bins in r["bins"].items():
        for b in bins:
            fw, fr, fe = b["found_where_real"], b["found_render"], b["found_real"]
            lines.append(
                f"| {preset} | {b['yaw']} | {f(b['distance'])} ({b['distances']}) | "
                f"{f(b['real_to_front'])} | {fw[0]}/{fw[1]} | {fr[0]} / {fe[0]} of {fe[1]} "
                f"| {f(b['iou'])} |")
    lines += ["", "Hair, render against real photo (the segmenter's hair on the real "
              "photo; CIEDE2000 of the median colours; read: the segmenter finds the "
              "render's hair where it finds hair in the real photo; steps: jumps of 2 px "
              "or more on the render's hair silhouette):", "",
              "| preset | \\|yaw\\| | views | hair IoU | hair colour CIEDE2000 (views) | "
              "read as hair | steps (views with any) |", "|---|---|---|---|---|---|---|"]
    for preset, bins in r.get("hair_bins", {}).items():
        for b in bins:
            rw = b["read_where_real"]
            lines.append(f"| {preset} | {b['yaw']} | {b['views']} | {f(b['hair_iou'])} | "
                         f"{f(b['hair_delta_e'], '.1f')} ({b['colours']}) | {rw[0]}/{rw[1]} "
                         f"| {b['steps']} ({b['views_with_steps']}) |")
    lines += ["", "Colour outliers (head pixels of the renders whose colour the frontal "
              "photo's skin and hair do not have): " + ", ".join(
                  f"{k} {'-' if v is None else format(v, '.2%')}"
                  for k, v in r["colour_outliers"].items()) + ".",
              "", "Per person (IoU over all yaws, fit seconds):", ""]
    for p in r["people"]:
        cells = []
        for preset, v in p["presets"].items():
            ious = [x["iou"] for x in v["pans"] if x["iou"] is not None]
            cells.append(f"{preset} IoU {np.mean(ious):.3f}, {v['seconds']:.1f} s, "
                         f"{v['hair']}, colour outliers {v['colour_outliers']}")
        lines.append(f"- person {p['person']} series {p['series']}: " + "; ".join(cells))
    return "\n".join(lines)
