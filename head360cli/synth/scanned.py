"""SynHead-P heads whose identity comes from ICT-FaceKit's scanned shape space.

Such a head is the template's sculpt with its face at the mean (what the scans do not
cover still varies: the ears, the neck's width, the eyes' opening), moved by ICT's 100
identity components (``models/identities.npz``, made by
:func:`head360cli.synth.ict.build_identities`) with standard-normal coefficients. Its
expressions, of either kind, are made on the sculpt and move the same vertices of the
moved head: per-vertex displacements, exact where the fields move a part rigidly (lids
with their eyeball, teeth, tongue).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from head360cli.synth.identity import IdentityParams, mean_identity

__all__ = ["IDENTITY_SPACES", "SCULPT_KEEP", "scanned_identity"]

IDENTITY_SPACES = ("sculpted", "scanned")
"""Where SynHead-P's identities come from: the procedural sculpt, or ICT's scans."""
SCULPT_KEEP = ("sex", "age", "eye_size", "ear_size", "ear_protrusion", "neck_width")
"""Sculpt parameters a scanned head keeps from its SynHead-P draw: ICT's scans have no
ears or lower neck, and each head's blink must close its own eye opening (the lids move
rigidly with the eyeball in ICT's fields)."""
COEFFICIENT_CLIP = 2.5
"""Coefficients are clipped to this many standard deviations, as the sculpt's are."""


def _eye_span(verts: np.ndarray) -> float:
    """Distance between the eyeballs' centres of a head ``(V, 3)``."""
    from head360cli.synth.sculpt import topology

    parts = topology().parts
    left, right = (verts[slice(*parts[p])].mean(0) for p in ("eye_l", "eye_r"))
    return float(np.linalg.norm(left - right))


def scanned_identity(params: IdentityParams, seed: int, expressions: str = "scanned"
                     ) -> tuple[np.ndarray, np.ndarray]:
    """A head of ICT's shape space with the sculpt's ``params`` kept where the scans end
    (:data:`SCULPT_KEEP`), and its expressions.

    Args:
        params: A SynHead-P draw (:func:`head360cli.synth.identity.sample_identity`).
        seed: Seed of the head's ICT coefficients.
        expressions: ``scanned`` (scaled by the moved head's eye span) or ``procedural``
            (the sculpt's own, anchored at its features).

    Returns:
        Neutral vertices ``(V, 3)`` and the 52 ARKit deltas ``(52, V, 3)``, float64.
    """
    from head360cli.synth.expressions import procedural_deltas, scanned_deltas, shipped_fields
    from head360cli.synth.sculpt import build_head

    base = dataclasses.replace(mean_identity(), **{k: getattr(params, k)
                                                   for k in SCULPT_KEEP})
    verts, frame = build_head(base)
    fields = shipped_fields("identities")
    rng = np.random.default_rng([seed, 0x1C7])
    code = np.clip(rng.standard_normal(len(fields)), -COEFFICIENT_CLIP, COEFFICIENT_CLIP)
    moved = verts + np.tensordot(code, fields, 1)
    if expressions == "procedural":
        return moved, procedural_deltas(verts, frame)
    return moved, scanned_deltas(verts, frame, span=_eye_span(moved))

