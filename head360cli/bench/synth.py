"""``head360 bench synth``: speed of the corpus renderer and of writing a corpus subset;
how human the corpus heads are: their face proportions against ICT-FaceKit's scanned
heads, and how far the fit's landmarks read their pose from the truth.

Targets: one 256x256 view in at most 50 ms on a 2-core CPU; pose read within 3 degrees.
"""

from __future__ import annotations

import tempfile
import time
from typing import Any

import numpy as np

__all__ = ["bench_synth", "face_ratios", "pose_on_renders", "proportions"]


def _render_timings(size: int, repeats: int) -> list[dict[str, Any]]:
    from head360cli.geometry.cameras import RIG_FOV_DEG, intrinsics_from_fov, rig72
    from head360cli.synth.scene import make_head, render_head

    head = make_head(3)
    c2w, _, _ = rig72()
    k = intrinsics_from_fov(RIG_FOV_DEG, size, size)
    w = np.zeros(52)
    rows = []
    for samples in (1, 2, 4):
        for batch in (1, 8):
            render_head(head, w, c2w[:batch], k, size, samples=samples)  # warm up
            t0 = time.perf_counter()
            n = 0
            for start in range(0, repeats, batch):
                render_head(head, w, c2w[start:start + batch], k, size, samples=samples)
                n += batch
            ms = 1000 * (time.perf_counter() - t0) / n
            rows.append({"size": size, "aa_samples": samples, "batch": batch,
                         "ms_per_view": round(ms, 1), "meets_50ms": ms <= 50.0})
    return rows


def bench_synth(identities: int = 100, size: int = 256, repeats: int = 24,
                out_dir: str | None = None, pose_heads: int = 8, skin_scan: str = "",
                detector: str = "auto") -> tuple[dict[str, Any], str]:
    """Measure render speed and the time to write ``identities`` identities
    (1 expression x 4 views each, with and without hair); the corpus's face proportions
    against ICT-FaceKit's (when the shared data has it); the pose the fit's landmarks
    read on ``pose_heads`` held-out heads (0: skipped), also with ``skin_scan``'s skin.

    Returns:
        ``(result, markdown)``.
    """
    from head360cli.bench.report import machine, markdown_table
    from head360cli.paths import shared_data_dir
    from head360cli.synth.corpus import CorpusConfig, write_corpus

    rows = _render_timings(size, repeats)
    cfg = CorpusConfig(identities=identities, expressions=1, views=4, size=size, seed=0)
    with tempfile.TemporaryDirectory(dir=out_dir) as tmp:
        t0 = time.perf_counter()
        summary = write_corpus(cfg, tmp)
        corpus_s = time.perf_counter() - t0
    subset = {"identities": identities, "expressions": 1, "views": 4, "size": size,
              "renders": 2 * summary["views"], "seconds": round(corpus_s, 1),
              "seconds_per_identity": round(corpus_s / identities, 3)}
    result = {"machine": machine(), "render": rows, "corpus_subset": subset}
    md = "### Corpus renderer (256x256 views)\n\n" + markdown_table(
        rows, ["size", "aa_samples", "batch", "ms_per_view", "meets_50ms"])
    md += ("\n\n### Corpus subset\n\n"
           f"{identities} identities x 1 expression x 4 views, with and without hair "
           f"({subset['renders']} renders, PNGs, masks, index): {subset['seconds']} s, "
           f"{subset['seconds_per_identity']} s per identity.")
    shared = shared_data_dir()
    ict = shared / "ict-facekit" if shared is not None else None
    result["proportions"] = proportions(40, str(ict) if ict and ict.is_dir() else None)
    md += ("\n\n### Face proportions (over the face's width)\n\n"
           + markdown_table(result["proportions"], ["heads", "count", *RATIO_NAMES]))
    if pose_heads:
        poses = [pose_on_renders(pose_heads, "", detector)]
        if skin_scan:
            poses.append(pose_on_renders(pose_heads, skin_scan, detector))
        result["pose"] = poses
        md += ("\n\n### Pose read from the landmarks of corpus renders (goal: within 3 "
               "degrees)\n\n" + markdown_table(
                   [{k: v for k, v in p.items() if k != "rows"} for p in poses],
                   ["skin", "detector", "heads", "views", "found", "yaw_abs_deg",
                    "pitch_abs_deg", "pitch_signed_deg"]))
    return result, md


