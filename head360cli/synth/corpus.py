"""Writing the SynHead-P corpus to disk, and its contact sheets.

Layout of ``OUTDIR``::

    corpus.json                    the configuration and format version
    index.jsonl                    one line per view: files, identity, expression weights,
                                   hairstyle and colour, camera (c2w, intrinsics, yaw, pitch)
    <split>/id0000/                one folder per identity, written atomically
        meta.json                  identity parameters, appearance, hair, its index lines
        e00_c05.png                RGBA render with hair (expression 0, rig camera 5)
        e00_c05_bald.png           RGBA render of the same view without hair
        e00_c05_hair.png           hair coverage (L, 255 = hair)
        e00_c05_face.png           face coverage in the render with hair (L)

Everything derives from the seed, so the same arguments give identical bytes. An identity
whose folder exists is skipped, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from head360cli.errors import BadInputError, FileFormatError
from head360cli.io.jsontext import dumps

__all__ = ["CORPUS_FORMAT", "CorpusConfig", "expressions_for", "views_for", "write_corpus",
           "write_previews"]

CORPUS_FORMAT = 1


@dataclasses.dataclass(frozen=True)
class CorpusConfig:
    """What ``head360 synth`` writes."""

    identities: int = 100
    """Number of identities of the split."""
    expressions: int = 4
    """Per identity: neutral plus this many minus one single ARKit shapes at weight 1,
    rotating over identities so that all 52 are covered; 53 gives every shape to every
    identity, as in SynHead100."""
    views: int = 24
    """Cameras per expression, drawn from the 72-camera rig (72 = all of them)."""
    size: int = 256
    """Image width and height."""
    seed: int = 0
    """Corpus seed: identities, appearances, hair and camera choices derive from it."""
    split: str = "train"
    """``train`` or ``test`` (held-out identities, from other seeds)."""
    samples: int = 2
    """Antialiasing samples per pixel (1, 2 or 4)."""
    start: int = 0
    """Index of the first identity (to write a split in parts)."""
    skin_scan: str = ""
    """Folder of a head scan (``head.obj``, ``lambertian.jpg``) whose skin detail every
    head's texture takes; ``""`` paints noise instead."""
    soft_hair: bool = False
    """Hairlines that follow each style's line and thin out at the edge, instead of
    stepping from grid row to grid row."""

    def __post_init__(self) -> None:
        """Refuse settings no corpus can be written with (the CLI checks its options first;
        this guards library callers, before any file is made).

        Raises:
            BadInputError: The first field out of range, expected against found.
        """
        for name in ("identities", "expressions", "views", "size", "seed", "samples",
                     "start"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise BadInputError(f"expected an integer {name}, found {value!r}")
        checks = [
            (self.identities >= 1, f"identities >= 1, found {self.identities}"),
            (1 <= self.expressions <= 53, f"expressions in 1..53, found {self.expressions}"),
            (1 <= self.views <= 72, f"views in 1..72, found {self.views}"),
            (16 <= self.size <= 2048, f"size in 16..2048, found {self.size}"),
            (self.seed >= 0, f"seed >= 0, found {self.seed}"),
            (self.split in ("train", "test"), f"split train or test, found {self.split!r}"),
            (self.samples in (1, 2, 4), f"samples 1, 2 or 4, found {self.samples}"),
            (self.start >= 0, f"start >= 0, found {self.start}"),
        ]
        for ok, message in checks:
            if not ok:
                raise BadInputError(f"expected {message}")


def expressions_for(index: int, count: int) -> list[dict[str, float]]:
    """The expressions of identity ``index``: neutral, then single shapes at weight 1."""
    from head360cli.mesh.arkit52 import ARKIT52

    out: list[dict[str, float]] = [{}]
    for e in range(1, count):
        out.append({ARKIT52[(index * (count - 1) + e - 1) % 52]: 1.0})
    return out


def views_for(cfg: CorpusConfig, index: int, expression: int) -> list[int]:
    """Rig cameras (0..71) rendered for one identity and expression."""
    if cfg.views == 72:
        return list(range(72))
    rng = np.random.default_rng([cfg.seed, 1 if cfg.split == "test" else 0, index, expression])
    return sorted(int(c) for c in rng.permutation(72)[: cfg.views])


def _png(array: np.ndarray, path: Path) -> None:
    from PIL import Image

    Image.fromarray(array).save(path, compress_level=6)


def _to_u8(x) -> np.ndarray:
    """``(..., C)`` float tensor in [0, 1] to uint8 numpy."""
    import torch

    return (x.clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()


def _write_identity(cfg: CorpusConfig, index: int, folder: Path, rel: str) -> list[dict]:
    import torch

    from head360cli.geometry.cameras import RIG_FOV_DEG, intrinsics_from_fov, rig72
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.synth.hair import HAIRSTYLES
    from head360cli.synth.scene import make_head, render_head

    head = make_head(index, cfg.split, cfg.seed, skin_scan=cfg.skin_scan or None,
                     soft_hair=cfg.soft_hair)
    c2w_all, yaw_all, pitch_all = rig72()
    k = intrinsics_from_fov(RIG_FOV_DEG, cfg.size, cfg.size)
    records = []
    for e, expr in enumerate(expressions_for(index, cfg.expressions)):
        weights = np.zeros(52)
        for name, value in expr.items():
            weights[INDEX[name]] = value
        cams = views_for(cfg, index, e)
        for start in range(0, len(cams), 8):
            chunk = cams[start:start + 8]
            c2w = c2w_all[chunk]
            hair = render_head(head, weights, c2w, k, cfg.size, with_hair=True,
                               samples=cfg.samples)
            bald = render_head(head, weights, c2w, k, cfg.size, with_hair=False,
                               samples=cfg.samples)
            for j, cam in enumerate(chunk):
                stem = f"e{e:02d}_c{cam:02d}"
                rgba = torch.cat([hair.rgb[j], hair.alpha[j]]).permute(1, 2, 0)
                rgba_bald = torch.cat([bald.rgb[j], bald.alpha[j]]).permute(1, 2, 0)
                _png(_to_u8(rgba), folder / f"{stem}.png")
                _png(_to_u8(rgba_bald), folder / f"{stem}_bald.png")
                _png(_to_u8(hair.labels[j, 0]), folder / f"{stem}_hair.png")
                _png(_to_u8(hair.labels[j, 1]), folder / f"{stem}_face.png")
                records.append({
                    "image": f"{rel}/{stem}.png",
                    "bald": f"{rel}/{stem}_bald.png",
                    "hair_mask": f"{rel}/{stem}_hair.png",
                    "face_mask": f"{rel}/{stem}_face.png",
                    "split": cfg.split,
                    "identity": index,
                    "expression": expr,
                    "hair_style": head.hair_style,
                    "hair_style_name": HAIRSTYLES[head.hair_style].name,
                    "hair_colour": head.hair_colour,
                    "camera": {
                        "rig_index": cam,
                        "yaw": float(yaw_all[cam]),
                        "pitch": float(pitch_all[cam]),
                        "c2w": [round(float(x), 7) for x in c2w_all[cam].reshape(-1)],
                        "intrinsics": [round(float(x), 5) for x in k.reshape(-1)],
                    },
                    "width": cfg.size,
                    "height": cfg.size,
                })
    meta = {
        "identity": index,
        "split": cfg.split,
        "params": dataclasses.asdict(head.identity),
        "appearance": dataclasses.asdict(head.look),
        "hair_style": head.hair_style,
        "hair_colour": head.hair_colour,
        "records": records,
    }
    (folder / "meta.json").write_text(dumps(meta, indent=1))
    return records


def write_corpus(cfg: CorpusConfig, outdir: str | os.PathLike[str],
                 progress: Callable[[Iterable[int], int], Iterable[int]] | None = None
                 ) -> dict:
    """Write (or resume writing) a corpus.

    Args:
        cfg: What to write.
        outdir: The corpus folder (created if missing).
        progress: Wraps the identity loop (e.g. a progress bar): ``progress(it, total)``.

    Returns:
        A summary: identities written and skipped, ``views`` (records in the whole index),
        ``views_written`` (records written by this call), seconds, paths.

    Raises:
        FileFormatError: ``outdir`` holds a corpus written with another configuration.
    """
    import time

    from head360cli.io.atomic import atomic_path, commit_dir, temp_dir_beside

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    config_path = out / "corpus.json"
    # Settings every identity of the folder must share (counts and split may differ).
    new_cfg = {k: v for k, v in dataclasses.asdict(cfg).items()
               if k not in ("identities", "start", "split")}
    if config_path.exists():
        try:
            old_cfg = json.loads(config_path.read_text()).get("config", {})
        except json.JSONDecodeError as exc:
            raise FileFormatError(f"{config_path}: not valid JSON ({exc.msg})") from exc
        if old_cfg != new_cfg:
            raise FileFormatError(
                f"{out} holds a corpus written with {old_cfg}; expected {new_cfg}: "
                "use another folder"
            )
    with atomic_path(config_path) as tmp:
        tmp.write_text(json.dumps({"format": CORPUS_FORMAT, "config": new_cfg}, indent=1))

    t0 = time.perf_counter()
    written = skipped = images_written = 0
    indices = range(cfg.start, cfg.start + cfg.identities)
    loop = progress(indices, len(indices)) if progress else indices
    for index in loop:
        rel = f"{cfg.split}/id{index:04d}"
        folder = out / rel
        if (folder / "meta.json").is_file():
            skipped += 1
            continue
        folder.parent.mkdir(parents=True, exist_ok=True)
        if folder.exists():  # a folder without meta.json is an unfinished leftover
            shutil.rmtree(folder)
        tmp = temp_dir_beside(folder)
        try:
            images_written += len(_write_identity(cfg, index, tmp, rel))
            commit_dir(tmp, folder)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
        written += 1
    seconds = time.perf_counter() - t0
    images = _rebuild_index(out)
    return {"outdir": str(out), "identities_written": written, "identities_skipped": skipped,
            "views": images, "views_written": images_written, "seconds": round(seconds, 2),
            "index": str(out / "index.jsonl")}


def _rebuild_index(out: Path) -> int:
    """Concatenate every finished identity's records into ``index.jsonl`` (atomically)."""
    from head360cli.io.atomic import atomic_path

    count = 0
    with atomic_path(out / "index.jsonl") as tmp, open(tmp, "w") as f:
        for meta_path in sorted(out.glob("*/id*/meta.json")):
            for record in json.loads(meta_path.read_text())["records"]:
                f.write(dumps(record, sort_keys=True) + "\n")
                count += 1
    return count


# --------------------------------------------------------------------------- previews


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    img = np.ascontiguousarray(img)
    cv2.putText(img, text, (4, img.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (0, 0, 0), 2,
                cv2.LINE_AA)
    cv2.putText(img, text, (4, img.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.36,
                (255, 255, 255), 1, cv2.LINE_AA)
    return img


def _grid(tiles: list[np.ndarray], cols: int) -> np.ndarray:
    h, w = tiles[0].shape[:2]
    rows = (len(tiles) + cols - 1) // cols
    sheet = np.full((rows * h, cols * w, 3), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, cols)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile[..., :3]
    return sheet


def write_previews(outdir: str | os.PathLike[str], seed: int = 0, size: int = 160,
                   identities: int = 8, split: str = "train", skin_scan: str = "",
                   soft_hair: bool = False) -> list[str]:
    """Contact sheets: identities x views; all 52 expressions of one identity; all 30
    hairstyles on one identity. The three are written as one set once all are rendered
    (an interrupted run leaves an earlier run's sheets as they were). Returns the PNG
    paths written."""
    import torch

    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
    )
    from head360cli.io.atomic import atomic_paths
    from head360cli.mesh.arkit52 import ARKIT52
    from head360cli.synth.hair import HAIR_COLOURS, HAIRSTYLES, build_hair, hair_texture
    from head360cli.synth.scene import make_head, render_head

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    k = intrinsics_from_fov(RIG_FOV_DEG, size, size)
    sheets: dict[str, np.ndarray] = {}

    def save(sheet: np.ndarray, name: str) -> None:
        sheets[name] = sheet

    # Identities x views.
    yaws = [0.0, 45.0, 90.0, 135.0, 180.0, 270.0]
    pitches = [0.0, 0.0, 0.0, 20.0, 0.0, -20.0]
    c2w = camera_on_sphere(torch.tensor(yaws), torch.tensor(pitches), RIG_DISTANCE)
    tiles = []
    heads = [make_head(i, split, seed, skin_scan=skin_scan or None, soft_hair=soft_hair)
             for i in range(identities)]
    for head in heads:
        r = render_head(head, np.zeros(52), c2w, k, size, samples=4)
        tiles += [_to_u8(img.permute(1, 2, 0)) for img in r.rgb]
    save(_grid(tiles, len(yaws)), "preview_identities.png")

    # All expressions of one identity, close up from the front.
    head = heads[0]
    close = intrinsics_from_fov(RIG_FOV_DEG * 0.55, size, size)
    front = camera_on_sphere(torch.tensor([0.0]), torch.tensor([0.0]), RIG_DISTANCE,
                             target=(0.0, -0.03, 0.0))
    tiles = []
    for name in ("neutral", *ARKIT52):
        w = np.zeros(52)
        if name != "neutral":
            w[ARKIT52.index(name)] = 1.0
        r = render_head(head, w, front, close, size, samples=4, with_hair=False)
        tiles.append(_label(_to_u8(r.rgb[0].permute(1, 2, 0)), name))
    save(_grid(tiles, 9), "preview_expressions.png")

    # All hairstyles on one identity, in a rotating palette of colours.
    three_q = camera_on_sphere(torch.tensor([35.0]), torch.tensor([10.0]), RIG_DISTANCE)
    colours = list(HAIR_COLOURS)
    tiles = []
    for sid, style in enumerate(HAIRSTYLES):
        head.hair_style, head.hair_colour = sid, colours[sid % len(colours)]
        head.hair = build_hair(head.verts, head.frame, sid, soft=soft_hair)
        head.hair_tex = hair_texture(HAIR_COLOURS[head.hair_colour], 256, sid)
        head.__dict__.pop("_render_cache", None)  # the hair changed
        r = render_head(head, np.zeros(52), three_q, k, size, samples=4)
        tiles.append(_label(_to_u8(r.rgb[0].permute(1, 2, 0)), f"{sid} {style.name}"))
    save(_grid(tiles, 10), "preview_hairstyles.png")
    paths = [out / name for name in sheets]
    with atomic_paths(*paths) as tmps:
        for tmp, sheet in zip(tmps, sheets.values(), strict=True):
            _png(sheet, tmp)
    return [str(p) for p in paths]
