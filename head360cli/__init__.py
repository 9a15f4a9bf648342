"""head360: one photo to an animatable 360-degree head.

The import package of the ``head360`` distribution. Its public API is four functions and a
config (:mod:`head360cli.api`)::

    from head360cli import fit, load_head, render, animate, FitConfig

They are imported on first use, and heavy dependencies (torch, OpenCV, dlib, onnxruntime)
inside the functions that need them, so ``import head360cli`` and ``head360 --help`` start
instantly.
"""

import os as _os

from head360cli.version import __version__ as __version__

__all__ = ["FitConfig", "__version__", "animate", "fit", "load_head", "render"]

# onnxruntime (1.32 on Linux and macOS) keeps a device identifier and a queue of usage
# events under ~/.cache/Microsoft from its first import and uploads them when it can.
# head360 works on people's photos and promises to run offline, so it turns that off
# before any onnxruntime import, unless the user set the variable themselves.
_os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")


def __getattr__(name: str):
    """The public API's names, imported from :mod:`head360cli.api` when first used."""
    if name in ("FitConfig", "animate", "fit", "load_head", "render"):
        from head360cli import api

        return getattr(api, name)
    raise AttributeError(f"module 'head360cli' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
