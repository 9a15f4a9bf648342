"""The parametric head: a bilinear model ``V = C x_id s x_exp [1, w]``.

Built from a corpus of identities, each given as a neutral mesh and its 52 ARKit
blendshape deltas. Per identity the 53 meshes ``[neutral, delta_1 .. delta_52]`` are
stacked into one vector; the identity mode is reduced by HOSVD (an SVD of that mode's
unfolding, here through the identities' Gram matrix) from ``N`` identities to ``K`` codes
(the paper: 100 -> 50). The expression mode is kept whole, so ``w`` stays ARKit weights::

    vertices(s, w) = (M_0 + s . B_0) + sum_e w_e (M_e + s . B_e)

linear in ``s`` for fixed ``w`` and in ``w`` for fixed ``s``. Blendshape blocks are stored
sparsely (each moves only its own region). Means are float32; bases float16, whose error is
checked against 0.1 mm when the model is built.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import FileFormatError, ModelNotFoundError
from head360cli.mesh.arkit52 import MIRROR_INDEX, NUM_BLENDSHAPES

__all__ = ["BilinearHead", "BilinearModel", "build_bilinear", "load_bilinear",
           "read_model_file"]

MODEL_FORMAT = 1
MOVE_THRESHOLD = 1e-6
"""A blendshape moves a vertex if any identity displaces it by more than this (metres)."""


@dataclasses.dataclass
class BilinearModel:
    """The model's arrays (numpy), as stored in ``bilinear.npz``.

    Attributes:
        neutral_mean: ``(V, 3)`` float32 mean neutral mesh.
        neutral_basis: ``(K, V, 3)`` identity basis of the neutral mesh (float16 on disk).
        expr_vertex: ``(N,)`` vertex id of each stored blendshape entry.
        expr_shape: ``(N,)`` ARKit index (0..51) of each entry.
        expr_mean: ``(N, 3)`` float32 mean delta.
        expr_basis: ``(K, N, 3)`` identity basis of the deltas.
        code_mean: ``(K,)`` mean identity code of the training identities (about 0).
        code_cov: ``(K, K)`` covariance of the codes: the prior for fitting.
        mirror_matrix: ``(K, K)``; with ``mirror_offset`` ``(K,)`` maps a code to the code
            of the mirror-image identity: ``s' = s @ mirror_matrix.T + mirror_offset``.
        mirror_offset: ``(K,)``.
        vertex_mirror: ``(V,)`` mirror vertex of each vertex.
        faces: ``(F, 3)``; ``uv`` ``(T, 2)`` and ``faces_uv`` ``(F, 3)`` when known.
        uv: ``(T, 2)``.
        faces_uv: ``(F, 3)``.
        region: ``(V,)`` region index per vertex (see ``meta["regions"]``).
        landmarks: ``(68,)`` landmark vertex ids (the nearest vertex of each landmark).
        meta: format, source corpus, rank, identities, errors measured at build time.
        landmark_tri: ``(68, 3)`` the three vertices each landmark lies between, with
            ``landmark_bary`` ``(68, 3)`` its barycentric weights: landmarks are points on
            the surface, not only vertices. Absent in older files: then the landmark
            vertices themselves.
        landmark_bary: ``(68, 3)``.
    """

    neutral_mean: np.ndarray
    neutral_basis: np.ndarray
    expr_vertex: np.ndarray
    expr_shape: np.ndarray
    expr_mean: np.ndarray
    expr_basis: np.ndarray
    code_mean: np.ndarray
    code_cov: np.ndarray
    mirror_matrix: np.ndarray
    mirror_offset: np.ndarray
    vertex_mirror: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    faces_uv: np.ndarray
    region: np.ndarray
    landmarks: np.ndarray
    meta: dict[str, Any]
    landmark_tri: np.ndarray | None = None
    landmark_bary: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.landmark_tri is None or self.landmark_bary is None:
            self.landmark_tri = np.repeat(np.asarray(self.landmarks, np.int64)[:, None], 3, 1)
            self.landmark_bary = np.tile(np.array([1.0, 0.0, 0.0], np.float32),
                                         (len(self.landmarks), 1))

    def with_landmarks(self, landmarks: np.ndarray, tri: np.ndarray | None = None,
                       bary: np.ndarray | None = None) -> BilinearModel:
        """A copy with other landmarks: vertex ids ``(68,)`` and, optionally, their surface
        embedding ``tri``/``bary`` ``(68, 3)`` (default: the vertices themselves)."""
        return dataclasses.replace(self, landmarks=np.asarray(landmarks, np.int64),
                                   landmark_tri=tri, landmark_bary=bary)

    def landmark_points(self, vertices: np.ndarray) -> np.ndarray:
        """``(68, 3)`` landmark positions on a mesh ``(V, 3)`` of this topology."""
        return np.einsum("lj,ljc->lc", self.landmark_bary.astype(vertices.dtype),
                         vertices[self.landmark_tri])

    @property
    def rank(self) -> int:
        return int(self.neutral_basis.shape[0])

    @property
    def num_vertices(self) -> int:
        return int(self.neutral_mean.shape[0])

    def vertices(self, s: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``(V, 3)`` float64 mesh for one code ``s (K,)`` and weights ``w (52,)``."""
        s = np.asarray(s, dtype=np.float64)
        out = self.neutral_mean + (s @ self._widened()["nb"]).reshape(-1, 3)
        d = self.entry_moves(s) * np.asarray(w, dtype=np.float64)[self.expr_shape][:, None]
        for c in range(3):  # bincount scatters far faster than np.add.at
            out[:, c] += np.bincount(self.expr_vertex, d[:, c], minlength=len(out))
        return out

    def entry_moves(self, s: np.ndarray) -> np.ndarray:
        """``(E, 3)`` float64: how far each stored blendshape entry (shape
        ``expr_shape[e]``, vertex ``expr_vertex[e]``) moves its vertex at weight 1, for
        code ``s (K,)``."""
        return self.expr_mean + (np.asarray(s, np.float64) @ self._widened()["eb"]
                                 ).reshape(-1, 3)

    def _widened(self) -> dict[str, np.ndarray]:
        """Float64 copies of the (float16) bases, ``nb (K, V*3)`` and ``eb (K, E*3)``,
        made once (and shared by the models loaded from one file, :func:`load_bilinear`)."""
        cache = self.__dict__.setdefault("_f64", {})
        if not cache:
            cache["nb"] = _widen(self.neutral_basis).reshape(self.rank, -1)
            cache["eb"] = _widen(self.expr_basis).reshape(self.rank, -1)
        return cache

    def deltas(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The neutral mesh ``(V, 3)`` of code ``s (K,)`` and how each of the 52 ARKit
        shapes at weight 1 moves it, ``(52, V, 3)`` float64: ``vertices(s, e_k) -
        vertices(s, 0)``, the same values, in one pass instead of 53 (0.14-0.19 s -> about
        0.01 s on 2 cores once the bases are widened)."""
        neutral = self.vertices(s, np.zeros(52))
        d = self.entry_moves(s)
        out = np.zeros((52, *neutral.shape))
        base = neutral[self.expr_vertex]
        # each (shape, vertex) is stored once, so vertices(s, e_k) adds only its own entry
        out[self.expr_shape, self.expr_vertex] = (base + d) - base
        return neutral, out

    def save(self, path: str | os.PathLike[str]) -> str:
        """Write ``bilinear.npz`` atomically; returns the model's content hash."""
        from head360cli.io.atomic import atomic_path

        arrays = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                  if f.name != "meta"}
        arrays["neutral_basis"] = arrays["neutral_basis"].astype(np.float16)
        arrays["expr_basis"] = arrays["expr_basis"].astype(np.float16)
        meta = {k: v for k, v in self.meta.items() if k != "sha256"}
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, __meta__=np.array(json.dumps(meta, sort_keys=True)),
                                **arrays)
        return content_hash(arrays, meta)