RATIO_NAMES = ("eyes_to_chin", "nose_to_chin", "eyes_to_nose", "eye_corners")
"""Face proportions, each over the face's width (iBUG points 0 to 16): the eyes' centre
to the chin (8), the nose's base (33) to the chin, the eyes' centre to the nose's base,
and the outer eye corners (36 to 45)."""


def face_ratios(verts: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """The :data:`RATIO_NAMES` of a head, ``(4,)``, from its 68 landmark vertex ids."""
    p = verts[landmarks]
    eyes = p[36:48].mean(0)
    width = np.linalg.norm(p[0] - p[16])
    return np.array([np.linalg.norm(eyes - p[8]), np.linalg.norm(p[33] - p[8]),
                     np.linalg.norm(eyes - p[33]), np.linalg.norm(p[36] - p[45])]) / width


def proportions(identities: int = 40, ict_folder: str | None = None) -> list[dict[str, Any]]:
    """Mean face ratios of ``identities`` corpus heads and, when its folder is given, of
    ICT-FaceKit's 100 identities, and the corpus's excess over ICT's in percent."""
    from head360cli.mesh.corpora import ict_facekit, synthead_p

    sources = [("SynHead-P", synthead_p(identities))]
    if ict_folder:
        sources.append(("ICT-FaceKit", ict_facekit(ict_folder)))
    rows = []
    for name, (heads, topo) in sources:
        r = np.array([face_ratios(v, topo["landmarks"]) for v, _ in heads])
        rows.append({"heads": name, "count": len(r)}
                    | {k: round(float(m), 3) for k, m in zip(RATIO_NAMES, r.mean(0), strict=True)})
    if len(rows) == 2:
        rows.append({"heads": "SynHead-P over ICT-FaceKit (%)", "count": ""}
                    | {k: round(100 * (rows[0][k] / rows[1][k] - 1), 1) for k in RATIO_NAMES})
    return rows


POSE_YAWS = (-30.0, 0.0, 30.0)
POSE_PITCHES = (-10.0, 0.0, 10.0)


def pose_on_renders(heads: int = 8, skin_scan: str = "", detector: str = "auto",
                    size: int = 512) -> dict[str, Any]:
    """Render held-out corpus heads (bald, neutral) from every yaw of :data:`POSE_YAWS`
    and pitch of :data:`POSE_PITCHES`, find the face and fit the shape to its landmarks
    with the render's focal length; the fitted yaw and pitch against the camera's.

    Returns:
        Counts, mean absolute yaw and pitch errors, the mean signed pitch error (+: the
        fit looks down on the head more than the camera did) and rows per view.
    """
    import torch

    from head360cli.fitting.landmarks import find_faces
    from head360cli.fitting.stages import fit_face
    from head360cli.geometry.cameras import (
        RIG_DISTANCE,
        RIG_FOV_DEG,
        camera_on_sphere,
        intrinsics_from_fov,
    )
    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.synth.scene import make_head, render_head

    model = load_bilinear()
    k = intrinsics_from_fov(RIG_FOV_DEG, size, size)
    focal = float(k[0, 0])
    yaw, pitch = np.meshgrid(POSE_YAWS, POSE_PITCHES, indexing="ij")
    yaw, pitch = yaw.ravel(), pitch.ravel()
    c2w = camera_on_sphere(torch.tensor(yaw), torch.tensor(pitch), RIG_DISTANCE).float()
    rows = []
    for i in range(heads):
        head = make_head(i, "test", 0, skin_scan=skin_scan or None)
        out = render_head(head, np.zeros(52), c2w, k, size, with_hair=False, samples=4)
        for b in range(len(yaw)):
            img = (out.rgb[b].permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)
            found = find_faces(img, detector)
            row = {"head": i, "yaw": float(yaw[b]), "pitch": float(pitch[b]),
                   "found": bool(found)}
            if found:
                face = max(found, key=lambda f: f.area)
                angles = fit_face(model, face, (size, size), focal).euler_degrees()
                row |= {"yaw_error": angles["yaw"] - yaw[b],
                        "pitch_error": angles["pitch"] - pitch[b]}
            rows.append(row)
    hit = [r for r in rows if r["found"]]

    def mean(key: str, f=abs) -> float:
        return round(float(np.mean([f(r[key]) for r in hit])), 2) if hit else float("nan")

    return {"heads": heads, "views": len(rows), "found": len(hit), "detector": detector,
            "skin": "scan" if skin_scan else "painted",
            "yaw_abs_deg": mean("yaw_error"), "pitch_abs_deg": mean("pitch_error"),
            "pitch_signed_deg": mean("pitch_error", float), "rows": rows}
