"""The settings of a whole fit, shared by ``head360 fit`` and :func:`head360cli.fit`.

Importing this module is cheap (no torch, no OpenCV), so the command line can build and
check a config before any heavy import."""

from __future__ import annotations

import dataclasses

from head360cli.errors import BadInputError

HAIR_PARSERS = ("segmenter", "grabcut")
"""How the hair is parsed (:func:`head360cli.fitting.hair_parse.parse_hair`)."""
PRESET_NAMES = ("fast", "quality")
"""The texture-inversion presets a user chooses from
(:data:`head360cli.fitting.texture.PRESETS` also has ``sweep``, which ``bench fit``
uses)."""

DETECTORS = ("auto", "yunet", "blazeface", "hog", "cnn")
"""The face detectors ``--detector`` names (:func:`head360cli.fitting.landmarks.find_faces`)."""

HAIRSTYLE_COUNT = 30
"""SynHead-P's hairstyles, ids 0 (bald) to 29 (:data:`head360cli.synth.hair.HAIRSTYLES`)."""


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """What a fit of one photo does; the defaults are ``head360 fit``'s."""

    preset: str = "fast"
    """Texture-inversion effort: ``fast`` (about 11 s on 2 CPU cores) or ``quality``
    (about 37 s)."""
    face: int = 0
    """Which face of the photo: 0 the largest, 1 the next, ..."""
    detector: str = "auto"
    """Face detector: ``auto`` (YuNet, then BlazeFace when YuNet finds none), ``yunet``
    or ``blazeface``, each with the 478-point face mesh; ``hog`` or ``cnn``: dlib's
    detectors with its 68-point predictor (research-only training data)."""
    focal: float | None = None
    """Focal length in pixels of the photo on disk; ``None``: from EXIF, else a 50 mm
    equivalent lens."""
    distance: float | None = None
    """The camera's distance to the head in metres when known (a rig): it fixes the
    head's size, which landmarks alone hardly tell from its distance."""
    hair_style: int | None = None
    """Force this hairstyle id (0-29) instead of the classifier's choice."""
    hair_parser: str = "segmenter"
    """``segmenter``: MediaPipe's hair segmentation network, kept to the fitted face;
    ``grabcut``: GrabCut seeded by the landmarks and skin colour (with the learned prior
    unless ``learned_prior`` is off)."""
    learned_prior: bool = True
    """With the ``grabcut`` parser: use the learned hair prior (when installed); ``False``
    parses by colour and landmarks alone."""
    hair_placement: bool = True
    """Shift the hairstyle's mesh to match the parsed hair from the fitted camera."""
    hair_texture: bool = True
    """Make the hair's texture from the photo's hair (``hair_detail`` in the head file,
    :mod:`~head360cli.fitting.hair_texture`); off: the generator's smooth strands."""
    closed_lids: bool = True
    """Fit the texture change that closed eyes show as a lid (stored in the head file);
    ``False`` leaves the inversion's eyelids, which blink as a dark smudge."""
    device: str = "cpu"
    """Torch device of the generator: ``cpu``, ``cuda`` or ``cuda:N``."""

    def check(self) -> FitConfig:
        """Refuse values no fit can use, before any work; returns ``self``.

        Raises:
            BadInputError: Naming the field, what was expected and what was found.
        """
        from head360cli.fitting.shape import check_camera

        if self.preset not in (*PRESET_NAMES, "sweep"):
            raise BadInputError(f"expected preset {' or '.join(PRESET_NAMES)}, found "
                                f"{self.preset!r}")
        if isinstance(self.face, bool) or not isinstance(self.face, int) or self.face < 0:
            raise BadInputError(f"expected a face number >= 0, found {self.face!r}")
        if self.hair_parser not in HAIR_PARSERS:
            raise BadInputError(f"expected hair parser {', '.join(HAIR_PARSERS)}, found "
                                f"{self.hair_parser!r}")
        if self.detector not in DETECTORS:
            raise BadInputError(f"expected detector {', '.join(DETECTORS)}, found "
                                f"{self.detector!r}")
        if self.hair_style is not None and not 0 <= self.hair_style < HAIRSTYLE_COUNT:
            from head360cli.synth.hair import style_index

            style_index(int(self.hair_style))  # raises, in its one wording
        check_camera(self.focal, self.distance)
        return self
