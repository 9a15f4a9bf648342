"""The 52 ARKit blendshape names: one ordered list used everywhere in head360.

The order is Apple's ``ARFaceAnchor.BlendShapeLocation`` order (eyes, jaw, mouth, brows,
cheeks, nose, tongue), which is also the order of the Live Link UDP packet. The Live Link
Face app's CSV export swaps ``JawLeft``/``JawRight`` and ``MouthLeft``/``MouthRight``, so
readers must match columns by name, never by position: :func:`canonical_name` does that.

"Left" and "Right" are the subject's own sides, as in ARKit.
"""

from __future__ import annotations

import re

__all__ = [
    "ARKIT52",
    "INDEX",
    "MEDIAPIPE_BLENDSHAPES",
    "MERGED_SPLITS",
    "MIRROR",
    "MIRROR_INDEX",
    "NUM_BLENDSHAPES",
    "OPPOSED",
    "canonical_name",
    "split_part",
]

ARKIT52: tuple[str, ...] = (
    # eyes (14)
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft",
    "eyeSquintLeft", "eyeWideLeft",
    "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight",
    # jaw (4)
    "jawForward", "jawLeft", "jawRight", "jawOpen",
    # mouth (23)
    "mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight",
    "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthUpperUpLeft", "mouthUpperUpRight",
    # brows (5)
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    # cheeks (3)
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight",
    # nose (2)
    "noseSneerLeft", "noseSneerRight",
    # tongue (1)
    "tongueOut",
)  # fmt: skip

NUM_BLENDSHAPES = len(ARKIT52)
assert NUM_BLENDSHAPES == 52

INDEX: dict[str, int] = {name: i for i, name in enumerate(ARKIT52)}
"""Position of each canonical name in :data:`ARKIT52`."""


_OPPOSED_SIDED = tuple(
    pair for side in ("Left", "Right") for pair in (
        (f"eyeWide{side}", f"eyeSquint{side}"),
        (f"eyeWide{side}", f"eyeBlink{side}"),
        (f"mouthSmile{side}", f"mouthFrown{side}"),
        (f"mouthSmile{side}", "mouthPucker"),
        (f"mouthStretch{side}", "mouthPucker"),
        (f"mouthDimple{side}", "mouthPucker"),
        (f"browDown{side}", f"browOuterUp{side}"),
        (f"browDown{side}", "browInnerUp"),
        (f"cheekSquint{side}", "cheekPuff"),
    ))
OPPOSED: tuple[tuple[str, str], ...] = (
    *_OPPOSED_SIDED, ("mouthLeft", "mouthRight"), ("jawLeft", "jawRight"),
    ("mouthPucker", "mouthFunnel"), ("mouthRollLower", "mouthShrugLower"),
    ("mouthRollUpper", "mouthShrugUpper"))
"""Pairs of blendshapes that move the face in opposite ways (a wide eye and a squint, a
smile and a pucker): a face shows one or the other, so a fit that saturates both is
reading landmark noise."""


def _mirror_of(name: str) -> str:
    if name.endswith("Left"):
        return name[: -len("Left")] + "Right"
    if name.endswith("Right"):
        return name[: -len("Right")] + "Left"
    return name


MIRROR: dict[str, str] = {name: _mirror_of(name) for name in ARKIT52}
"""Name of the blendshape that a left/right mirror maps each one to (itself if central).

``jawLeft`` moves the jaw to the subject's left; mirrored, that is ``jawRight``. Likewise
``eyeLookInLeft`` (left eye looks towards the nose) mirrors to ``eyeLookInRight``.
"""

MIRROR_INDEX: tuple[int, ...] = tuple(INDEX[MIRROR[name]] for name in ARKIT52)
"""Permutation: ``w_mirrored = w[..., MIRROR_INDEX]``."""

