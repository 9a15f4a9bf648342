"""Mesh corpora the bilinear model can be built from: identities as (neutral, 52 deltas).

- ``synthead-p``: the project's own procedural heads (:mod:`head360cli.synth`), any count,
  with procedural or scanned expressions, sculpted or scanned identities.
- ``ict``: ICT-FaceKit's light npz (neutral, 100 identity deltas, 53 ARKit-style expression
  deltas with ``browInnerUp``/``cheekPuff`` split into halves and no ``tongueOut``). Its
  expressions do not depend on the identity, as in that linear model. ICT-FaceKit is in
  centimetres; the reader converts to metres.
- ``synthead100``: SynHead100's layout, one mesh per identity per ARKit expression:
  ``ROOT/<identity>/neutral.obj`` and ``ROOT/<identity>/<arkitName>.obj`` (any spelling
  that :func:`~head360cli.mesh.arkit52.canonical_name` maps; ``.obj``/``.ply``).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError, FileFormatError
from head360cli.mesh.arkit52 import ARKIT52, INDEX, canonical_name

__all__ = ["ict_facekit", "read_ict", "synthead100", "synthead_p"]


def synthead_p(count: int = 100, seed: int = 0, split: str = "train",
               expressions: str = "procedural", identity_space: str = "sculpted"
               ) -> tuple[Iterator[tuple[np.ndarray, np.ndarray]], dict]:
    """SynHead-P identities (geometry only, blendshapes of the kind ``expressions``) and
    the template's topology. ``identity_space``: ``sculpted`` (the procedural sculpt) or
    ``scanned`` (ICT-FaceKit's shape space, :mod:`head360cli.synth.scanned`)."""
    from head360cli.mesh.template import REGION_NAMES, template
    from head360cli.synth.expressions import blendshape_deltas
    from head360cli.synth.identity import sample_identity
    from head360cli.synth.scanned import scanned_identity
    from head360cli.synth.scene import head_seed
    from head360cli.synth.sculpt import build_head

    def gen():
        for i in range(count):
            s = head_seed(seed, split, i)
            rng = np.random.default_rng([s, 0x5EED])
            age = 16.0 + (((i * 7) % 10) + rng.uniform()) * 5.4  # as in make_head
            params = sample_identity(s, sex=float(i % 2), age=age)
            if identity_space == "scanned":
                yield scanned_identity(params, s, expressions)
                continue
            verts, frame = build_head(params)
            yield verts, blendshape_deltas(verts, frame, expressions)

    t = template()
    topo = {"faces": t.faces, "uv": t.uv, "faces_uv": t.faces_uv, "region": t.region,
            "landmarks": t.landmarks, "vertex_mirror": t.mirror,
            "region_names": list(REGION_NAMES)}
    return gen(), topo


def read_ict(path: str | Path) -> dict[str, Any]:
    """ICT-FaceKit's light npz (or its folder) in metres: ``neutral (V, 3)``, ``deltas
    (52, V, 3)`` in ARKit order (halves summed, ``tongueOut`` zero), ``identity_deltas
    (100, V, 3)``, ``landmarks (68,)``, ``faces (F, 3)`` and the file's ``sha256``."""
    import hashlib

    path = Path(path)
    if path.is_dir():
        path = path / "derived" / "ict_facekit_light_f16.npz"
    if not path.is_file():
        raise BadInputError(f"expected ICT-FaceKit's ict_facekit_light_f16.npz at "
                            f"{str(path)!r}, found nothing")
    try:
        data = np.load(path, allow_pickle=False)
        arrays = {k: data[k] for k in ("neutral", "expression_names", "expression_deltas",
                                       "identity_deltas", "landmarks68", "tris", "quads")}
    except (KeyError, ValueError, OSError) as exc:
        raise FileFormatError(f"{path}: not ICT-FaceKit's light npz ({exc})") from None
    cm = 0.01  # ICT-FaceKit's unit is the centimetre
    neutral = arrays["neutral"].astype(np.float64) * cm
    deltas = np.zeros((52, *neutral.shape))
    for name, delta in zip(arrays["expression_names"], arrays["expression_deltas"],
                           strict=True):
        canon = canonical_name(str(name))
        if canon is None:
            continue
        # a half moves half the face: the whole is their sum
        deltas[INDEX[canon]] += delta.astype(np.float64) * cm
    faces = np.concatenate([arrays["tris"], arrays["quads"][:, [0, 1, 2]],
                            arrays["quads"][:, [0, 2, 3]]]).astype(np.int64)
    return {"neutral": neutral, "deltas": deltas,
            "identity_deltas": arrays["identity_deltas"].astype(np.float64) * cm,
            "landmarks": arrays["landmarks68"].astype(np.int64), "faces": faces,
            "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


def ict_facekit(path: str | Path) -> tuple[Iterator[tuple[np.ndarray, np.ndarray]], dict]:
    """ICT-FaceKit identities from ``ict_facekit_light_f16.npz`` (or its folder)."""
    ict = read_ict(path)
    neutral, deltas = ict["neutral"], ict["deltas"]

    def gen():
        for d in ict["identity_deltas"]:
            yield neutral + d, deltas

    return gen(), {"faces": ict["faces"], "landmarks": ict["landmarks"],
                   "vertex_mirror": _mirror_by_position(neutral)}


def _mirror_by_position(verts: np.ndarray) -> np.ndarray:
    """Mirror vertex of each vertex: the nearest vertex to its reflection in x = 0."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(verts).query(verts * np.array([-1.0, 1.0, 1.0]))
    return idx.astype(np.int64)


def synthead100(root: str | Path) -> tuple[Iterator[tuple[np.ndarray, np.ndarray]], dict]:
    """Identities from a SynHead100-style folder (one mesh per identity and expression)."""
    import trimesh

    root = Path(root)
    folders = sorted(p for p in root.iterdir() if p.is_dir()) if root.is_dir() else []
    if not folders:
        raise BadInputError(f"expected identity folders in {str(root)!r}, found none")

    def load(path: Path) -> trimesh.Trimesh:
        try:
            return trimesh.load(path, process=False, force="mesh")
        except Exception as exc:
            raise FileFormatError(f"cannot read mesh {path}: {exc}") from exc

    def find(folder: Path) -> tuple[Path, dict[str, Path]]:
        files = [p for p in folder.iterdir() if p.suffix.lower() in (".obj", ".ply")]
        neutral = [p for p in files if p.stem.lower() in ("neutral", "_neutral", "basis")]
        if not neutral:
            raise BadInputError(f"{folder}: expected a neutral.obj, found none")
        shapes = {canonical_name(p.stem): p for p in files if canonical_name(p.stem)}
        missing = [n for n in ARKIT52 if n not in shapes]
        if missing:
            raise BadInputError(f"{folder}: missing expressions {', '.join(missing[:5])}")
        return neutral[0], shapes

    first = load(find(folders[0])[0])

    def gen():
        for folder in folders:
            neutral_path, shapes = find(folder)
            neutral = np.asarray(load(neutral_path).vertices, dtype=np.float64)
            if neutral.shape != first.vertices.shape:
                raise FileFormatError(f"{folder}: expected {len(first.vertices)} vertices "
                                      f"like the first identity, found {len(neutral)}")
            deltas = np.stack([np.asarray(load(shapes[n]).vertices) - neutral
                               for n in ARKIT52])
            yield neutral, deltas

    verts = np.asarray(first.vertices, dtype=np.float64)
    return gen(), {"faces": np.asarray(first.faces, dtype=np.int64),
                   "landmarks": np.zeros(68, dtype=np.int64),
                   "vertex_mirror": _mirror_by_position(verts)}
