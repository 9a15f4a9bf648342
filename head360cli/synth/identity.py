"""Identities of the SynHead-P corpus: interpretable sculpt parameters and their sampling.

Every length is in metres. Means and spreads follow published adult anthropometry
(Farkas et al., *Anthropometry of the Head and Face*; the NASA/ANSUR head surveys): head
breadth about 0.155 m (men) / 0.145 m (women), head length 0.195 / 0.185, head height
(vertex to menton) 0.232 / 0.218, bizygomatic width 0.140 / 0.131, bigonial width
0.107 / 0.097, interpupillary distance 0.064 / 0.062, nose length 0.053 / 0.049, nose width
0.036 / 0.032, mouth width 0.053 / 0.050, ear length 0.064 / 0.060. Samples are clipped to
the mean +- 2.5 standard deviations, so proportions stay inside the published ranges.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["IdentityParams", "mean_identity", "sample_identity"]


@dataclasses.dataclass(frozen=True)
class IdentityParams:
    """The sculpt parameters of one synthetic identity."""

    sex: float = 0.5
    """0 female, 1 male (used by the sampler and by the appearance)."""
    age: float = 35.0
    """Years, 16 to 70: softer jaw and deeper folds with age, lighter hair later."""
    head_breadth: float = 0.150
    """Widest left-right extent of the cranium."""
    head_length: float = 0.190
    """Front-back extent of the cranium (glabella to the back of the head)."""
    head_height: float = 0.225
    """Vertex (top of the head) to menton (bottom of the chin)."""
    face_width: float = 0.135
    """Bizygomatic width: across the cheekbones."""
    jaw_width: float = 0.102
    """Bigonial width: across the angles of the jaw."""
    chin_projection: float = 0.004
    """How far the chin sticks out beyond the lower lip line."""
    chin_height: float = 0.040
    """Lower-lip line to menton."""
    nose_length: float = 0.051
    """Nasion to the base of the nose."""
    nose_projection: float = 0.022
    """How far the nose tip stands out of the face."""
    nose_width: float = 0.034
    """Across the alae."""
    eye_spacing: float = 0.063
    """Between the centres of the eyes (interpupillary distance)."""
    eye_size: float = 1.0
    """Scale of the eye opening (1 = 30 mm wide)."""
    brow_ridge: float = 0.004
    """How much the brow ridge stands out."""
    lip_fullness: float = 1.0
    """Scale of lip volume."""
    mouth_width: float = 0.051
    """Corner to corner."""
    ear_size: float = 0.062
    """Ear length."""
    ear_protrusion: float = 0.35
    """Angle (radians) between ear and head side."""
    forehead_slope: float = 0.3
    """0 upright, 1 strongly sloped forehead."""
    cheek_fullness: float = 0.5
    """0 hollow, 1 full cheeks."""
    neck_width: float = 0.115
    """Neck diameter left-right."""
    deform_seed: int = 0
    """Seed of the smooth random deformation of the skin."""
    deform_amplitude: float = 0.003
    """Amplitude of that deformation, metres."""


def mean_identity() -> IdentityParams:
    """The template identity: the average of both sexes, no random deformation."""
    return IdentityParams(deform_amplitude=0.0)


# (female mean, male mean, standard deviation) per parameter.
_STATS: dict[str, tuple[float, float, float]] = {
    "head_breadth": (0.145, 0.155, 0.005),
    "head_length": (0.185, 0.195, 0.0065),
    "head_height": (0.218, 0.232, 0.008),
    "face_width": (0.131, 0.140, 0.005),
    "jaw_width": (0.097, 0.107, 0.006),
    "chin_projection": (0.002, 0.005, 0.003),
    "chin_height": (0.037, 0.043, 0.004),
    "nose_length": (0.049, 0.053, 0.004),
    "nose_projection": (0.020, 0.023, 0.0025),
    "nose_width": (0.032, 0.036, 0.0025),
    "eye_spacing": (0.062, 0.064, 0.0030),
    "eye_size": (1.02, 0.98, 0.06),
    "brow_ridge": (0.002, 0.006, 0.0015),
    "lip_fullness": (1.08, 0.95, 0.15),
    "mouth_width": (0.050, 0.053, 0.0035),
    "ear_size": (0.060, 0.064, 0.004),
    "ear_protrusion": (0.33, 0.37, 0.08),
    "forehead_slope": (0.2, 0.4, 0.15),
    "cheek_fullness": (0.55, 0.45, 0.18),
    "neck_width": (0.105, 0.122, 0.007),
}


def sample_identity(seed: int, sex: float | None = None, age: float | None = None
                    ) -> IdentityParams:
    """Draw an identity: sex-specific means, correlated sizes, clipped to +-2.5 SD.

    Args:
        seed: Random seed; the same seed gives the same identity.
        sex: 0 or 1 to fix it (else drawn).
        age: Years, to fix it (else uniform in 16..70).
    """
    rng = np.random.default_rng([seed, 0x4EAD])
    sex = float(rng.integers(0, 2)) if sex is None else float(sex)
    age = float(rng.uniform(16.0, 70.0)) if age is None else float(age)
    size = rng.standard_normal()  # a shared "overall size" factor correlates dimensions
    values = {}
    for name, (female, male, sd) in _STATS.items():
        z = 0.6 * size + 0.8 * rng.standard_normal() if name.startswith(("head", "face",
                                                                          "jaw", "neck")) \
            else rng.standard_normal()
        z = float(np.clip(z, -2.5, 2.5))
        values[name] = female + (male - female) * sex + sd * z
    # Age: the nose and ears keep growing, cheeks lose fullness.
    years = (age - 35.0) / 35.0
    values["nose_length"] += 0.002 * years
    values["ear_size"] += 0.003 * years
    values["cheek_fullness"] = float(np.clip(values["cheek_fullness"] - 0.15 * years, 0, 1))
    return IdentityParams(sex=sex, age=age, deform_seed=int(rng.integers(0, 2**31)),
                          deform_amplitude=float(rng.uniform(0.0015, 0.004)), **values)