def _widen(a: np.ndarray) -> np.ndarray:
    """``a`` as float64, the same values as ``a.astype(np.float64)``. A float16 array goes
    through torch: numpy widens float16 one value at a time (the model's expression basis,
    5.6 M values, took 0.50 s against torch's 0.02 on 2 cores)."""
    if a.dtype != np.float16:
        return a.astype(np.float64)
    import warnings

    import torch

    with warnings.catch_warnings():  # read-only arrays (a cached model's) are only read
        warnings.simplefilter("ignore", UserWarning)
        source = torch.from_numpy(np.ascontiguousarray(a))
    return source.to(torch.float64).numpy()


def content_hash(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> str:
    """SHA-256 of a model's arrays (names, dtypes, shapes, bytes) and metadata.

    Unlike the file's bytes (zip entries carry timestamps), it is the same whenever the
    same model is rebuilt; head files record it as the model they were made with.
    """
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}".encode())
        h.update(a.tobytes())
    h.update(json.dumps({k: v for k, v in meta.items() if k != "sha256"},
                        sort_keys=True).encode())
    return h.hexdigest()


_LOADED: dict[tuple[str, int, int, int], tuple[dict[str, np.ndarray], dict[str, Any], dict]] = {}
"""The latest model file read, by (resolved path, inode, modification time in ns, size): its
arrays (the :data:`_SHARED` ones read-only), metadata and float64 cache. A fit loads the
model in four places (0.22 s each on 2 cores)."""


