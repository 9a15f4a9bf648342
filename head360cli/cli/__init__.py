"""The ``head360`` command line: parses, calls the library, prints. Nothing else.

One module per command group: :mod:`~head360cli.cli.files` (``info``, ``inspect``),
:mod:`~head360cli.cli.photo` (``fit``, ``parse-hair``, ``classify-hair``, ``demo``),
:mod:`~head360cli.cli.head` (``render``, ``animate``, ``swap-hair``, ``sample``,
``export-mesh``, ``export-onnx``), :mod:`~head360cli.cli.corpus` (``synth``,
``build-model``, ``train``, ``train-hair-prior``) and :mod:`~head360cli.cli.bench`;
what they share is in :mod:`~head360cli.cli.base`, the entry point in
:mod:`~head360cli.cli.app`. Heavy modules (torch, OpenCV, dlib) are imported inside
the commands, so ``head360 --help`` starts instantly."""

from head360cli.cli.app import cli, main

__all__ = ["cli", "main"]
