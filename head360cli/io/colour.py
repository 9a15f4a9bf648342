"""Colour spaces of photos: the sRGB transfer curve (:func:`srgb_to_linear`), and ICC
display profiles made from primaries, for images that describe their colours without one.

A HEIF or AVIF photo may say its colour space as ``nclx`` code points (ITU-T H.273: the
primaries, the transfer curve) instead of an embedded ICC profile; ``pillow-heif`` hands
them over as ``info["nclx_profile"]``. :func:`nclx_profile` turns the ones head360 can
convert into an ICC profile (:func:`matrix_profile`), which
:mod:`head360cli.io.images` then converts to sRGB as it does an embedded one.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

__all__ = ["SRGB_TRC", "matrix_profile", "nclx_profile", "srgb_to_linear"]

SRGB_TRC = "srgb"
"""The sRGB transfer curve (a linear toe, then a 2.4 power), for :func:`matrix_profile`."""

def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """Linear light of sRGB values ``v`` in [0, 1] (any shape; the sRGB transfer curve:
    a linear toe, then a 2.4 power)."""
    v = np.asarray(v)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


_D50 = np.array([0.9642, 1.0, 0.8249])
"""The ICC profile connection space's white (D50), XYZ."""

_BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367],
                      [0.0389, -0.0685, 1.0296]])
"""Bradford's cone response matrix, which ICC profiles use to adapt colorants to D50."""

_NCLX_SRGB_LIKE = (1, 6, 13, 14, 15)
"""H.273 transfer codes read as the sRGB curve: sRGB's own (13) and BT.709's (1, 6, 14,
15), which still-image software renders as sRGB's (as Apple's and libheif's do)."""

_NCLX_GAMMA = {4: 2.2, 5: 2.8, 8: 1.0}
"""H.273 transfer codes that are pure power curves, and their exponent."""

_NCLX_PRIMARIES = {9: "BT.2020", 11: "DCI-P3", 12: "Display P3"}
"""Names of the wide-gamut H.273 primaries codes photos use, for the profile's name."""


def matrix_profile(primaries: Any, white: Any, trc: float | str, name: str) -> bytes:
    """An ICC v2 display profile of RGB primaries, a white and a transfer curve.

    Args:
        primaries: ``((xr, yr), (xg, yg), (xb, yb))``, the primaries' CIE xy.
        white: ``(xw, yw)``, the white's CIE xy (D65 is ``(0.3127, 0.329)``).
        trc: A power (``2.2``; ``563 / 256`` for Adobe RGB) or :data:`SRGB_TRC`.
        name: The profile's description (ASCII).

    Returns:
        The profile's bytes (the ICC.1 layout: header, tag table, tags; colorants adapted
        to the D50 connection space by Bradford's matrix).
    """
    xw, yw = (float(v) for v in white)
    white_xyz = np.array([xw / yw, 1.0, (1 - xw - yw) / yw])
    xyz = np.array([[x / y, 1.0, (1 - x - y) / y] for x, y in primaries]).T
    rgb_to_xyz = xyz * np.linalg.solve(xyz, white_xyz)  # columns: each primary at full
    adapt = np.linalg.inv(_BRADFORD) @ np.diag((_BRADFORD @ _D50) / (_BRADFORD @ white_xyz)
                                               ) @ _BRADFORD
    colorants = adapt @ rgb_to_xyz
    text = name.encode("ascii", "replace") + b"\0"
    tags = {b"desc": b"desc" + bytes(4) + struct.pack(">I", len(text)) + text
            + bytes(4 + 4 + 2 + 1 + 67),  # no Unicode or ScriptCode names
            b"wtpt": _xyz_tag(_D50), b"rXYZ": _xyz_tag(colorants[:, 0]),
            b"gXYZ": _xyz_tag(colorants[:, 1]), b"bXYZ": _xyz_tag(colorants[:, 2]),
            b"cprt": b"text" + bytes(4) + b"none\0"}
    curve = _curve_tag(trc)
    tags.update({b"rTRC": curve, b"gTRC": curve, b"bTRC": curve})
    return _assemble(tags, b"mntr", b"RGB ")


def _assemble(tags: dict[bytes, bytes], device_class: bytes, colour_space: bytes) -> bytes:
    """An ICC v2 profile's bytes from its tags (signature -> body): the 128-byte header
    (XYZ connection space, D50 illuminant), the tag table, then the tags, each on a 4-byte
    boundary. ``device_class`` is ``b"mntr"`` for a display, ``b"prtr"`` for a printer;
    ``colour_space`` ``b"RGB "`` or ``b"CMYK"``."""
    start = 128 + 4 + 12 * len(tags)
    table, data = b"", b""
    for sig, body in tags.items():
        body += bytes(-len(body) % 4)
        table += sig + struct.pack(">II", start + len(data), len(body))
        data += body
    header = (struct.pack(">I", start + len(data)) + bytes(4) + struct.pack(">I", 0x02100000)
              + device_class + colour_space + b"XYZ "
              + struct.pack(">6H", 2026, 1, 1, 0, 0, 0) + b"acsp"
              + bytes(24) + struct.pack(">I", 0) + _s15(_D50) + bytes(4 + 16 + 28))
    return header + struct.pack(">I", len(tags)) + table + data


def nclx_profile(nclx: dict[str, Any] | None) -> bytes | None:
    """An ICC profile for ``pillow-heif``'s ``nclx_profile`` (primaries as CIE xy, a
    transfer code), or ``None`` where there is nothing to convert: no nclx, sRGB's
    primaries (code 1) or unspecified ones (2).

    Raises:
        ValueError: A transfer curve head360 does not convert (PQ or HLG high dynamic
            range, among others), named by its code.
    """
    if not nclx or nclx.get("color_primaries") in (None, 1, 2):
        return None
    transfer = nclx.get("transfer_characteristics")
    if transfer in _NCLX_SRGB_LIKE or transfer == 2:  # unspecified: sRGB's, as for JPEG
        trc: float | str = SRGB_TRC
    elif transfer in _NCLX_GAMMA:
        trc = _NCLX_GAMMA[transfer]
    else:
        raise ValueError(f"transfer characteristics {transfer} (H.273) not converted")
    primaries = [(nclx[f"color_primary_{c}_x"], nclx[f"color_primary_{c}_y"])
                 for c in ("red", "green", "blue")]
    white = (nclx["color_primary_white_x"], nclx["color_primary_white_y"])
    code = nclx["color_primaries"]
    name = _NCLX_PRIMARIES.get(code, f"primaries {code}")
    return matrix_profile(primaries, white, trc, f"{name} (nclx, transfer {transfer})")


def _s15(values: Any) -> bytes:
    """ICC s15Fixed16Number values."""
    return b"".join(struct.pack(">i", round(float(v) * 65536)) for v in values)


def _xyz_tag(xyz: Any) -> bytes:
    return b"XYZ " + bytes(4) + _s15(xyz)


def _curve_tag(trc: float | str) -> bytes:
    """A ``curv`` tag: one u8Fixed8 exponent, or 1024 samples of the sRGB curve."""
    if trc == SRGB_TRC:
        v = np.linspace(0.0, 1.0, 1024)
        linear = srgb_to_linear(v)
        samples = np.round(linear * 65535).astype(">u2").tobytes()
        return b"curv" + bytes(4) + struct.pack(">I", 1024) + samples
    return b"curv" + bytes(4) + struct.pack(">IH", 1, round(float(trc) * 256))
