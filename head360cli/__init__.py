"""head360: one photo to an animatable 360-degree head.

The import package of the ``head360`` distribution. Importing it is cheap: heavy
dependencies (torch, OpenCV, dlib, onnxruntime) are imported inside the functions that
need them, so ``head360 --help`` starts instantly.
"""

import os as _os

__version__ = "0.1.0"

# onnxruntime (1.32 on Linux and macOS) keeps a device identifier and a queue of usage
# events under ~/.cache/Microsoft from its first import and uploads them when it can.
# head360 works on people's photos and promises to run offline, so it turns that off
# before any onnxruntime import, unless the user set the variable themselves.
_os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