MERGED_SPLITS: frozenset[str] = frozenset(
    name for name in ARKIT52 if not name.endswith(("Left", "Right"))
)
"""Central shapes that some rigs split in two halves (ICT-FaceKit's ``browInnerUp_L`` and
``browInnerUp_R``, ``cheekPuff_L``/``_R``); readers merge the halves by their mean."""


def _key(name: str) -> str:
    """Case- and separator-insensitive key: ``Jaw_Open`` -> ``jawopen``."""
    return re.sub(r"[\s_.\-]", "", name).casefold()


_BY_KEY: dict[str, str] = {_key(name): name for name in ARKIT52}

# Prefixes that some exporters put before the ARKit name.
_PREFIXES = ("blendshapes", "blendshape", "arkit", "bs")

# Side suffixes: `_L`, `.R`, `_left`, ` Right` ... (case-insensitive).
_SIDE_SUFFIX = re.compile(r"[\s_.\-](l|r|left|right)$", re.IGNORECASE)


def _strip_prefix(key: str) -> str:
    for prefix in _PREFIXES:
        if key.startswith(prefix) and key[len(prefix) :] in _BY_KEY:
            return key[len(prefix) :]
    return key


def canonical_name(column: str) -> str | None:
    """Map a column name from any common exporter onto its canonical ARKit name.

    Handles Live Link Face (``EyeBlinkLeft``), ARKit/MediaPipe (``eyeBlinkLeft``), snake
    case (``eye_blink_left``), side suffixes (``eyeBlink_L``, ``mouthSmile.R``) and
    prefixes (``blendShape.jawOpen``). Halves of central shapes (``browInnerUp_L``) map
    onto the central name; use :func:`split_part` to tell that they are halves.

    Args:
        column: A column header as found in a file.

    Returns:
        The canonical name from :data:`ARKIT52`, or ``None`` if the column is not an
        ARKit blendshape (``Timecode``, ``_neutral``, ``HeadYaw`` ...).
    """
    key = _strip_prefix(_key(column))
    if key in _BY_KEY:
        return _BY_KEY[key]
    match = _SIDE_SUFFIX.search(column.strip())
    if match is None:
        return None
    side = "Left" if match.group(1).lower().startswith("l") else "Right"
    base = _strip_prefix(_key(column.strip()[: match.start()]))
    sided = base + side.casefold()
    if sided in _BY_KEY:
        return _BY_KEY[sided]
    if base in _BY_KEY and _BY_KEY[base] in MERGED_SPLITS:
        return _BY_KEY[base]
    return None


def split_part(column: str) -> str | None:
    """Tell whether a column is one half of a central shape that some rigs split.

    Args:
        column: A column header such as ``browInnerUp_L``.

    Returns:
        ``"Left"`` or ``"Right"`` when the column is a half of a central shape
        (e.g. ``browInnerUp_L``), else ``None``.
    """
    name = canonical_name(column)
    if name is None or name not in MERGED_SPLITS:
        return None
    if _strip_prefix(_key(column)) in _BY_KEY:
        return None
    match = _SIDE_SUFFIX.search(column.strip())
    assert match is not None
    return "Left" if match.group(1).lower().startswith("l") else "Right"


MEDIAPIPE_BLENDSHAPES = (
    "_neutral", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft",
    "browOuterUpRight", "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft",
    "eyeBlinkRight", "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight",
    "eyeLookOutLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft",
    "eyeSquintRight", "eyeWideLeft", "eyeWideRight", "jawForward", "jawLeft", "jawOpen",
    "jawRight", "mouthClose", "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft",
    "mouthFrownRight", "mouthFunnel", "mouthLeft", "mouthLowerDownLeft",
    "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight", "mouthPucker", "mouthRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthSmileLeft", "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthUpperUpLeft", "mouthUpperUpRight", "noseSneerLeft", "noseSneerRight")
"""The order of the 52 scores of MediaPipe's blendshape model (its first, ``_neutral``, is
not an ARKit shape; it has no ``tongueOut``)."""
