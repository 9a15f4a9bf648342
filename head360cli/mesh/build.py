"""``head360 build-model``: build the bilinear model from a corpus and measure it."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from head360cli.errors import BadInputError
from head360cli.mesh.bilinear import BilinearModel, build_bilinear

__all__ = ["build_model", "reconstruction_error"]


def reconstruction_error(model: BilinearModel, identities) -> dict[str, float]:
    """Project identities onto the model (least squares on their codes, which is exact
    projection for the orthonormal basis) and compare all 53 meshes (neutral and each
    shape at weight 1) vertex by vertex.

    Returns:
        ``mean_mm``, ``p99_mm`` and ``max_mm`` of the per-vertex error.
    """
    k = model.rank
    nb = model.neutral_basis.astype(np.float64).reshape(k, -1)
    eb = model.expr_basis.astype(np.float64).reshape(k, -1)
    basis = np.concatenate([nb, eb], 1)
    errs = []
    for neutral, deltas in identities:
        d = deltas[model.expr_shape, model.expr_vertex]
        x = np.concatenate([(neutral - model.neutral_mean).reshape(-1),
                            (d - model.expr_mean).reshape(-1)])
        s = basis @ x
        # the 53 meshes at once, each as model.vertices(s, w) makes it for a one-hot w
        # (each (shape, vertex) entry is stored once: the neutral mesh plus that entry)
        base = model.vertices(s, np.zeros(52))
        moved = np.zeros((52, *base.shape))
        moved[model.expr_shape, model.expr_vertex] = model.entry_moves(s)
        errs.append(np.linalg.norm(base - neutral, axis=1))
        errs.append(np.linalg.norm((base + moved) - (neutral + deltas), axis=2).reshape(-1))
    e = np.concatenate(errs) * 1000.0
    return {"mean_mm": round(float(e.mean()), 4), "p99_mm": round(float(np.percentile(e, 99)), 3),
            "max_mm": round(float(e.max()), 3)}


def build_model(corpus: str = "synthead-p", path: str | None = None, identities: int = 100,
                rank: int = 50, seed: int = 0, out: str | Path = "models/bilinear.npz",
                held_out: int = 20, calibrate: str | Path | None = None,
                expressions: str = "procedural", identity_space: str = "sculpted"
                ) -> dict[str, Any]:
    """Build, save and measure a bilinear model.

    Args:
        corpus: ``synthead-p``, ``ict`` or ``synthead100``.
        path: Folder or file of an external corpus.
        identities: Training identities (SynHead-P) or at most this many (external).
        rank: Identity codes kept.
        seed: SynHead-P seed.
        out: Output ``.npz``.
        held_out: Identities measured but not used for building (SynHead-P: the test
            split; external corpora: the last ones).
        calibrate: A folder of dlib landmark XML files: learn where the landmarks sit on
            the template from those faces (see :mod:`head360cli.fitting.calibrate`).
        expressions: SynHead-P's blendshapes, ``procedural`` or ``scanned``
            (:mod:`head360cli.synth.expressions`).
        identity_space: SynHead-P's identities, ``sculpted`` or ``scanned``
            (:mod:`head360cli.synth.scanned`).

    Returns:
        Summary with the model hash, size and reconstruction errors.
    """
    from head360cli.io.atomic import check_folder_name
    from head360cli.mesh import corpora

    if Path(out).suffix.lower() != ".npz":
        raise BadInputError(f"expected a model output ending in .npz, found {str(out)!r}")
    check_folder_name(Path(out).parent)  # made if missing, but writable: before the work
    if identities < 2 or held_out < 0:
        raise BadInputError(f"expected --identities >= 2 and --held-out >= 0, found "
                            f"{identities} and {held_out}")
    t0 = time.perf_counter()
    from head360cli.synth.expressions import EXPRESSION_KINDS

    if expressions not in EXPRESSION_KINDS:
        raise BadInputError(f"expected --expressions {' or '.join(EXPRESSION_KINDS)}, found "
                            f"{expressions!r}")
    from head360cli.synth.scanned import IDENTITY_SPACES

    if identity_space not in IDENTITY_SPACES:
        raise BadInputError(f"expected --identity-space {' or '.join(IDENTITY_SPACES)}, "
                            f"found {identity_space!r}")
    if (expressions, identity_space) != ("procedural", "sculpted") and corpus != "synthead-p":
        raise BadInputError(f"--expressions and --identity-space are for --corpus "
                            f"synthead-p; found --corpus {corpus}, whose meshes bring their own")
    if corpus == "synthead-p":
        train_it, topo = corpora.synthead_p(identities, seed, "train", expressions,
                                            identity_space)
        train = list(train_it)
        test = (list(corpora.synthead_p(held_out, seed, "test", expressions,
                                        identity_space)[0]) if held_out else [])
    elif corpus in ("ict", "synthead100"):
        if path is None:
            raise BadInputError(f"--corpus {corpus} needs --path")
        reader = corpora.ict_facekit if corpus == "ict" else corpora.synthead100
        all_it, topo = reader(path)
        everything = list(all_it)
        if len(everything) <= held_out + 1:
            raise BadInputError(f"expected more than {held_out + 1} identities in {path}, "
                                f"found {len(everything)}")
        train = everything[: min(identities, len(everything) - held_out)]
        test = everything[len(everything) - held_out:] if held_out else []
    else:
        raise BadInputError(f"expected --corpus synthead-p, ict or synthead100, found "
                            f"{corpus!r}")
    if not 1 <= rank < len(train):
        raise BadInputError(f"expected --rank in 1..{len(train) - 1}, found {rank}")
    meta = {"corpus": corpus, "seed": seed, "held_out": held_out,
            "command": f"head360 build-model --corpus {corpus} --identities {identities} "
                       f"--rank {rank} --seed {seed}"}
    if expressions != "procedural":
        meta["command"] += f" --expressions {expressions}"
    if identity_space != "sculpted":
        meta["command"] += f" --identity-space {identity_space}"
    if calibrate is not None:
        meta["command"] += f" --calibrate {calibrate}"
    model = build_bilinear(train, rank, topo, meta)
    if calibrate is not None:
        from head360cli.fitting.calibrate import calibrate_landmarks, read_dlib_landmarks

        files = sorted(Path(calibrate).glob("*.xml"))
        faces = [face for f in files for face in read_dlib_landmarks(f)]
        if not faces:
            raise BadInputError(f"expected dlib landmark XML files in {calibrate}, found none")
        model, stats = calibrate_landmarks(model, faces, rounds=3)
        model.meta["landmarks_calibrated_on"] = {
            "files": [f.name for f in files], "faces": len(faces),
            "fit_error_before": round(stats["round0_error"], 5),
            "fit_error_after_round2": round(stats["round2_error"], 5)}
    t_build = time.perf_counter() - t0
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sha = model.save(out)
    from head360cli.mesh.bilinear import load_bilinear

    stored = load_bilinear(out)  # measure what was written (float16 bases)
    summary = {
        "out": str(out), "sha256": sha, "bytes": out.stat().st_size, "corpus": corpus,
        "identities": len(train), "rank": rank, "vertices": model.num_vertices,
        "sparse_entries": len(model.expr_vertex), "seconds": round(t_build, 1),
        "train_error": reconstruction_error(stored, train),
    }
    if test:
        summary["held_out"] = len(test)
        summary["held_out_error"] = reconstruction_error(stored, test)
    return summary