_SHARED = ("neutral_basis", "expr_basis")
"""The large arrays every model loaded from one file shares, read-only (torch warns when
it wraps a read-only array, so the small ones, which ``torch.as_tensor`` takes in many
places, are each load's own copies)."""


def load_bilinear(path: str | os.PathLike[str] | None = None) -> BilinearModel:
    """Load a bilinear model (default: ``bilinear.npz`` in the models folder).

    The file is read once while it is unchanged: every model loaded from it shares its two
    bases, read-only (:data:`_SHARED`), and their float64 copies; its other arrays and its
    ``meta`` are each load's own.

    Raises:
        ModelNotFoundError: The file does not exist.
        FileFormatError: It is not a head360 bilinear model of a known version.
    """
    if path is None:
        from head360cli.paths import models_dir

        path = models_dir() / "bilinear.npz"
    path = Path(path)
    if not path.is_file():
        raise ModelNotFoundError(
            f"bilinear model not found at {str(path)!r}; build it with 'head360 build-model'")
    stat = path.stat()
    key = (str(path.resolve()), stat.st_ino, stat.st_mtime_ns, stat.st_size)
    if key not in _LOADED:
        arrays, meta = read_model_file(path)
        for name in _SHARED:
            arrays[name].flags.writeable = False
        _LOADED.clear()
        _LOADED[key] = (arrays, meta, {})
    arrays, meta, widened = _LOADED[key]
    model = BilinearModel(**{k: v if k in _SHARED else v.copy() for k, v in arrays.items()},
                          meta=json.loads(json.dumps(meta)))
    model.__dict__["_f64"] = widened  # filled by the first ``_widened()`` of any of them
    return model


