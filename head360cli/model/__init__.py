"""The core generator: a neural texture on the parametric mesh, hex-plane features, a
near-surface volume renderer and a RefineNet (the Head360 paper's representation)."""
