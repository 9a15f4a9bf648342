"""Export of the generator (ONNX) and runners that need no torch."""