def read_model_file(path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays and metadata (with its ``sha256``) of a model file (a path or a binary
    file object), checked, without the caching of :func:`load_bilinear`.

    Raises:
        FileFormatError: Not a readable head360 bilinear model.
    """
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except Exception as exc:  # zip, zlib, pickle and value errors alike
        raise FileFormatError(f"{path}: not a readable model file ({exc})") from exc
    try:
        meta = json.loads(str(data.pop("__meta__")))
        # checked in words, not by assert: ``python -O`` drops asserts, and with them
        # the refusal of another program's or a newer version's file
        kind, version = meta.get("format"), int(meta.get("format_version", 0))
        if kind != "head360-bilinear" or version > MODEL_FORMAT:
            raise ValueError(f"format {kind!r} version {version}; head360 reads "
                             f"'head360-bilinear' up to version {MODEL_FORMAT}")
        fields = {f.name for f in dataclasses.fields(BilinearModel)} - {"meta"}
        optional = {"landmark_tri", "landmark_bary"}  # added after format version 1
        missing = sorted(fields - optional - set(data))
        if missing:
            raise KeyError(", ".join(missing))
    except (KeyError, ValueError, TypeError) as exc:
        raise FileFormatError(f"{path}: expected a head360 bilinear model ({exc!r})") from exc
    meta["sha256"] = content_hash(
        {k: v for k, v in data.items()}, {k: v for k, v in meta.items() if k != "sha256"})
    return {k: v for k, v in data.items() if k in fields}, meta


def build_bilinear(identities: Iterable[tuple[np.ndarray, np.ndarray]], rank: int,
                   topology: dict[str, np.ndarray], meta: dict[str, Any] | None = None
                   ) -> BilinearModel:
    """Build the model from identities by HOSVD on the identity mode.

    Args:
        identities: ``(neutral (V, 3), deltas (52, V, 3))`` per identity.
        rank: Identity codes kept (``K``); at most the number of identities minus one.
        topology: ``faces``, ``landmarks``, ``vertex_mirror`` and optionally ``uv``,
            ``faces_uv``, ``region``.
        meta: Extra metadata to store (source corpus, command...).

    Returns:
        The model.
    """
    rows = []
    for neutral, deltas in identities:
        rows.append(np.concatenate([neutral[None], deltas]).astype(np.float32).reshape(-1))
    x = np.stack(rows)  # (N, 53 * V * 3)
    n = x.shape[0]
    if not 1 <= rank <= n - 1:
        raise ValueError(f"expected rank in 1..{n - 1}, found {rank}")
    v = x.shape[1] // (3 * (NUM_BLENDSHAPES + 1))
    mean = x.mean(0, dtype=np.float64)
    xc = (x - mean).astype(np.float64)
    gram = xc @ xc.T  # (N, N): the identity mode's unfolding, through its Gram matrix
    eigval, eigvec = np.linalg.eigh(gram)
    order = np.argsort(eigval)[::-1][:rank]
    sigma = np.sqrt(np.clip(eigval[order], 1e-30, None))
    basis = (eigvec[:, order].T @ xc) / sigma[:, None]  # (K, D), orthonormal rows
    codes = xc @ basis.T  # (N, K)
    basis_t = basis.reshape(rank, NUM_BLENDSHAPES + 1, v, 3)
    mean_t = mean.reshape(NUM_BLENDSHAPES + 1, v, 3)

    # Sparse blendshape blocks: vertices that any identity's delta moves.
    deltas_all = x.reshape(n, NUM_BLENDSHAPES + 1, v, 3)[:, 1:]
    moving = np.abs(deltas_all).max(axis=(0, 3)) > MOVE_THRESHOLD  # (52, V)
    e_idx, v_idx = np.nonzero(moving)
    expr_mean = mean_t[1:][e_idx, v_idx]
    expr_basis = basis_t[:, 1:][:, e_idx, v_idx]

    # Mirror: reflect the stacked meshes (x -> -x, vertices and left/right shapes swapped)
    # and express the reflection in code space.
    vm = topology["vertex_mirror"]
    flip = np.array([-1.0, 1.0, 1.0])

    def reflect(t: np.ndarray) -> np.ndarray:  # (..., 53, V, 3)
        order_e = np.concatenate([[0], 1 + np.asarray(MIRROR_INDEX)])
        return t[..., order_e, :, :][..., :, vm, :] * flip

    mirror_matrix = basis @ reflect(basis_t).reshape(rank, -1).T  # (K, K): B P B^T
    mirror_offset = basis @ (reflect(mean_t).reshape(-1) - mean)
    model = BilinearModel(
        neutral_mean=mean_t[0].astype(np.float32),
        neutral_basis=basis_t[:, 0].astype(np.float32),
        expr_vertex=v_idx.astype(np.int32),
        expr_shape=e_idx.astype(np.int16),
        expr_mean=expr_mean.astype(np.float32),
        expr_basis=expr_basis.astype(np.float32),
        code_mean=codes.mean(0),
        code_cov=np.cov(codes, rowvar=False),
        mirror_matrix=mirror_matrix,
        mirror_offset=mirror_offset,
        vertex_mirror=np.asarray(vm, dtype=np.int64),
        faces=np.asarray(topology["faces"], dtype=np.int64),
        uv=np.asarray(topology.get("uv", np.zeros((0, 2))), dtype=np.float32),
        faces_uv=np.asarray(topology.get("faces_uv", np.zeros((0, 3))), dtype=np.int64),
        region=np.asarray(topology.get("region", np.zeros(v)), dtype=np.int64),
        landmarks=np.asarray(topology["landmarks"], dtype=np.int64),
        meta={"format": "head360-bilinear", "format_version": MODEL_FORMAT,
              "identities": n, "rank": rank, "vertices": v, **(meta or {})},
    )
    return model


class BilinearHead:
    """Differentiable, batched evaluation of a :class:`BilinearModel` in torch.

    Args:
        model: The model.
        device: Torch device for its tensors.
        dtype: Floating dtype.
    """

    def __init__(self, model: BilinearModel, device: Any = "cpu", dtype: Any = None) -> None:
        import torch

        dtype = dtype or torch.float32
        t = lambda a: torch.as_tensor(_widen(np.asarray(a)), dtype=dtype,  # noqa: E731
                                      device=device)
        self.model = model
        self.neutral_mean = t(model.neutral_mean)
        self.neutral_basis = t(model.neutral_basis)
        self.expr_mean = t(model.expr_mean)
        self.expr_basis = t(model.expr_basis)
        self.expr_vertex = torch.as_tensor(model.expr_vertex, dtype=torch.long, device=device)
        self.expr_shape = torch.as_tensor(model.expr_shape, dtype=torch.long, device=device)
        self.mirror_matrix = t(model.mirror_matrix)
        self.mirror_offset = t(model.mirror_offset)
        self.code_cov = t(model.code_cov)
        self.landmark_tri = torch.as_tensor(model.landmark_tri, dtype=torch.long, device=device)
        self.landmark_bary = t(model.landmark_bary)
        self.vertex_mirror = torch.as_tensor(model.vertex_mirror, dtype=torch.long,
                                             device=device)

    @property
    def rank(self) -> int:
        return self.model.rank

    def vertices(self, s, w):
        """``(B, V, 3)`` vertices for codes ``s (B, K)`` and ARKit weights ``w (B, 52)``."""
        import torch

        base = self.neutral_mean + torch.einsum("bk,kvc->bvc", s, self.neutral_basis)
        d = self.expr_mean + torch.einsum("bk,knc->bnc", s, self.expr_basis)
        d = d * w[:, self.expr_shape, None]
        return base.index_add(1, self.expr_vertex, d)

    def landmarks(self, s, w):
        """``(B, 68, 3)`` landmark positions (points on the surface)."""
        v = self.vertices(s, w)[:, self.landmark_tri]  # (B, 68, 3, 3)
        return (v * self.landmark_bary[None, :, :, None]).sum(2)

    def mirror(self, s, w):
        """Codes and weights of the mirror-image head (x -> -x)."""
        return s @ self.mirror_matrix.T + self.mirror_offset, w[:, list(MIRROR_INDEX)]
