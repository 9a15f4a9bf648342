"""head360: one photo to an animatable 360-degree head.

The import package of the ``head360`` distribution. Importing it is cheap: heavy
dependencies (torch, OpenCV, dlib, onnxruntime) are imported inside the functions that
need them, so ``head360 --help`` starts instantly.
"""

__version__ = "0.1.0"
